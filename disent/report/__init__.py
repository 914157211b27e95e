"""Regenerate ``reports/README.md`` and its figures from run folders and measured JSON.

``python -m disent.report`` (or ``disent-report``) reads

* run folders under ``outputs/`` and ``multirun/`` (:mod:`disent.runs`),
* ``reports/eval/*.json`` from :mod:`disent.eval.protocols` and :mod:`disent.eval.stability`
  (``--compute`` runs both first),
* ``reports/bench.json`` (``python -m disent.bench``) and ``reports/lighting/``,

and writes one Markdown report with PNG figures under ``reports/figures/``.  Every figure is
drawn from run data; whatever is missing becomes a note in the report, never a crash.

One module per family of sections, each section a ``sec_*`` function (:data:`SECTIONS` lists them in the
report's order): :mod:`~disent.report.claims` (the targets and the paper's claims),
:mod:`~disent.report.ablations` (claim 4 and the ablation tables), :mod:`~disent.report.training` (runs, ceiling,
teaser, recipe, learning curves), :mod:`~disent.report.tools` (what the evaluation tools measured: SH variance,
stability, methods, photos), :mod:`~disent.report.benchmarks` and :mod:`~disent.report.lighting`; they share
:mod:`~disent.report.document` (the Markdown, kept across builds), :mod:`~disent.report.tables` (spreads, verdicts,
run selection) and :mod:`~disent.report.pictures` (models and image grids).
"""

from __future__ import annotations

import argparse
import datetime as _dt
from pathlib import Path

import torch

from disent.eval import ablation as _ablation
from disent.report.ablations import sec_ablation
from disent.report.benchmarks import sec_bench
from disent.report.claims import sec_claims, sec_targets
from disent.report.document import (
    PROVENANCE,
    Report,
    contents,
    kept_provenance,
    provenance_row,
    rel_path,
    section_name,
)
from disent.report.lighting import sec_lighting
from disent.report.tables import table_head
from disent.report.tools import sec_methods, sec_photos, sec_sh_variance, sec_stability
from disent.report.training import (
    sec_ceiling,
    sec_learning_curves,
    sec_recipe,
    sec_runs,
    sec_teaser,
    sec_uv_by_seed,
)
from disent.runs import RUN_ROOTS, find_runs, head_revision, publish, record_run, setting, tool_folder


def build(
    out="reports",
    roots=RUN_ROOTS,
    n_vis: int = 6,
    compute: bool = False,
    name: str = "README.md",
    publish_folders=(),
    sections=None,
) -> Path:
    """Publish each tool folder of ``publish_folders`` into ``out`` (:func:`disent.runs.publish`), then write
    ``out/name`` and ``out/figures/*.png``; returns the Markdown path.  ``sections`` (names, see
    :data:`SECTIONS`): build only these and keep the others as published."""
    unknown = set(sections or ()) - set(SECTIONS)
    if unknown:
        raise ValueError(f"unknown section(s) {', '.join(sorted(unknown))}; the sections: {', '.join(SECTIONS)}")
    out = Path(out)
    eval_dir = out / "eval"
    missing = [str(r) for r in roots if not Path(r).is_dir()]
    if missing and any("runs" in SECTIONS[s][2] for s in sections or SECTIONS):  # a run root only where runs are read
        raise FileNotFoundError(f"run root(s) not found: {', '.join(missing)}")
    for folder in publish_folders:
        print(f"published {len(publish(folder, out))} file(s) of {folder}")
    if compute:
        from disent.eval import protocols, stability

        folder = tool_folder("eval")
        protocols.main(["--out", str(folder), "--roots", *map(str, roots)])
        stability.main(["--out", str(folder), "--roots", *map(str, roots)])
        publish(folder, out)
    records = out / "runs"  # the records of the runs the report has read (record_run)
    roots = [r for r in roots if str(r) not in missing]
    for r in find_runs(roots):
        if r.status != "incomplete" and r.recorded_from is None:
            record_run(r, records)
    runs = find_runs([*roots, records])
    recorded = sum(r.recorded_from is not None for r in runs)
    published = out / name
    previous = published.read_text() if published.is_file() else ""
    measured = {(setting(r, drop_model=True), r.model) for r in runs} | {(setting(r), None) for r in runs}
    rep = Report(out, previous, only=sections, measured=measured)
    budget = _ablation.budget(runs)
    roots_arg = f" --roots {' '.join(map(str, roots))}" if roots else ""
    command = f"python -m disent.report{' --compute' if compute else ''}{roots_arg}" + (
        f" --sections {' '.join(sections)}" if sections else ""
    )
    source = (
        f"{len(runs)} run(s): {len(runs) - recorded} folder(s) under "
        f"{', '.join(f'`{r}/`' for r in roots) or 'no root'}, {recorded} record(s); budget "
        f"{', '.join(f'{k}={v}' for k, v in budget.items()) or 'none recorded'}"
    )
    revision = (head_revision() or "unknown")[:7]
    built = f"`{revision}`, {_dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}"
    rep.add(
        "# disent report\n",
        "All numbers are measured on SynthFaces (its ground truth); nothing is copied from the paper except where "
        "marked *paper*. Each section comes from the build in the table below that names it (`python -m "
        "disent.report` at that revision), from the run folders under its roots and the records of earlier runs in "
        f"`{rel_path(records, out)}/` (config, git revision, metrics and eval of each ended run the report has read, "
        "without its weights), with the tool folders published into `reports/`. To regenerate everything: run the "
        "suite (`ablations/suite.sh EXPERIMENT`, see `ablations/README.md`), then `python -m disent.report "
        "--compute --roots ROOT...`.\n",
        "\n".join(
            [*table_head(*PROVENANCE), provenance_row(list(sections or SECTIONS), built, source, command)]
            + (kept_provenance(previous, sections) if sections else [])
        )
        + "\n",
    )
    inputs = {"runs": runs, "eval_dir": eval_dir, "out": out, "n_vis": n_vis}
    head = len(rep.lines)
    for title, fn, needs in SECTIONS.values():
        rep.section(title, fn, *(inputs[k] for k in needs))
    rep.lines[head:head] = contents("\n".join(rep.lines))
    path = out / name
    path.write_text("\n".join(rep.lines) + "\n")
    return path


SECTIONS = {  # name (--sections): title, builder, its inputs; in the report's order
    section_name(fn): (title, fn, needs)
    for title, fn, needs in (
        ("At a glance: the targets", sec_targets, ("runs",)),
        ("Teaser: input, recon, albedo, normal, shading, matte", sec_teaser, ("runs", "n_vis")),
        ("The paper's claims, measured", sec_claims, ("runs", "eval_dir")),
        ("Floor and ceiling: what each layer can reach", sec_ceiling, ("runs",)),
        ("Lighting stability: SH variance (supplement protocol)", sec_sh_variance, ("eval_dir",)),
        ("Ablations", sec_ablation, ("runs",)),
        ("Stability where methods fail", sec_stability, ("eval_dir",)),
        ("Stability across seeds: the implicit model's UV map", sec_uv_by_seed, ("runs",)),
        ("Training recipe: leave-one-out", sec_recipe, ("runs",)),
        ("Learning curves", sec_learning_curves, ("runs",)),
        ("Real photos: the domain gap", sec_photos, ("out",)),
        ("Methods on one plane: time against accuracy", sec_methods, ("eval_dir",)),
        ("Benchmarks (`reports/bench*.json`)", sec_bench, ("out",)),
        ("L-hat uncertainty and lighting model order", sec_lighting, ("out",)),
        ("Runs", sec_runs, ("runs",)),  # every run read, last: the tables above cite it
    )
}


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m disent.report", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="reports")
    p.add_argument("--roots", nargs="*", default=list(RUN_ROOTS))
    p.add_argument("--n-vis", type=int, default=6, help="test images per figure")
    p.add_argument("--compute", action="store_true", help="recompute reports/eval/*.json first (protocols, stability)")
    p.add_argument(
        "--publish",
        nargs="+",
        default=(),
        metavar="FOLDER",
        help="tool folders (edit, lighting, photos, eval, bench, sheet) to copy into the report first",
    )
    p.add_argument(
        "--sections",
        nargs="+",
        default=None,
        metavar="NAME",
        help=f"build only these sections and keep the others as published ({', '.join(SECTIONS)})",
    )
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    try:
        path = build(a.out, a.roots, a.n_vis, a.compute, publish_folders=a.publish, sections=a.sections)
    except (FileNotFoundError, ValueError) as e:
        p.error(str(e))
    print(f"wrote {path}")

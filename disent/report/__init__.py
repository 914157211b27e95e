"""Rebuild the whole report, ``reports/README.md`` (the front page) and ``reports/appendix/*.md``, with every figure
they draw, from the committed records alone.

``python -m disent.report`` (or ``disent-report``) reads

* ``reports/runs.jsonl``: one row per ended run (:func:`disent.publish.write_records`), and the run folders under
  ``--roots`` (``outputs/`` and ``multirun/`` by default), whose ended runs it adds to that file first;
* the tools' results published into ``reports/`` (``--publish FOLDER``): ``eval/*.json`` from
  :mod:`disent.eval.protocols` and :mod:`disent.eval.stability` (``--compute`` runs both first), ``edit/``,
  ``photos/``, ``lighting/``, ``bench*.json``;

and writes every page at one revision; nothing is kept from an earlier build.  ``--check`` rebuilds into a scratch
folder and fails where a committed page differs from the rebuild other than in its build line.

The front page is :mod:`~disent.report.front`; each appendix page lists its sections in :data:`PAGES`, each section a
``sec_*`` function of :mod:`~disent.report.targets`, :mod:`~disent.report.claims` (the paper's claims),
:mod:`~disent.report.ablations`, :mod:`~disent.report.training` (runs, ceiling, teaser, recipe, learning curves),
:mod:`~disent.report.tools` (SH variance, stability, methods, photos), :mod:`~disent.report.benchmarks` and
:mod:`~disent.report.lighting`.  They share :mod:`~disent.report.document` (a page), :mod:`~disent.report.tables`
(spreads, verdicts, cells) and :mod:`~disent.report.pictures`.
"""

from __future__ import annotations

import argparse
import difflib
import shutil
import sys
import tempfile
from pathlib import Path

import torch

from disent.publish import publish, write_records
from disent.report import front
from disent.report.ablations import sec_ablation
from disent.report.benchmarks import sec_bench
from disent.report.claims import sec_claims
from disent.report.document import Report
from disent.report.lighting import sec_lighting
from disent.report.tables import Glance
from disent.report.targets import sec_targets
from disent.report.tools import sec_methods, sec_photos, sec_sh_variance, sec_stability
from disent.report.training import (
    sec_ceiling,
    sec_learning_curves,
    sec_recipe,
    sec_runs,
    sec_teaser,
    sec_uv_by_seed,
)
from disent.runs import RECORDS, RUN_ROOTS, find_runs, with_records
from disent.storage import head_revision, tool_folder

PAGES = {  # appendix page: (title, what it holds, [(section title, builder, its inputs)]), in the contents' order
    "claims": (
        "The paper's claims in full",
        "every table behind the front page's claims, with the settings off the budget ladder",
        [("The paper's claims, measured", sec_claims, ("runs", "eval_dir", "glance"))],
    ),
    "targets": (
        "Targets, floors and the L-hat target studies",
        "the ladder against the targets of a trainable recipe, what holds the albedo back, and each L-hat target "
        "tried as E_recon-L's",
        [("At a glance: the targets", sec_targets, ("runs",))],
    ),
    "decomposition": (
        "Decompositions",
        "the three models on the same test faces, and their normals against the pseudo-GT and the truth",
        [("Input, recon, albedo, normal, shading, matte", sec_teaser, ("runs", "n_vis"))],
    ),
    "ablations": (
        "Ablations by setting",
        "one table per budget and setting: each ablation against the full model",
        [("Ablations", sec_ablation, ("runs",))],
    ),
    "training": (
        "Training: floor and ceiling, recipe, learning curves",
        "what each layer can reach, the recipe's leave-one-out, and validation accuracy during training",
        [
            ("Floor and ceiling: what each layer can reach", sec_ceiling, ("runs",)),
            ("Training recipe: leave-one-out", sec_recipe, ("runs",)),
            ("Learning curves", sec_learning_curves, ("runs",)),
        ],
    ),
    "stability": (
        "Stability",
        "lighting stability (the supplement's protocol), where methods fail, and the implicit model's UV map by seed",
        [
            ("Lighting stability: SH variance (supplement protocol)", sec_sh_variance, ("eval_dir",)),
            ("Stability where methods fail", sec_stability, ("eval_dir",)),
            ("Stability across seeds: the implicit model's UV map", sec_uv_by_seed, ("runs",)),
        ],
    ),
    "lighting": (
        "L-hat uncertainty and lighting model order",
        "the emcee posterior of L-hat, its calibration, and the lighting model order a scene needs",
        [("L-hat uncertainty and lighting model order", sec_lighting, ("out",))],
    ),
    "photos": ("Real photos", "the domain gap on the bundled photos", [("Real photos", sec_photos, ("out",))]),
    "benchmarks": (
        "Speed",
        "every estimator's time against its accuracy, and the benchmarks",
        [
            ("Methods on one plane: time against accuracy", sec_methods, ("eval_dir",)),
            ("Benchmarks", sec_bench, ("out",)),
        ],
    ),
    "runs": ("Runs", "every run the report reads", [("Runs", sec_runs, ("runs",))]),
}
ARCHIVE = Path(__file__).with_name("archive.md")  # tables whose runs left no record, as the last build to have them
BUILD_LINE = "_Built by `python -m disent.report` at "  # the one line a rebuild may change


def build_line(runs) -> str:
    revision = (head_revision() or "unknown")[:7]
    return f"{BUILD_LINE}`{revision}` from {len(runs)} runs (`runs.jsonl`) and the tools' published results._\n"


def appendix_page(out: Path, name: str, inputs: dict) -> Report:
    title, holds, sections = PAGES[name]
    rep = Report(out, f"appendix/{name}.md")
    rep.add(f"# {title}\n", f"[Front page](../README.md). This page: {holds}.\n", build_line(inputs["runs"]))
    for section, fn, needs in sections:
        rep.section(section, fn, *(inputs[k] for k in needs))
    rep.write(contents_list=True)
    return rep


def archive_page(out: Path, runs) -> Report:
    rep = Report(out, "appendix/archive.md")
    rep.add(
        "# Archive: tables whose runs are gone\n",
        "[Front page](../README.md). These rows and sections were measured on runs that left no record in "
        "`reports/runs.jsonl` (their folders are gone); they stand as the last build that had the runs published "
        "them (revision `2604938`), run folders named by their run id. No front-page number reads them.\n",
        build_line(runs),
        ARCHIVE.read_text(),
    )
    rep.write(contents_list=True)
    return rep


def build(out="reports", roots=RUN_ROOTS, n_vis: int = 6, compute: bool = False, publish_folders=()) -> list[Path]:
    """Publish each tool folder of ``publish_folders`` into ``out``, add the ended runs under ``roots`` to
    ``out/runs.jsonl``, then write every page; returns the pages written."""
    out = Path(out)
    missing = [str(r) for r in roots if not Path(r).is_dir() and str(r) not in RUN_ROOTS]
    if missing:
        raise FileNotFoundError(f"run root(s) not found: {', '.join(missing)}")
    for folder in publish_folders:
        print(f"published {len(publish(folder, out))} file(s) of {folder}")
    if compute:
        from disent.eval import protocols, stability

        folder = tool_folder("eval")
        protocols.main(["--out", str(folder), "--roots", *map(str, roots)])
        stability.main(["--out", str(folder), "--roots", *map(str, roots)])
        publish(folder, out)
    folders = find_runs(roots)  # read once: their ended runs join the records, then every record joins them
    write_records(folders, out / RECORDS)
    runs = with_records(folders, out / RECORDS)
    inputs = {"runs": runs, "eval_dir": out / "eval", "out": out, "n_vis": n_vis, "glance": Glance()}
    pages = [appendix_page(out, name, inputs) for name in PAGES]
    pages.append(archive_page(out, runs))
    pages.insert(0, front.page(out, runs, inputs["glance"], build_line(runs), (*PAGES, "archive")))
    failed = [f"{p.page.name}: {t}" for p in pages for t in p.failed]
    if failed:
        print(f"sections that failed: {'; '.join(failed)}", file=sys.stderr)
    return [p.page for p in pages]


def pages_of(folder: Path) -> dict[str, str]:
    """``{page: text}`` of a built report, less each page's build line."""
    paths = [folder / "README.md", *sorted((folder / "appendix").glob("*.md"))]
    return {
        str(p.relative_to(folder)): "".join(line for line in p.read_text().splitlines(True) if BUILD_LINE not in line)
        for p in paths
        if p.is_file()
    }


def check(out="reports", n_vis: int = 6) -> list[str]:
    """Rebuild the report from the committed records into a scratch copy of ``out`` and return a unified diff of
    each page that differs from the committed one (its build line aside); empty where the rebuild matches."""
    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp) / "reports"
        shutil.copytree(out, scratch)
        build(scratch, roots=(), n_vis=n_vis)
        new, old = pages_of(scratch), pages_of(out)
    diffs = []
    for page in sorted(set(new) | set(old)):
        a, b = old.get(page, "").splitlines(True), new.get(page, "").splitlines(True)
        diffs += difflib.unified_diff(a, b, f"committed/{page}", f"rebuilt/{page}", n=1)
    return diffs


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m disent.report", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="reports")
    p.add_argument("--roots", nargs="*", default=list(RUN_ROOTS), help="run folders whose ended runs join the records")
    p.add_argument("--n-vis", type=int, default=6, help="test images per figure")
    p.add_argument("--compute", action="store_true", help="recompute reports/eval/*.json first (protocols, stability)")
    p.add_argument(
        "--publish",
        nargs="+",
        default=(),
        metavar="FOLDER",
        help="tool folders (edit, lighting, photos, eval, bench, sheet) to copy into the report first",
    )
    p.add_argument("--check", action="store_true", help="rebuild into a scratch folder; fail where the pages differ")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    if a.check:
        diffs = check(a.out, a.n_vis)
        sys.stdout.writelines(diffs[:400])
        if diffs:
            raise SystemExit(f"the committed report differs from its rebuild ({len(diffs)} diff lines above)")
        print("the committed report matches its rebuild")
        return
    try:
        pages = build(a.out, a.roots, a.n_vis, a.compute, publish_folders=a.publish)
    except (FileNotFoundError, ValueError) as e:
        p.error(str(e))
    print(f"wrote {len(pages)} pages: {', '.join(str(p) for p in pages)}")

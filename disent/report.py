"""Regenerate ``reports/README.md`` and its figures from run folders and measured JSON.

``python -m disent.report`` (or ``disent-report``) reads

* run folders under ``outputs/`` and ``multirun/`` (:mod:`disent.runs`),
* ``reports/eval/*.json`` from :mod:`disent.eval.protocols` and :mod:`disent.eval.stability`
  (``--compute`` runs both first),
* ``reports/bench.json`` (``python -m disent.bench``) and ``reports/lighting/``,

and writes one Markdown report with PNG figures under ``reports/figures/``.  Every figure is
drawn from run data; whatever is missing becomes a note in the report, never a crash.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import re
import shutil
import subprocess
import traceback
from pathlib import Path

import numpy as np
import torch

from disent.eval import ablation as _ablation
from disent.eval.metrics import FLAT_SHARE, normals_collapsed
from disent.eval.trivial import TEMPLATE_KEYS
from disent.images import over_max, to_array
from disent.runs import (
    RUN_ROOTS,
    Run,
    find_runs,
    group_by_setting,
    joins,
    machine_text,
    pick_runs,
    publish,
    record_run,
    retyped_label,
    setting,
    tool_folder,
)
from disent.runs import defining_overrides as _overrides

MODELS = ("baseline", "explicit", "implicit")
TRAIN_SPEED_KEY = "images_per_s"  # logged by every training step (metrics.jsonl)
INFER_SPEED_KEY = "infer_images_per_s"  # eval.json


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _load_json(path: Path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def _speed(run: Run, key: str) -> float | None:
    """Median of the values logged under ``key`` (training speed is logged per step), else eval.json's."""
    logged = sorted(r[key] for r in run.metrics if isinstance(r.get(key), (int, float)))
    if logged:
        return float(logged[len(logged) // 2])
    v = run.value(key)
    return None if v is None else float(v)


def _rel(path: Path, out: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(out.resolve()))
    except ValueError:
        return str(path)


class Report:
    """Markdown assembled section by section; each section survives the others' failures."""

    def __init__(self, out: Path, previous: str = "", only=None):
        self.out = Path(out)
        self.only = set(only) if only else None  # section names (sec_NAME) to build; the others are kept
        self.fig = self.out / "figures"
        self.fig.mkdir(parents=True, exist_ok=True)
        self.lines: list[str] = []
        self.previous = published_sections(previous)  # what is published now, by section title
        self.title = ""  # the section being built
        self.kept_rows = 0  # rows of the published section kept by rows_kept in the section being built

    def add(self, *lines: str) -> None:
        self.lines.extend(lines)

    def note(self, text: str) -> None:
        self.lines.append(f"{MISSING} {text}\n")

    def image(self, path: Path, alt: str) -> None:
        self.lines.append(f"![{alt}]({_rel(path, self.out)})\n")

    def figure(self, fig, name: str, alt: str) -> None:
        """Lay out ``fig``, save it as ``figures/<name>``, close it and show it here."""
        fig.tight_layout()
        path = self.fig / name
        fig.savefig(path, dpi=120)
        _plt().close(fig)
        self.image(path, alt)

    def section(self, title: str, fn, *args) -> None:
        """``## title`` and what ``fn`` adds.  Where ``fn`` finds only missing inputs (or fails) but the
        published report has content for the section, that content is kept, marked as such."""
        self.add(f"## {title}\n")
        self.title, self.kept_rows = title, 0
        start = len(self.lines)
        old = self.previous.get(title, [])
        if self.only is not None and section_name(fn) not in self.only and old:
            self.lines += [f"{KEPT} as published before; not rebuilt in this build (`--sections`)\n"]
            self.lines += [line for line in old if not line.startswith(KEPT)]
            return
        try:
            fn(self, *args)
        except Exception as e:  # a broken section is reported, the rest of the report still builds
            self.note(f"this section failed: `{type(e).__name__}: {e}`")
            traceback.print_exc()
        if self.kept_rows:
            self.add(f"_{KEPT_ROW}: {KEPT_ROW_TEXT}_\n")
        new = self.lines[start:]
        if all(line.startswith(MISSING) for line in new) and any(not line.startswith((MISSING, KEPT)) for line in old):
            why = " ".join(line[len(MISSING) :].strip() for line in new)
            self.lines[start:] = [f"{KEPT} as published before; its inputs are missing in this build ({why})\n"] + [
                line for line in old if not line.startswith(KEPT)
            ]

    def rows_kept(self, head: str, rows: list[str], key: int = 1, unless: str | None = None) -> list[str]:
        """``rows`` of a table with header line ``head``, then the rows of the published table under the same
        header in this section whose first ``key`` cells match none of ``rows`` (and that do not contain
        ``unless``): an earlier build measured them on runs this build does not have.  Those are marked
        :data:`KEPT_ROW` (a note under the section says why)."""

        def key_of(line):
            return tuple(retyped_cell(c.replace(KEPT_ROW, "")) for c in line.strip().strip("|").split("|")[:key])

        have = {key_of(r) for r in rows}
        kept = []
        for block in self.previous.get(self.title, []):
            lines = block.rstrip("\n").split("\n")
            if lines[0] == head:
                kept += [
                    line
                    for line in lines[2:]
                    if line.startswith("|") and key_of(line) not in have and not (unless and unless in line)
                ]
        for i, line in enumerate(kept):
            cells = [f" {retyped_cell(c)} " if c.strip().startswith("`") else c for c in line.split("|")]
            if KEPT_ROW not in cells[1]:
                cells[1] = f"{cells[1].rstrip()} {KEPT_ROW} "
            kept[i] = "|".join(cells)
        self.kept_rows += len(kept)
        return [*rows, *kept]

    def subsections_kept(self, start: int) -> None:
        """Append the published ``###`` subsections of this section whose headings ``self.lines[start:]`` lack
        (an earlier build measured them on runs this build does not have), their headings marked :data:`KEPT_ROW`."""

        def heading(block):
            head = block.split("\n")[0].replace(KEPT_ROW, "").strip()
            return f"### {retyped_cell(head[4:])}" if head.startswith("### `") else head

        have = {heading(line) for line in self.lines[start:] if line.startswith("### ")}
        groups: list[list[str]] = []
        for block in self.previous.get(self.title, []):
            if block.startswith("### "):
                groups.append([block])
            elif groups and not block.startswith(f"_{KEPT_ROW}:"):
                groups[-1].append(block)
        for head, *body in groups:
            if heading(head) not in have:
                self.add(f"{heading(head)} {KEPT_ROW}\n", *body)
                self.kept_rows += 1


def retyped_cell(cell: str) -> str:
    """A table cell or heading that names a setting (```+experiment=long train.max_steps=10000```), read against
    today's ``conf/`` (:func:`disent.runs.retyped_label`): a row an earlier build published under a default since
    changed then matches the row this build writes for the same runs.  Any other cell, stripped."""
    text = cell.strip()
    inner = text[1:-1] if len(text) > 2 and text[0] == text[-1] == "`" else None
    if inner is None or not all("=" in w or w == "(defaults)" for w in inner.split()):
        return text
    return f"`{retyped_label(inner)}`"


MISSING, KEPT = "> **Missing:**", "> **Kept:**"
KEPT_ROW = "‡"
KEPT_ROW_TEXT = (
    "as an earlier build published it; its runs are not among this build's inputs (their folders are gone and "
    "they left no record in `reports/runs/`)"
)
PROVENANCE = ("sections", "built", "from", "regenerate")  # the header's table: one row per build still shown


def provenance_row(sections: list[str], built: str, source: str, command: str) -> str:
    """One build's row of the header's table (``sections``: what it built that no later build rebuilt)."""
    return f"| {', '.join(sections)} | {built} | {source} | `{command}` |"


def kept_provenance(previous: str, rebuilt: list[str]) -> list[str]:
    """The rows of ``previous``'s provenance table that still describe a section after a ``--sections rebuilt``
    build: each row less the sections rebuilt now, its command rewritten to build only what it has left; a row
    goes once none is left."""
    kept = []
    for line in previous.split("\n## ")[0].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if not line.startswith("| ") or len(cells) != len(PROVENANCE) or cells[0] == PROVENANCE[0]:
            continue
        left = [s for s in cells[0].split(", ") if s not in rebuilt]
        if left:
            command = re.sub(r" --compute| --sections [\w ]+", "", cells[3].strip("`"))
            kept.append(provenance_row(left, cells[1], cells[2], f"{command} --sections {' '.join(left)}"))
    return kept


def section_name(fn) -> str:
    """A section's name for ``--sections``: its function's, less ``sec_`` (``sec_claims``: ``claims``)."""
    return fn.__name__.removeprefix("sec_")


def published_sections(markdown: str) -> dict[str, list[str]]:
    """``{title: lines}`` of a report written by :class:`Report` (each ``## title`` up to the next)."""
    sections, title = {}, None
    for block in markdown.split("\n## ")[1:]:
        head, _, body = block.partition("\n")
        title = head.strip()
        sections[title] = [b + "\n" for b in body.strip("\n").split("\n\n") if b.strip()]
    return sections


# ----------------------------------------------------------------------------- pictures from models
def _grid(rows: list[tuple[str, torch.Tensor]], path: Path, title: str) -> None:
    """One row per named ``[N,C,H,W]`` tensor, N columns."""
    plt = _plt()
    n = rows[0][1].shape[0]
    fig, axes = plt.subplots(len(rows), n, figsize=(1.2 * n + 1, 1.2 * len(rows)), squeeze=False)
    for i, (name, t) in enumerate(rows):
        for j in range(n):
            ax = axes[i, j]
            ax.imshow(to_array(t[j], "normal" if name.startswith("normal") else "rgb"), interpolation="nearest")
            ax.set_xticks([]), ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _test_batch(n: int, resolution: int = 64):
    from disent.data import SynthFaces
    from disent.eval.evaluate import batches

    return next(iter(batches(SynthFaces(split="test", resolution=resolution, seed=0), n, n)))


def _models(chosen: dict) -> dict:
    """``{name: model}`` of ``{name: run or shipped name}`` (:func:`disent.models.load_run`)."""
    from disent.models import load_run

    out = {}
    for name, r in chosen.items():
        model, _ = load_run(r.path if isinstance(r, Run) else r)
        out[name] = model.eval()
    return out


# ----------------------------------------------------------------------------- sections
ERROR_WHITE = 40.0  # degrees of angular error drawn white in the normals figure
RUNG = ("model=", "+experiment=", "experiment=")  # a run of the budget ladder sets only these
MIN_SEEDS = 3  # a verdict needs at least this many seeds per arm
EDIT_WORKS = 0.5  # an edit works where at least this share of the edited faces reads as having the attribute


def _spread(runs: list[Run], key: str) -> dict | None:
    """Mean, std and count over ``runs`` of one metric (:func:`disent.eval.ablation.mean_std`)."""
    return _ablation.mean_std([r.value(key) for r in runs])


def table_head(*columns: str) -> tuple[str, str]:
    """A Markdown table's header line and its separator, one column each."""
    return "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)


def _fmt(value, fmt: str) -> str:
    return "–" if value is None else f"{value:{fmt}}"


def _ms(st, fmt=".2f", count: bool = True) -> str:
    """``mean ± std (n=N)`` of a :func:`_spread`; without the count where the table has a seeds column."""
    if st is None:
        return "–"
    n = f" (n={st['n']})" if count else ""
    if st["n"] == 1:
        return f"{st['mean']:{fmt}}{n}"
    return f"{st['mean']:{fmt}} ± {st['std']:{fmt}}{n}"


def measured_setting(info: dict, loaded: dict | None = None) -> str | None:
    """The setting of a run that a tool measured (its ``run`` folder and ``setting``), read against today's
    ``conf/`` from the run's folder or record (``loaded``: the report's runs by origin, so none is read twice);
    ``shipped`` for a shipped model.  None where neither is left: the setting the tool wrote was read against
    the ``conf/`` of its day, which may have changed since (its published rows are kept instead)."""
    folder = Path(str(info.get("run", "")))
    if info.get("setting") in (None, "shipped"):
        return info.get("setting", "shipped")
    run = (loaded or {}).get(folder.resolve())
    if run is None and (folder / ".hydra" / "config.yaml").is_file():
        run = Run.load(folder)
    return setting(run, drop_model=True) if run is not None else None


def on_the_ladder(run: Run) -> bool:
    """A plain run of a budget rung (``smoke``, the defaults, ``long``): no override beyond model and experiment."""
    return all(o.startswith(RUNG) for o in _overrides(run))


def ladder_runs(runs: list[Run]) -> list[Run]:
    """The finished plain runs of the budget ladder (no ablation, no override beyond model and experiment)."""
    return [r for r in runs if r.status == "ok" and r.eval and not r.ablations and on_the_ladder(r)]


def machines(runs: list[Run]) -> str:
    """The machines ``runs`` trained on (their ``machine.json``), for a caption."""
    seen = sorted({machine_text(r.machine) for r in runs if r.machine})
    older = sum(1 for r in runs if not r.machine)
    text = "; ".join(seen) if seen else "not recorded"
    return text + (f" ({older} run(s) from before machines were recorded)" if seen and older else "")


def verdict(a, b, better: str) -> str:
    """Whether arm ``a`` beats arm ``b`` (``better``: "lower" or "higher"; each a :func:`_spread`): confirmed
    or refuted where the difference exceeds both arms' seed spread, else not resolved; not testable with fewer
    than ``MIN_SEEDS`` seeds in an arm."""
    if a is None or b is None:
        return "not testable (no runs)"
    if min(a["n"], b["n"]) < MIN_SEEDS:
        return f"not testable ({min(a['n'], b['n'])} seed(s); {MIN_SEEDS} needed)"
    diff = (b["mean"] - a["mean"]) if better == "lower" else (a["mean"] - b["mean"])
    if abs(diff) <= max(a["std"], b["std"]):
        return "not resolved (difference within the seed spread)"
    return "**confirmed**" if diff > 0 else "**refuted**"


# The trainable-models targets by rung: the default rung's absolute ones (TARGETS), the long rung's normals 15 %
# better than the pseudo-GT they were supervised by (the paper's "beyond the morphable model" claim, with a margin)
LONG_NORMALS_SHARE_OF_PSEUDO = 0.85


TEMPLATE_LABELS = ("albedo si-MSE", "one scale for RGB", "one scale per channel for all faces")  # of TEMPLATE_KEYS


def sec_targets(rep: Report, runs: list[Run]) -> None:
    """At a glance: each model of the budget ladder against its rung's targets and its floors (mean ± std over seeds);
    a layer is learned only where it beats its floor, the dataset-mean map."""
    groups: dict = {}
    for r in ladder_runs(runs):
        groups.setdefault((setting(r, drop_model=True), r.model), []).append(r)
    head = table_head(
        "setting",
        "model",
        "seeds",
        "normals (deg)",
        "mean map / pseudo-GT (deg)",
        "face PSNR (dB)",
        "albedo / mean map's",
        "targets missed",
    )
    rows = []
    for (where, model), rs in sorted(groups.items()):
        normal, pseudo, floor = (_spread(rs, k) for k in ("normal_mean", "pseudo_normal_mean", "trivial_normal_mean"))
        psnr, share = _spread(rs, "recon_face_psnr"), albedo_share(rs)
        misses = []
        if where == "(defaults)" and model != "baseline":
            misses = budget_misses(rs) or []
        elif where == "+experiment=long" and normal and pseudo:
            goal = LONG_NORMALS_SHARE_OF_PSEUDO * pseudo["mean"]
            misses = [f"normals (<= {goal:.2f})"] if normal["mean"] > goal else []
            if model != "baseline":  # the ablations' budget check holds every budget to the default rung's targets
                misses += [f"default rung's {m}" for m in budget_misses(rs) or []]
        elif model != "baseline":
            misses = ["(no targets at this setting)"]
        rows.append(
            f"| `{where}` | {model} | {len(rs)} | {_ms(normal)} | "
            f"{_fmt(normal and floor and floor['mean'], '.2f')} / {_fmt(pseudo and pseudo['mean'], '.2f')} | "
            f"{_ms(psnr)} | "
            f"{_fmt(share, '.2f')} | {'; '.join(misses) if misses else ('none' if model != 'baseline' else '–')} |"
        )
    if not rows:
        rep.note("no finished runs of the budget ladder (`python -m disent model=MODEL seed=N`).")
        return
    rep.add(
        "The budget ladder's runs against the targets of a trainable recipe: at the default rung normals <= "
        f"{TARGETS['normal_mean']} deg, face PSNR >= {TARGETS['recon_face_psnr']} dB and albedo scale-invariant "
        f"error <= {TARGETS['albedo_share_of_trivial']} of the dataset-mean map's; at the long rung normals "
        f"{1 - LONG_NORMALS_SHARE_OF_PSEUDO:.0%} better than the pseudo-GT that supervised them, and the default "
        "rung's targets too, which the ablation tables' budget check applies at every budget. A layer counts as "
        "learned only where it beats its floor, the dataset-mean map (its error beside it). Test split, mean ± std "
        "over seeds; the floor-and-ceiling section says what the same network reaches on the true layers.\n",
        *head,
        *rep.rows_kept(head[0], rows, key=2),
        "",
    )
    template_rows = [
        f"| `{where}` | {model} | "
        + " | ".join(
            f"{_ms(_spread(rs, key), '.4f')} / {_spread(rs, f'template_{key}')['mean']:.4f} / "
            f"{_spread(rs, f'trivial_{key}')['mean']:.4f}"
            for key in TEMPLATE_KEYS
        )
        + " |"
        for (where, model), rs in sorted(groups.items())
        if all(_spread(rs, f"template_{key}") and _spread(rs, key) for key in TEMPLATE_KEYS)
    ]
    head = table_head(
        "setting", "model", *(f"{label}: network / placed mean texture / mean map" for label in TEMPLATE_LABELS)
    )
    if template_rows := rep.rows_kept(head[0], template_rows, key=2):
        rep.add(
            "A stronger floor for the albedo: the *placed mean texture*, the mean train albedo in UV space put on each "
            "test face through its true uv (`disent.eval.trivial.template_albedo`). It knows where the face's eyes, "
            "brows and lips are and nothing of whose face it is, so an albedo that beats the mean map but not this "
            "floor has learned where the face is, not what it looks like. Three scorings: a scale per image and "
            "channel (the targets' measure), one scale per image for R, G and B (the skin's colour must be in the "
            "albedo), one scale per channel for the whole test set (each face's brightness must be too).\n",
            *head,
            *template_rows,
            "",
        )
    if not any(where == "+experiment=long" for where, _ in groups):
        rep.add(
            "_No run of the long rung is among this build's inputs (runs from before `reports/runs/` kept records "
            "left none): its numbers are the kept rows of claims 1 and 3._\n"
        )


def beyond_the_fit(groups: dict) -> list[str]:
    """Claim 1 pixel by pixel: the network's and the pseudo-GT's normal error where the pseudo-GT errs by each
    range of :data:`disent.eval.evaluate.PSEUDO_ERROR_BINS` (``groups``: ``{(setting, model): runs}``; runs
    scored before the bins were kept show none)."""
    from disent.eval.evaluate import PSEUDO_ERROR_BINS

    bins = [f"{lo}_{hi}" for lo, hi in zip(PSEUDO_ERROR_BINS, PSEUDO_ERROR_BINS[1:])]
    rows, readings = [], []
    for (where, model), rs in sorted(groups.items()):
        cells, side = [], {"beats": [], "loses to": []}
        for b in bins:
            keys = (f"normal_mean_where_pseudo_{b}", f"pseudo_normal_mean_where_pseudo_{b}", f"share_where_pseudo_{b}")
            net, pseudo, share = (_spread(rs, k) for k in keys)
            if model in ("explicit", "implicit") and net and pseudo and share:
                cells.append(f"{_ms(net)} / {pseudo['mean']:.2f} ({100 * share['mean']:.0f} %)")
                if abs(net["mean"] - pseudo["mean"]) > net["std"]:  # beyond the seed spread
                    side["beats" if net["mean"] < pseudo["mean"] else "loses to"].append(b.replace("_", "-"))
        if len(cells) == len(bins):
            rows.append(f"| `{where}` | {model} | " + " | ".join(cells) + " |")
            found = [f"{how} the pseudo-GT where that errs by {', '.join(bs)} deg" for how, bs in side.items() if bs]
            readings.append(f"- `{where}`: the network {'; it '.join(found) or 'ties the pseudo-GT in every bin'}.")
    if not rows:
        return []
    return [
        "Where it goes beyond: the scored pixels binned by the pseudo-GT's own error against the truth; in each bin "
        "the network's error (mean ± std over seeds) / the pseudo-GT's (deg), and the bin's share of the pixels "
        "(`disent.eval.evaluate.PSEUDO_ERROR_BINS`; runs scored before these bins: "
        "`python -m disent.eval.evaluate RUN` rescores them).\n",
        *table_head("setting", "model", *(f"pseudo-GT off by {b.replace('_', '-')} deg" for b in bins)),
        *rows,
        "",
        *readings,
    ]


def lower_than_fixed(*pairs: tuple) -> str:
    """One verdict over ``(spread over seeds, a deterministic estimator's value)`` pairs: the network lower on
    each (:func:`verdict`), or ``mixed`` naming the verdicts where they differ."""
    verdicts = {verdict(net, {"mean": fixed, "std": 0.0, "n": net["n"]}, "lower") for net, fixed in pairs}
    return verdicts.pop() if len(verdicts) == 1 else "mixed: " + " / ".join(sorted(verdicts))


def shown_variance_table(rep: Report, groups: dict, est: dict) -> list[str]:
    """Claim 2 on the light the faces show: per ``(model, setting)`` group of the SH-variance protocol's rows, the
    within-condition variance and the error in the SH directions a face shows
    (:func:`disent.eval.protocols.sh_variance_shown_hidden`), against L-hat's and the mean light's."""
    ls, mean_light = est.get("ls_pseudo") or {}, est.get("mean_light") or {}
    if "variance_shown" not in ls:
        return []
    head = table_head(
        "model", "setting", "shown variance", "L-hat", "mean light", "shown SH error", "L-hat", "mean light", "verdict"
    )
    rows = []
    for (model, where), measured in sorted(groups.items()):
        measured = [r for r in measured if "variance_shown" in r]
        if not measured:
            continue
        var, err = (_ablation.mean_std([r[k] for r in measured]) for k in ("variance_shown", "sh_error_shown"))
        rows.append(
            f"| {model} | `{where}` | {_ms(var, '.3f')} | {ls['variance_shown']:.3f} | "
            f"{mean_light.get('variance_shown', float('nan')):.3f} | {_ms(err, '.3f')} | {ls['sh_error_shown']:.3f} | "
            f"{mean_light.get('sh_error_shown', float('nan')):.3f} | "
            f"{lower_than_fixed((var, ls['variance_shown']), (err, ls['sh_error_shown']))} |"
        )
    if not (rows := rep.rows_kept(head[0], rows, key=2)):
        return []
    return [
        "The same protocol on the light the faces show: a face's normals cover part of the sphere, so L-hat's "
        "least squares spreads freely along the SH directions its shading hides, and a lower variance there says "
        "nothing about the light. Within-condition variance and SH error in the shown directions "
        "(`variance_shown`, `sh_error_shown`; each estimate scaled to the truth in shading, a share of the true "
        "light's squared norm), against L-hat's and the constant mean light's (whose only spread is its scale). "
        "Confirmed where the network is lower than L-hat on both beyond its seed spread.\n",
        *head,
        *rows,
        "",
    ]


def shown_hidden_lines(runs: list[Run]) -> list[str]:
    """Claim 2's reading of the SH error split by what a face shows (``sh_error_shown`` / ``sh_error_hidden``),
    per model over the runs scored with it, beside the mean light and L-hat on the same images."""
    scored = [r for r in runs if r.value("sh_error_shown") is not None]
    if not scored:
        return []
    parts, learned = [], []
    mean_light = _spread(scored, "trivial_sh_error_shown")
    for label, rs, prefix in (
        *((model, [r for r in scored if r.model == model], "") for model in ("explicit", "implicit")),
        ("the mean light", scored, "trivial_"),
        ("L-hat", scored, "pseudo_"),
    ):
        shown, hidden = (_spread(rs, f"{prefix}sh_error_{k}") for k in ("shown", "hidden"))
        if shown is not None:
            parts.append(f"{label} {_ms(shown, '.3f')} shown / {_ms(hidden, '.3f')} hidden")
            if not prefix:
                learned.append(f"{label} {verdict(shown, mean_light, 'lower')}")
    return [
        "- The SH error split by what the face shows (`sh_error_shown` / `sh_error_hidden`, test split, relative to "
        "the true light; `disent.eval.metrics.sh_error_shown_hidden`): a face's normals cover part of the sphere, "
        "so the SH directions whose shading over the face carries under 1 % of the largest direction's energy (on "
        "frontal normals ambient, n_z and 3 n_z^2 - 1 are nearly collinear, as are n_y and n_y n_z) are hidden from "
        "any image of it; the scale is read from the shading. "
        + "; ".join(parts)
        + ". A light counts as learned where its shown error beats the mean light's (over the seeds, beyond their "
        "spread): "
        + ", ".join(learned)
        + "; the hidden part is a guess that only a prior (the mean light's) can make well."
    ]


def background_lines(measured: list[tuple]) -> list[str]:
    """The edits made through the background code (``python -m disent.edit measure RUN --background``): per model,
    attribute and method, the best success of the manifold sets with the background code against those without."""
    lines = []
    for model, where, res in measured:
        best: dict = {}  # (attribute, method) -> {with background: best success}
        for c in res["claims"]:
            cell, with_bg = best.setdefault((c["attribute"], c["method"]), {}), "bg" in c["manifolds"].split("+")
            cell[with_bg] = max(cell.get(with_bg, 0.0), c["best_success"])
        cells = [
            f"{attribute} by {method}: {v[True]:.2f} with it, {v[False]:.2f} with the face codes alone"
            for (attribute, method), v in best.items()
            if {True, False} <= set(v)
        ]
        if cells:
            lines.append(f"- {model} (`{where}`): " + "; ".join(cells) + ".")
    if not lines:
        return []
    return [
        "Outside the face: the same measurement with the background code among the manifold sets "
        "(`python -m disent.edit measure RUN --background`; best success). An edit the face codes cannot make but "
        "the background code can is one the reader sees outside the face, in what the model draws as background "
        "(SynthFaces greys a senior face's hair).\n",
        *lines,
        "",
    ]


def sec_claims(rep: Report, runs: list[Run], eval_dir: Path) -> None:
    """The paper's claims, each with its numbers (mean ± std over seeds, grouped by setting) and a verdict."""
    done = ladder_runs(runs)
    loaded = {r.origin: r for r in runs}  # for the tools' records of these runs
    if not done:
        rep.note(
            "no finished runs of the plain models; train them (`python -m disent -m model=baseline,explicit,"
            "implicit seed=0,1,2`) and run the report again."
        )
        return
    rep.add(
        f"Each verdict needs {MIN_SEEDS} seeds per arm and a difference larger than the arms' seed spread "
        "(std). Runs of the budget ladder only (the defaults, `+experiment=long`; no other override), grouped by "
        "their *setting*: what one types today to train them again, apart from the seed and the time guard (the "
        "config groups, and each run-defining value that differs from today's `conf/`, so runs trained before a "
        "default changed show the old value). Trained on: "
        f"{machines(done)}.\n"
    )
    head = table_head("setting", "model", "network normals (deg)", "pseudo-GT (deg)", "mean map (deg)", "verdict")
    groups: dict = {}
    for r in done:
        groups.setdefault((setting(r), r.model), []).append(r)
    rows = []
    for (where, model), rs in sorted(groups.items()):
        if model not in ("explicit", "implicit"):
            continue
        net, pseudo, mean = (_spread(rs, k) for k in ("normal_mean", "pseudo_normal_mean", "trivial_normal_mean"))
        rows.append(
            f"| `{where}` | {model} | {_ms(net)} | {_ms(pseudo)} | {_ms(mean)} | {verdict(net, pseudo, 'lower')} |"
        )
    rep.add(
        "### 1. The network's normals go beyond the morphable-model fit that supervised them\n",
        *head,
        *rep.rows_kept(head[0], rows, key=2),
    )
    rep.add("", *beyond_the_fit(groups))
    rep.add("", "### 2. The network's light varies less across identities under one light than L-hat\n")
    shv = _load_json(eval_dir / "sh_variance.json")
    if shv:
        est = shv["estimators"]
        trivial = _spread(done, "trivial_sh_error")
        runs_of = shv.get("runs") or {m: {"model": m, "setting": "one run a model"} for m in ("explicit", "implicit")}
        groups: dict = {}  # (model, setting) -> the protocol's rows of its trained models (seeds)
        for name, info in runs_of.items():
            where = measured_setting(info, loaded)
            if name in est and where is not None:
                groups.setdefault((info["model"], where), []).append(est[name])
        ls = est.get("ls_pseudo")
        head = table_head("model", "setting", "relative variance", "L-hat", "SH error", "L-hat", "verdict")
        rows = []
        for (model, where), measured in sorted(groups.items()) if ls else ():
            rel, err = (_ablation.mean_std([r[k] for r in measured]) for k in ("relative", "sh_error"))
            rows.append(
                f"| {model} | `{where}` | {_ms(rel, '.3f')} | {ls['relative']:.3f} | {_ms(err, '.3f')} | "
                f"{ls['sh_error']:.3f} | {lower_than_fixed((rel, ls['relative']), (err, ls['sh_error']))} |"
            )
        if rows := rep.rows_kept(head[0], rows, key=2):
            rep.add(
                "Relative variance and SH error on the light bank (`python -m disent.eval.protocols --every-run`), "
                "mean ± std over the trained models of a setting, against L-hat's (a deterministic fit: no "
                "spread). Confirmed where the network is lower on both beyond its seed spread.\n",
                *head,
                *rows,
            )
        rep.add("", *shown_variance_table(rep, groups, est))
        if trivial:
            rep.add(
                f"- The constant mean light scores SH error {trivial['mean']:.3f} on the test split: lower variance "
                "than L-hat is not by itself evidence of a learned light (section *Lighting stability*)."
            )
        rep.add(*shown_hidden_lines(done))
        rep.add("")
    else:
        rep.note("`reports/eval/sh_variance.json`; run `python -m disent.eval.protocols` and publish it.")
    head = table_head(
        "setting",
        "baseline face PSNR",
        "explicit",
        "implicit",
        "explicit > baseline",
        "implicit > baseline",
        "implicit > explicit (face SSIM: baseline / explicit / implicit)",
    )
    rows = []
    across: dict = {}
    for where, rs in group_by_setting(done).items():
        for r in rs:
            across.setdefault(where, {}).setdefault(r.model, []).append(r)
    for where, by_model in sorted(across.items()):
        if "baseline" not in by_model or not ({"explicit", "implicit"} & set(by_model)):
            continue
        psnr = {m: _spread(by_model.get(m, []), "recon_face_psnr") for m in ("baseline", "explicit", "implicit")}
        ssim = {m: _spread(by_model.get(m, []), "recon_face_ssim") for m in ("baseline", "explicit", "implicit")}
        rows.append(
            f"| `{where}` | {_ms(psnr['baseline'])} | {_ms(psnr['explicit'])} | {_ms(psnr['implicit'])} | "
            f"{verdict(psnr['explicit'], psnr['baseline'], 'higher')} | "
            f"{verdict(psnr['implicit'], psnr['baseline'], 'higher')} | "
            f"{verdict(ssim['implicit'], ssim['explicit'], 'higher')} "
            f"({' / '.join(_ms(ssim[m], '.3f') for m in ('baseline', 'explicit', 'implicit'))}) |"
        )
    rep.add(
        "### 3. The rendering models reconstruct better than the 265-d baseline; the implicit one more sharply\n",
        *head,
        *rep.rows_kept(head[0], rows),
    )
    rep.add("", "### 4. BWS prevents degenerate shading; each prior does what the paper says\n")
    claim_ablations(rep, runs)
    claim_skin(rep, runs)
    rep.add("### 5. Edits on the paper's manifolds change the attribute with less leakage than other manifolds\n")
    groups: dict = {}  # (model, setting) -> the edit results of its trained models (seeds)
    outside = []  # the --background diagnostics: (model, setting, result)
    for p in sorted((eval_dir.parent / "edit").glob("*/edit.json")):
        res = _load_json(p)
        where = measured_setting(res, loaded) if res and res.get("claims") else None
        if where is not None and res.get("background"):
            outside.append((res.get("model", p.parent.name), where, res))
        elif where is not None:
            groups.setdefault((res.get("model", p.parent.name), where), []).append(res)
    head = table_head(
        "model",
        "setting",
        "method",
        "attribute",
        "paper's manifolds: gain per leakage",
        "best other",
        "best success",
        "verdict",
    )
    rows, idle, relit = [], [], []
    for (model, where), results in sorted(groups.items()):
        cells: dict = {}  # (method, attribute) -> manifolds -> [(gain per leak, best success)] over models
        for res in results:
            for c in res["claims"]:
                cells.setdefault((c["method"], c["attribute"]), {}).setdefault(c["manifolds"], []).append(
                    (c["gain_per_leak"], c["best_success"])
                )
        cannot = []  # the edits no manifold set makes: (attribute, method, best success)
        for (method, attribute), sets in cells.items():
            stats = {m: _ablation.mean_std([g for g, _ in v]) for m, v in sets.items()}
            paper = next((m for m in sets if str(m).startswith("paper:")), None)
            if paper is None:
                continue
            others = [m for m in sets if m != paper]
            rival = max(others, key=lambda m: stats[m]["mean"]) if others else None
            success = max(_ablation.mean_std([s for _, s in v])["mean"] for v in sets.values())
            if success < EDIT_WORKS:  # listed under the table: no verdict to read
                cannot.append((attribute, method, success))
                continue
            rows.append(
                f"| {model} | `{where}` | {method} | {attribute} | {paper[6:]}: {_ms(stats[paper], '.3g')} | "
                f"{rival}: {_ms(stats[rival], '.3g') if rival else '–'} | {success:.2f} | "
                f"{verdict(stats[paper], stats[rival] if rival else None, 'higher')} |"
            )
        if cannot:
            ceiling = []  # how often the model's reconstruction of faces that have the attribute reads as it
            for attribute in dict.fromkeys(a for a, _, _ in cannot):
                rates = {
                    m: _ablation.mean_std(
                        [
                            r["success"]
                            for res in results
                            for r in res.get("traversal") or []
                            if r["attribute"] == attribute and r["method"] == m
                        ]
                    )
                    for m in ("truth reconstructed", "truth")
                }
                if all(rates.values()):
                    ceiling.append(
                        f"{attribute} {rates['truth reconstructed']['mean']:.2f} (truth {rates['truth']['mean']:.2f})"
                    )
            idle.append(
                f"| {model} | `{where}` | {', '.join(f'{a} by {m} {v:.2f}' for a, m, v in cannot)} | "
                f"{', '.join(ceiling) or '–'} |"
            )
        faces = [{r["method"]: r["psnr_face"] for r in res.get("relight") or []} for res in results]
        faces = [f for f in faces if {"transfer", "ratio", "input"} <= set(f)]
        if faces:

            def col(fn):
                return _ms(_ablation.mean_std([fn(f) for f in faces]))

            relit.append(
                f"| {model} | `{where}` | {col(lambda f: f['transfer'])} | {col(lambda f: f['ratio'])} | "
                f"{col(lambda f: f.get('decode', float('nan')))} | {col(lambda f: f['input'])} | "
                f"{col(lambda f: f['transfer'] - f['input'])} | {col(lambda f: f['transfer'] - f['ratio'])} |"
            )
    idle_head = table_head(
        "model",
        "setting",
        "edits no manifold set makes (attribute by method: best success)",
        "faces that have it, reconstructed, read as it",
    )
    relit_head = table_head(
        "model", "setting", "transfer", "ratio", "decode", "input", "transfer - input", "transfer - ratio"
    )
    rows, idle, relit = (
        rep.rows_kept(h[0], r, key=k) for h, r, k in ((head, rows, 4), (idle_head, idle, 2), (relit_head, relit, 2))
    )
    if not (rows or idle or relit):
        rep.note(
            "`reports/edit/*/edit.json`; run `python -m disent.edit measure explicit` (and `implicit`, or run "
            "folders), then publish its folder."
        )
        return
    rep.add(
        "Attribute gain per unit leakage over the strengths of each method (`python -m disent.edit measure RUN`, "
        "16 source faces per attribute), mean ± std over the trained models (seeds) of a setting; the paper's "
        "manifolds against the best other manifold set of the same model kind and method. A verdict needs "
        f"{MIN_SEEDS} models and a difference beyond the spread, and is read only where some manifold set makes the "
        f"edit (best success, the share of edited faces read as having the attribute, >= {EDIT_WORKS} on average). "
        "`shipped`: the shipped long-budget weights.\n",
        *head,
        *rows,
        "",
    )
    if idle:
        rep.add(
            f"Not testable, no manifold set makes the edit (best success < {EDIT_WORKS}). Last column: the share of "
            "the model's reconstructions of the same faces with the attribute truly on that the reader calls "
            "positive (beside the true images' share, the reader's recall): an edit reads as the attribute no "
            "more often than the model can draw it, so a low share says the decoder cannot draw the attribute, "
            "and a high one that the traversal, not the decoder, fails.\n",
            *idle_head,
            *idle,
            "",
        )
    rep.add(*background_lines(outside))
    rep.add(
        "### Relighting with detailed albedo (Sec. 5.3)\n",
        "PSNR (dB) on the face against the generator's own render of the face under the source light, "
        "8 faces x 6 lights per model, mean ± std over the models of a setting: *transfer* (detailed albedo), the "
        "naive *ratio* image, *decode* (the network re-rendered with the new light), and the unrelit *input* as "
        "the floor.\n",
        *relit_head,
        *relit,
        "",
    )


def sec_runs(rep: Report, runs: list[Run]) -> None:
    if not runs:
        rep.note(
            "no run folders under `outputs/` or `multirun/`. Train with `python -m disent` or run the "
            "suite (`ablations/README.md`), then run `python -m disent.report` again."
        )
        return
    cols = (
        "recon_mse",
        "recon_face_psnr",
        "normal_mean",
        "trivial_normal_mean",
        "pseudo_normal_mean",
        "albedo_si_mse",
        "trivial_albedo_si_mse",
        "sh_error",
        "trivial_sh_error",
        "light_shading_si_mse",
        "trivial_light_shading_si_mse",
    )

    def f(v):
        return "–" if v is None else f"{v:.4g}"

    head = table_head("run", "variant", "seed", "status", "train img/s", "infer img/s", *cols)
    rows = [
        f"| `{r.origin}` | {r.variant} | {r.seed} | {r.status} | {f(_speed(r, TRAIN_SPEED_KEY))} | "
        f"{f(_speed(r, INFER_SPEED_KEY))} | " + " | ".join(f(r.value(c)) for c in cols) + " |"
        for r in runs
    ]
    rep.add(*head, *rep.rows_kept(head[0], rows, unless="| incomplete |"))  # a running job's row is not kept
    rep.add(
        "",
        "_`trivial_*`: the dataset-mean normal map, albedo map and light on the same test images "
        "(`disent/eval/trivial.py`); a layer counts as learned only where it beats them. Normals, albedo and "
        "`light_shading_si_mse` (the light's shading through the true normals) are scored on the face inside "
        "the pseudo mask, the model's own foreground; `sh_error` on the 27 SH coefficients, including the "
        "directions a face's normals cannot reveal._\n",
    )


CEILING_COLUMNS = (
    ("normal_mean", "normals (deg)", ".2f"),
    ("shading_si_mse", "shading si-MSE", ".4f"),
    ("albedo_si_mse", "albedo si-MSE", ".4f"),
    ("albedo_coarse_si_mse", "albedo: coarse", ".4f"),
    ("albedo_fine_si_mse", "albedo: detail", ".4f"),
    ("light_shading_si_mse", "light on the face", ".4f"),
    ("sh_error", "SH error", ".3f"),
)


def sec_ceiling(rep: Report, runs: list[Run]) -> None:
    """Each layer between its floor (the dataset mean) and its ceiling (the same network trained on the truth)."""
    ceiling = [r for r in runs if r.status == "ok" and r.eval and r.ceiling]
    if not ceiling:
        rep.note(
            "no finished ceiling run; train one with `python -m disent loss=ceiling` (and `+experiment=long "
            "loss=ceiling`) and point the report at its folder."
        )
        return
    with_ceiling = {setting(r, drop_model=True, drop=("loss=",)) for r in ceiling}  # trained settings with a ceiling
    trained = [
        r
        for r in runs
        if r.status == "ok" and r.eval and r.plain and (on_the_ladder(r) or setting(r, drop_model=True) in with_ceiling)
    ]
    rep.add(
        "Where a trained model's layer lies between its **floor**, the dataset-mean map or light "
        "(`disent.eval.trivial`), and its **ceiling**: the same network, optimiser, schedule, batch and data "
        "order trained on SynthFaces' true albedo, normals and light in place of the paper's objective "
        "(`python -m disent loss=ceiling`, `conf/loss/ceiling.yaml`). The paper's models see no albedo and only "
        "the pseudo-GT's normals and L-hat, so the gap to the ceiling is what the missing supervision costs at "
        "that budget, and the ceiling is what the architecture reaches there at all. The rendered face A (.) S "
        "matches the image closely, so the albedo's error follows the shading's (compare the two columns): "
        "an albedo can only be as right as the normals and light that shade it. The albedo's error is split by "
        "scale: *coarse*, its Gaussian blur (2 px, inside the scored region), and *detail*, what the blur leaves "
        "(eyes, brows, lips, pores; the two add up to the total but for twice their inner product; "
        "`disent.eval.metrics.scale_invariant_mse_bands`). Test split, 256 images; "
        "mean ± std over seeds.\n",
        *table_head("model", "row", "setting", "steps", *(label for _, label, _ in CEILING_COLUMNS)),
    )
    gaps, reach = [], []
    for model in ("explicit", "implicit"):
        rows = [("ceiling", r) for r in ceiling if r.model == model] + [
            ("trained", r) for r in trained if r.model == model
        ]
        if not any(kind == "ceiling" for kind, _ in rows):
            continue
        floor = next(r for kind, r in rows if kind == "ceiling")  # any run scores the same dataset means
        rep.add(
            f"| {model} | floor (dataset mean) | – | – | "
            + " | ".join(_fmt(floor.value("trivial_" + k), fmt) for k, _, fmt in CEILING_COLUMNS)
            + " |"
        )
        groups: dict = {}
        for kind, r in rows:
            groups.setdefault((kind, setting(r, drop_model=True)), []).append(r)
        steps = {g: (_spread(rs, "steps") or {"mean": math.nan})["mean"] for g, rs in groups.items()}
        order = sorted(groups.items(), key=lambda g: (steps[g[0]], g[0][0] == "ceiling"))
        for (kind, where), rs in order:
            rep.add(
                f"| {model} | {kind} | `{where}` | {steps[kind, where]:,.0f} | "
                + " | ".join(_ms(_spread(rs, k), fmt) for k, _, fmt in CEILING_COLUMNS)
                + " |"
            )
        tops: dict = {}  # each ceiling by the setting of the trained runs at its budget: its overrides but loss=ceiling
        for kind, r in rows:
            if kind == "ceiling":
                tops.setdefault(setting(r, drop_model=True, drop=("loss=",)), []).append(r)
        for (kind, where), rs in order:  # what the ceiling itself removes of the floor's albedo error, by scale
            if kind != "ceiling":
                continue
            shares = []
            for k, band in (("albedo_coarse_si_mse", "coarse part"), ("albedo_fine_si_mse", "detail")):
                lo, got = floor.value("trivial_" + k), _spread(rs, k)
                if lo and got:
                    shares.append(f"{100 * (1 - got['mean'] / lo):.0f} % of its {band}")
            if shares:
                reach.append(f"- {model}, `{where}` ({steps[kind, where]:,.0f} steps): {' and '.join(shares)}")
        for (kind, where), rs in order:
            top = tops.get(where)
            if kind != "trained" or not top:
                continue
            closed = []
            for k, label, _ in CEILING_COLUMNS:
                lo, got, hi = floor.value("trivial_" + k), _spread(rs, k), _spread(top, k)
                if None in (lo, got, hi) or lo == hi["mean"]:
                    closed.append(f"{label} –")
                else:
                    closed.append(f"{label} {100 * (lo - got['mean']) / (lo - hi['mean']):.0f} %")
            top_steps = (_spread(top, "steps") or {"mean": math.nan})["mean"]
            unequal = f" (trained {steps[kind, where]:,.0f} steps, ceiling {top_steps:,.0f})"
            gaps.append(
                f"- {model}, `{where}`: {', '.join(closed)}" + (unequal if steps[kind, where] != top_steps else "")
            )
    if gaps:
        rep.add(
            "",
            "Share of the floor-to-ceiling gap the trained models close, against the ceiling of their setting:\n",
            *gaps,
        )
    if reach:
        rep.add(
            "",
            "What each ceiling removes of the dataset-mean map's albedo error, by scale (detail the ceiling keeps is "
            "out of reach of the paper's objective at that budget too):\n",
            *reach,
        )
    rep.add(
        "",
        "_Regenerate: `python -m disent model=MODEL loss=ceiling` and `python -m disent model=MODEL "
        "+experiment=long loss=ceiling`, then `python -m disent.report --roots ...` with their folders._\n",
    )


def sec_teaser(rep: Report, runs: list[Run], n_vis: int) -> None:
    from disent.eval.evaluate import decomposed_region
    from disent.eval.metrics import angular_error_deg

    chosen = pick_runs(ladder_runs(runs))  # the paper's models as configured, side by side from the same runs
    missing = [m for m in MODELS if m not in chosen]
    if missing:  # only notes: the published teaser stays
        rep.note(
            f"no finished run with a checkpoint of {', '.join(f'`{m}`' for m in missing)} on the budget ladder "
            "(defaults or `+experiment=long`, no other override); the teaser sets the three models side by side."
        )
        return
    try:
        models, batch = _models(chosen), _test_batch(n_vis)
    except (ImportError, FileNotFoundError) as e:  # fall back to the grids the runs saved
        rep.note(f"cannot render from checkpoints ({e}); showing the runs' own sample grids.")
        for name, r in chosen.items():
            pngs = sorted((r.path / "samples").glob("*.png"))
            if pngs:
                dst = rep.fig / f"teaser_{name}.png"
                shutil.copyfile(pngs[-1], dst)
                rep.image(dst, f"samples of {name}")
        return
    from disent.eval.evaluate import predict

    outs = {name: predict(model, batch["image"]) for name, model in models.items()}

    def foreground(out, k):  # the intrinsic layers where the model's own matte claims the face
        return out[k] * (out["matte"] > 0.5) if k in ("albedo", "normal", "shading") and "matte" in out else out[k]

    def shown(out, k):  # shading (mean 0.75 by BWS, peaks above 1) divided by each image's maximum
        x = foreground(out, k)
        return over_max(x) if k == "shading" else x

    for name, out in outs.items():
        rows = [("input", batch["image"])] + [
            (k + (" / max" if k == "shading" else ""), shown(out, k))
            for k in ("recon", "albedo", "normal", "shading", "matte")
            if k in out
        ]
        path = rep.fig / f"teaser_{name}.png"
        _grid(
            rows,
            path,
            f"{name} ({chosen[name].path}) on SynthFaces test images; albedo, normal and shading where its matte > 0.5",
        )
        rep.add(f"**{name}** (`{chosen[name].path}`)\n")
        rep.image(path, f"teaser {name}")
    rec = [("input", batch["image"])] + [(f"{k} recon", outs[k]["recon"]) for k in MODELS if k in outs]
    path = rep.fig / "baseline_vs_ours.png"
    _grid(rec, path, "Baseline autoencoder against the rendering models (paper Fig. 3)")
    rep.add("### Baseline against ours (paper Fig. 3)\n")
    rep.image(path, "baseline vs ours")
    nrm = [
        ("input", batch["image"]),
        ("normal true", batch["normal"] * batch["matte"]),
        ("normal pseudo-GT", batch["normal_pseudo"] * batch["mask_pseudo"]),
    ]
    with_normals = [k for k in MODELS if k in outs and "normal" in outs[k]]
    nrm += [(f"normal {k}", foreground(outs[k], "normal")) for k in with_normals]
    scored = decomposed_region(batch)  # the angular error where it is scored, black 0 to white ERROR_WHITE degrees

    def error(normal):
        return (angular_error_deg(normal, batch["normal"])[:, None] / ERROR_WHITE).clamp(0, 1) * scored

    nrm += [("error pseudo-GT", error(batch["normal_pseudo"]))]
    nrm += [(f"error {k}", error(outs[k]["normal"])) for k in with_normals]
    path = rep.fig / "normals.png"
    _grid(
        nrm,
        path,
        "Our normals against the pseudo-GT they were trained on and the true normals; their angular error on the "
        f"scored pixels (black 0, white >= {ERROR_WHITE:g} deg)",
    )
    rep.add("### Our normals against the pseudo-GT and the truth\n")
    rep.image(path, "normals")
    rows = [(n, r) for n, r in chosen.items() if r.value("normal_mean") is not None]
    if rows:
        rep.add(
            *table_head(
                "run",
                "normal error (deg)",
                "dataset-mean map (deg)",
                "pseudo-GT error, same pixels (deg)",
                "under 25° ours / pseudo",
            ),
        )
        for n, r in rows:
            rep.add(
                f"| {n} | {r.value('normal_mean'):.2f} | {r.value('trivial_normal_mean') or float('nan'):.2f} | "
                f"{r.value('pseudo_normal_mean') or float('nan'):.2f} | "
                f"{r.value('normal_under_25') or float('nan'):.3f} / "
                f"{r.value('pseudo_normal_under_25') or float('nan'):.3f} |"
            )
        rep.add(
            "",
            '_The paper\'s claim "beyond the 3DMM subspace" holds for a run when its error is below the '
            "pseudo-GT's on the same pixels._\n",
        )


def sec_sh_variance(rep: Report, eval_dir: Path) -> None:
    res = _load_json(eval_dir / "sh_variance.json")
    if not res:
        rep.note("`reports/eval/sh_variance.json`; run `python -m disent.eval.protocols`.")
        return
    rep.add(
        f"Protocol of the paper's supplement on the `{res.get('split', 'lightbank')}` split: for every light "
        "condition the variance of each SH coefficient across identities and poses, averaged over conditions "
        "and RGB. Paper: 0.36 (3DMM least squares) and 0.16 (network). *relative* divides by the estimator's "
        "mean squared coefficient (scale-free); *within share* is the within-condition variance over the variance "
        "across all images (1: the estimate ignores the light); SH error is relative, after per-image scale "
        "alignment (0 perfect, 1 uninformative). A constant estimate has zero variance, so read the variance "
        "beside the last two columns. `ls_oracle` (true normals and albedo) and `true` are checks. *shown* / "
        "*hidden*: the variance and the error split between the SH directions a face's shading shows and those it "
        "hides (`disent.eval.protocols.sh_variance_shown_hidden`; each estimate scaled to the truth in shading, a "
        "share of the true light's squared norm); `mean_light` is the training split's mean light, the trivial "
        "baseline (its only spread is its per-image scale).\n",
        *table_head(
            "estimator",
            "variance",
            "relative",
            "within share",
            "SH error",
            "variance shown / hidden",
            "SH error shown / hidden",
            "conditions",
            "images",
        ),
    )
    for k, v in res["estimators"].items():
        split = (
            (f"{v[f'{key}_shown']:.3g} / {v[f'{key}_hidden']:.3g}" for key in ("variance", "sh_error"))
            if "variance_shown" in v
            else ("–", "–")  # a row measured before the split
        )
        rep.add(
            f"| {k} | {v['mean']:.4g} | {v['relative']:.4g} | {v.get('within_share', float('nan')):.3g} | "
            f"{v['sh_error']:.4g} | {' | '.join(split)} | {v['n_conditions']} | {v['n_images']} |"
        )
    rep.add("")
    published_figure(rep, eval_dir / "sh_variance.png", "SH variance per coefficient")
    from disent.eval.protocols import CHECKS, FITTED

    if not any(k not in (*FITTED, *CHECKS) for k in res["estimators"]):
        rep.note(
            "no trained model's Z_L in the SH-variance table (no finished explicit/implicit run when it was computed)."
        )


def is_recipe_run(run: Run) -> bool:
    """A run of the training recipe's leave-one-out (ablations/recipe.sh): a folder under a ``recipe/`` folder.
    Each changes a setting without an ``+ablation``, so it belongs in the recipe table, not among a model's seeds."""
    return "recipe" in run.origin.parts[:-1]


# What the full explicit model must reach at a budget before ablations there can give verdicts: normal error
# (deg, at most), face PSNR (dB, at least), albedo scale-invariant error (at most this share of the mean map's)
TARGETS = {"normal_mean": 12.5, "recon_face_psnr": 26.0, "albedo_share_of_trivial": 0.5}


def albedo_share(runs: list[Run]) -> float | None:
    """The runs' mean albedo error as a share of their mean map's (the albedo target's measure), or None."""
    albedo, trivial = _spread(runs, "albedo_si_mse"), _spread(runs, "trivial_albedo_si_mse")
    return albedo["mean"] / trivial["mean"] if albedo and trivial else None


def budget_misses(explicit: list[Run]) -> list[str] | None:
    """The :data:`TARGETS` the full explicit model misses at a budget (the mean over its seeds; empty: it meets
    them all), or None without a finished run there."""
    normal, psnr, share = _spread(explicit, "normal_mean"), _spread(explicit, "recon_face_psnr"), albedo_share(explicit)
    if not (normal and psnr and share is not None):
        return None
    misses = []
    if normal["mean"] > TARGETS["normal_mean"]:
        misses.append(
            f"normals {_past(normal['mean'], TARGETS['normal_mean'])} deg (target <= {TARGETS['normal_mean']})"
        )
    if psnr["mean"] < TARGETS["recon_face_psnr"]:
        misses.append(
            f"face PSNR {_past(psnr['mean'], TARGETS['recon_face_psnr'])} dB (>= {TARGETS['recon_face_psnr']})"
        )
    if share > TARGETS["albedo_share_of_trivial"]:
        misses.append(
            f"albedo {_past(share, TARGETS['albedo_share_of_trivial'])} of the mean map's "
            f"(<= {TARGETS['albedo_share_of_trivial']})"
        )
    return misses


def _past(value: float, target: float, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals, or as many more (up to 4) as it takes not to read as ``target`` (a miss
    of 0.5016 against 0.5 reads 0.502, not 0.50)."""
    while digits < 4 and f"{value:.{digits}f}" == f"{target:.{digits}f}":
        digits += 1
    return f"{value:.{digits}f}"


def budget_check(explicit: list[Run]) -> str:
    """:func:`budget_misses` as the caption under an ablation table: where the full explicit model misses a
    target, the ablation differences at that budget are not testable verdicts."""
    misses = budget_misses(explicit)
    if misses is None:
        return "_Budget check: no finished full explicit run at this budget; verdicts not testable._\n"
    if misses:
        return (
            f"_Budget check: the full explicit model misses {', '.join(misses)}; the ablation differences "
            "at this budget are **not testable** verdicts._\n"
        )
    return "_Budget check: the full explicit model meets every target at this budget._\n"


# What the paper says each ablated piece does, read off the test metric where its absence should show:
# (ablation, the paper's reason for the piece, metric; the full model wins where the metric is lower, except PSNR
# and SSIM).  Equation numbers count the paper's numbered equations (E_smooth-A 10, E_smooth-S 11, BWS 14).
ABLATION_CLAIMS = (
    ("no_bws", "BWS: no colour cast in the shading (Eq. 14)", "shading_cast"),
    ("no_bws", "BWS: no degenerate split where A_e takes the shading (Sec. 4.2)", "albedo_shading_corr"),
    ("no_bws", "BWS: the skin's colour stays in A_e, not in S_e (Sec. 4.2)", "albedo_colour_si_mse"),
    ("no_bws", "BWS: S_e keeps the light's colour, not the skin's (Sec. 4.2)", "shading_colour_si_mse"),
    ("no_bws", "BWS: S_e keeps the light's colour, not the skin's (Sec. 4.2)", "shading_albedo_tone_corr"),
    ("no_smooth_a", "Retinex: a piecewise-constant albedo leaves the shading to S_e (Eq. 10)", "albedo_shading_corr"),
    ("no_smooth_a", "Retinex: a better albedo (Eq. 10)", "albedo_si_mse"),
    ("no_smooth_s", "a smooth shading (Eq. 11)", "shading_si_mse"),
    ("no_smooth", "both smoothness priors (Eqs. 10, 11)", "albedo_si_mse"),
    ("no_matting", "the matte lets the face layers serve the face (Sec. 3.3)", "recon_face_psnr"),
    ("no_matting", "the matte lets the face layers serve the face (Sec. 3.3)", "normal_mean"),
    ("no_adv", "the adversarial loss: realistic, sharp faces (Eq. 7)", "recon_face_ssim"),
    ("no_pseudo_normal", "the morphable model's normals guide N_e (Eq. 8)", "normal_mean"),
    ("no_pseudo_light", "L-hat guides the light (Eq. 9)", "light_shading_si_mse"),
)
CLAIM_METRICS = {  # metric -> its label in the claims' tables
    "shading_cast": "shading cast",
    "albedo_shading_corr": "corr(albedo, true shading)",
    "albedo_si_mse": "albedo si-MSE",
    "albedo_colour_si_mse": "albedo si-MSE, one scale for RGB",
    "shading_colour_si_mse": "shading si-MSE, one scale for RGB",
    "shading_albedo_tone_corr": "corr over faces (shading's tone, skin's tone)",
    "shading_si_mse": "shading si-MSE",
    "recon_face_psnr": "face PSNR",
    "recon_face_ssim": "face SSIM",
    "normal_mean": "normals (deg)",
    "light_shading_si_mse": "light on the face",
}
HIGHER_IS_BETTER = ("recon_face_psnr", "recon_face_ssim")


def claim_ablations(rep: Report, runs: list[Run]) -> None:
    """Claim 4: each ablation of the explicit model against the full model at the same budget and setting, on the
    metric where the paper says the ablated piece shows; a verdict only where the full model meets the targets."""
    done = [r for r in runs if r.status == "ok" and r.eval and r.model == "explicit" and not r.ceiling]
    ablated: dict = {}  # (setting of the full model, ablation) -> runs
    for r in done:
        if len(r.ablations) == 1 and not is_recipe_run(r):
            where = setting(r, drop=("ablation=",))
            ablated.setdefault((where, r.ablations[0]), []).append(r)
    full: dict = {}
    for r in done:
        if r.plain and not is_recipe_run(r):
            full.setdefault(setting(r), []).append(r)
    # an ablated run also stands against each full model whose setting differs from its own only in settings it
    # leaves idle (:func:`joins`: without BWS and the whitened L-hat, c does nothing)
    for (where, ablation), rs in list(ablated.items()):
        for label in full:
            if joined := [r for r in rs if joins(r, where, label)]:
                ablated.setdefault((label, ablation), []).extend(joined)
    head = table_head(
        "setting",
        "ablation",
        "what the paper says the piece does",
        "metric",
        "full model",
        "without it",
        "difference",
        "verdict",
    )
    rows = []
    for where in sorted({w for w, _ in ablated}):
        misses = budget_misses(full.get(where, []))
        gate = (
            "not testable (no full model)"
            if misses is None
            else f"not testable (targets missed: {len(misses)} of {len(TARGETS)})"
            if misses
            else None
        )
        for ablation, reason, key in ABLATION_CLAIMS:
            rs = ablated.get((where, ablation))
            if not rs:
                continue
            a, b = _spread(full.get(where, []), key), _spread(rs, key)
            if a is None and b is None:  # runs scored before the metric existed
                continue
            diff = verdict(a, b, "higher" if key in HIGHER_IS_BETTER else "lower")
            rows.append(
                f"| `{where}` | {ablation} | {reason} | {CLAIM_METRICS[key]} | {_ms(a, '.4g')} | {_ms(b, '.4g')} | "
                f"{diff} | {gate or diff} |"
            )
    if not (rows := rep.rows_kept(head[0], rows, key=4)):
        rep.note(
            "no finished ablation runs of the explicit model; run the suite (`ablations/suite.sh`) and point the "
            "report at its folders."
        )
        return
    rep.add(
        "Each ablation of `conf/ablation/` against the full explicit model of the same setting (budget), on the "
        "test metric where the paper's reason for the piece should show; *difference* applies the claims' rule "
        "(the full model better beyond both arms' seed spread: confirmed), *verdict* reads it only where the full "
        "model meets the default-run targets at that budget (`TARGETS`; the budget check under each ablation "
        "table).\n",
        *head,
        *rows,
        "",
    )
    collapsed = [r for rs in ablated.values() for r in rs if normals_collapsed(r.eval)]
    if collapsed:
        rep.add(
            f"Runs whose normals collapsed flat (their spread about each face's mean normal under {FLAT_SHARE:.0%} of "
            "the truth's; the albedo then takes the shading, and the reconstruction can stay good):\n",
            *(
                f"- `{r.origin}` ({r.variant}, seed {r.seed}): spread {r.value('normal_spread'):.1f} deg against "
                f"{r.value('true_normal_spread'):.1f}, normals {r.value('normal_mean'):.1f} deg off, albedo "
                f"{r.value('albedo_si_mse'):.4f} against the mean map's "
                f"{_fmt(r.value('trivial_albedo_si_mse'), '.4f')}, face PSNR {r.value('recon_face_psnr'):.2f} dB"
                for r in sorted(collapsed, key=lambda r: str(r.origin))
            ),
            "",
        )


SKIN_METRICS = (  # (key, label, its floor's key or None): where each face's skin went (disent.eval.evaluate.bws_stats)
    ("shading_albedo_tone_corr", "corr over faces: shading's tone, skin's tone", None),
    ("shading_albedo_brightness_corr", "the same, brightness", None),
    ("albedo_colour_si_mse", "albedo si-MSE, one scale for RGB", "trivial_albedo_colour_si_mse"),
    ("shading_colour_si_mse", "shading si-MSE, one scale for RGB", "trivial_shading_colour_si_mse"),
    ("albedo_si_mse", "albedo si-MSE, a scale per channel", "trivial_albedo_si_mse"),
    ("albedo_pattern_corr", "albedo pattern corr (higher: better)", None),
    ("albedo_ceiling_share", "albedo at its ceiling (share)", None),
)


def claim_skin(rep: Report, runs: list[Run]) -> None:
    """Where each face's skin went: BWS fixes the batch's mean shading colour, so a model can still put each face's
    skin tone and brightness in its shading (the degenerate split per face); one row per setting and model."""
    from disent.eval.evaluate import ALBEDO_CEILING

    done = [r for r in runs if r.status == "ok" and r.eval and r.model in ("explicit", "implicit") and not r.ceiling]
    groups: dict = {}
    for r in done:
        if r.eval.get(SKIN_METRICS[0][0]) is not None and not is_recipe_run(r):
            groups.setdefault((setting(r, drop_model=True), r.model), []).append(r)
    head = table_head("setting", "model", *(label for _, label, _ in SKIN_METRICS))
    rows = [
        f"| `{where}` | {model} | "
        + " | ".join(
            _ms(_spread(rs, key), ".3g")
            + (f" (mean map {m['mean']:.3g})" if floor and (m := _spread(rs, floor)) else "")
            for key, _, floor in SKIN_METRICS
        )
        + " |"
        for (where, model), rs in sorted(groups.items())
    ]

    def truth(key):  # one test split, so the truth's value is the same in every run that has the key
        return next((v for rs in groups.values() for r in rs if (v := r.value(key)) is not None), None)

    tone, brightness, true_ceiling = (
        truth(f"true_{key}")
        for key in ("shading_albedo_tone_corr", "shading_albedo_brightness_corr", "albedo_ceiling_share")
    )
    if not (rows := rep.rows_kept(head[0], rows, key=2)):
        rep.note(
            "no run scored for where the skin goes; rescore finished runs with `python -m disent.eval.evaluate RUN`."
        )
        return
    rep.add(
        "Where each face's skin goes. BWS (Eq. 14) fixes the shading's mean colour over a batch, not over a face, "
        "and L-hat's constant albedo leaves each face's skin in the light that E_recon-L (Eq. 9) teaches "
        "(`loss.lhat_gray=true` takes each face's colour out of L-hat first; not the paper's). The first two columns "
        "correlate, over the test faces, the mean colour (chromaticity) and the mean brightness of the model's "
        "shading on each face with the true albedo's: 0 where the shading carries only the light"
        + (
            f" (the true shading: {tone:.2f} and {brightness:.2f})"
            if tone is not None and brightness is not None
            else ""
        )
        + ", towards 1 where it carries the skin. The si-MSEs with one scale shared by R, G and B forgive a face's "
        "brightness but not its colour: the albedo must carry the skin's colour, the shading the light's; the last two "
        "columns forgive both, what BWS decides: the si-MSE with a scale per channel (the targets' measure) and "
        "Pearson's correlation with the true albedo per image and channel, which forgives contrast too "
        "(`disent.eval.metrics.pattern_corr`; runs scored before it show –). The last column is the share of the "
        f"albedo's values (pixels and channels) at or above {ALBEDO_CEILING} of its sigmoid's 1"
        + (f" (the true albedo's: {true_ceiling:.3f})" if true_ceiling is not None else "")
        + ": where the split leaves the albedo near 1 (the shading takes the face's brightness: without BWS, or "
        "with a low c), the albedo is pinned at 1 over the skin and flat there, whatever the skin does "
        "(`disent.eval.evaluate.ceiling_share`; runs scored before it show –). Test "
        "split, 256 images; mean ± std over seeds (`python -m disent.eval.evaluate RUN` scores a finished run).\n",
        *head,
        *rows,
        "",
    )
    plot_skin_albedos(rep, groups)


SKIN_FACES = 6  # test faces in the albedo-by-setting figure


def plot_skin_albedos(rep: Report, groups: dict) -> None:
    """The albedo of one explicit run per setting of the skin table (:func:`pick_runs`; the shipped model for a
    setting whose runs left no checkpoint but include the shipped one) on the same test faces, beside the input and
    the true albedo, each where its matte is above 0.5: how BWS and its c set the albedo's brightness and where it
    is pinned at 1.  Drawn where two settings or more have a model."""
    import textwrap

    from disent.eval.evaluate import predict
    from disent.models.shipped import manifest

    shipped_run = str(manifest().get("explicit", {}).get("run", ""))
    sources = {}
    for (where, model), rs in sorted(groups.items()):
        if model != "explicit":
            continue
        if picked := pick_runs(rs, {r.variant for r in rs}):
            sources[where] = next(iter(picked.values()))
        elif shipped_run and any(str(r.origin) == shipped_run for r in rs):
            sources[where] = "explicit"  # the shipped weights
    if len(sources) < 2:
        if any("figures/skin_albedo.png" in line for line in rep.previous.get(rep.title, [])):
            rep.note("the albedo by setting is kept from an earlier build: here fewer than two settings have a model.")
            rep.image(rep.fig / "skin_albedo.png", "albedo by setting")
        return
    try:
        models, batch = _models(sources), _test_batch(SKIN_FACES)
    except (ImportError, FileNotFoundError) as e:
        rep.note(f"cannot render the albedo by setting from checkpoints ({e}).")
        return
    columns = [("input", batch["image"]), ("true albedo", batch["albedo"] * (batch["matte"] > 0.5))]
    for where, model in models.items():
        out = predict(model, batch["image"])
        shipped = " (shipped weights)" if isinstance(sources[where], str) else f" ({sources[where].path.name})"
        columns.append((where + shipped, out["albedo"] * (out["matte"] > 0.5)))
    plt = _plt()
    fig, axes = plt.subplots(SKIN_FACES, len(columns), figsize=(1.15 * len(columns), 1.15 * SKIN_FACES + 0.9))
    for j, (name, t) in enumerate(columns):
        axes[0, j].set_title(textwrap.fill(name, 22), fontsize=5)
        for i in range(SKIN_FACES):
            axes[i, j].imshow(to_array(t[i]), interpolation="nearest")
            axes[i, j].set_xticks([]), axes[i, j].set_yticks([])
    rep.add(
        "The albedo of one run per setting (explicit; the run's folder in parentheses) on the first "
        f"{SKIN_FACES} test faces, where its own matte is above 0.5, beside the true albedo:\n"
    )
    rep.figure(fig, "skin_albedo.png", "albedo by setting")


def sec_ablation(rep: Report, runs: list[Run]) -> None:
    """One table per setting apart from the model and the ablation (the budget, ``+experiment=``, and any other
    override), so runs of different settings never share a mean."""
    kept = [r for r in runs if not is_recipe_run(r) and not r.ceiling]  # the ceiling has its own section
    groups, tables = group_by_setting(kept, drop=("ablation=",)), {}
    start = len(rep.lines)
    for name, rs in sorted(groups.items()) or [("(defaults)", [])]:
        tables[name] = _ablation.ablation_table(rs)
        rep.add(f"### {name if name == '(defaults)' else f'`{name}`'}\n")
        rep.add(_ablation.to_markdown(tables[name]))
        rep.add(budget_check([r for r in rs if r.variant == "explicit" and r.status == "ok"]))
        rep.add(f"_Trained on: {machines(rs)}._\n")
    rep.subsections_kept(start)
    (rep.out / "ablation.json").write_text(
        json.dumps(tables if len(tables) > 1 else next(iter(tables.values()), {}), indent=1)
    )


def published_figure(rep: Report, path: Path, alt: str) -> None:
    """Show the figure a tool published beside its JSON (the report does not draw a second copy)."""
    if path.is_file():
        rep.image(path, alt)
    else:
        rep.note(f"`{_rel(path, rep.out)}` is missing; publish the tool folder that wrote the JSON beside it.")


def _stability_conditioning(rep: Report, cond: dict | None, eval_dir: Path) -> None:
    from disent.eval import stability as st

    rep.add("### L-hat conditioning against yaw and mask size\n")
    if cond:
        rep.add(
            f"Median over {cond['yaw']['n']} test faces turned to each yaw (pitch = roll = 0), and over "
            f"{cond['mask']['n']} test faces whose mask is shrunk towards its centre. `ls_oracle_noisy` fits with "
            f"true normals and albedo on the image plus Gaussian noise (sigma {st.ORACLE_NOISE}): its error is "
            "conditioning alone. Where the condition number passes the fit's `max_cond` (1e7) the fit is "
            "ridge-regularised (`disent.render.fit_sh`).\n"
        )

        def at(v, unit=""):
            return "never in the range" if v is None else f"**{v}{unit}**"

        f = cond["yaw"]["blowup_factor"]
        for est in st.LS_ESTIMATORS:
            y, m = cond["yaw"], cond["mask"]
            rep.add(
                f"- `{est}`: condition number {f:g}x its frontal value at yaw {at(y.get(est + '_blowup_yaw'), '°')}, "
                f"SH error {f:g}x at yaw {at(y.get(est + '_blowup_yaw_error'), '°')}; against the full mask, "
                f"condition {f:g}x at mask share {at(m.get(est + '_blowup_fraction'))}, "
                f"SH error {f:g}x at {at(m.get(est + '_blowup_fraction_error'))}."
            )
        for res, key, unit in ((cond["yaw"], "yaw", "°"), (cond["mask"], "fraction", "")):
            rep.add(
                "",
                *table_head(key, "face pixels", *(c for e in st.LS_ESTIMATORS for c in (f"cond {e}", f"SH err {e}"))),
            )
            for r in res["rows"]:
                if "error" in r:
                    rep.add(
                        f"| {r[key]}{unit} | – | " + " | ".join("–" for _ in range(2 * len(st.LS_ESTIMATORS))) + " |"
                    )
                    continue
                rep.add(
                    f"| {r[key]}{unit} | {r['face_pixels']:.0f} | "
                    + " | ".join(
                        f"{r[e + '_cond']['median']:.3g} | {r[e + '_sh_error']['median']:.3g}"
                        for e in st.LS_ESTIMATORS
                        if e + "_cond" in r
                    )
                    + " |"
                )
        bad = [r for r in cond["yaw"]["rows"] if "error" in r]
        if bad:
            rep.add(f"- yaws the generator refused: {', '.join(str(r['yaw']) for r in bad)}")
        rep.add("")
        published_figure(rep, eval_dir / "conditioning.png", "conditioning")
    else:
        rep.note("`reports/eval/conditioning.json`; run `python -m disent.eval.stability conditioning`.")


BREAK_FACTOR = 1.5  # an estimator breaks at the first severity whose error is this many times its clean error


def _stability_ood(rep: Report, res: dict) -> None:
    """Where each estimator breaks: per effect, the first severity whose error passes ``BREAK_FACTOR`` x its
    error on clean images, for the normals and the light."""
    sev = res["severities"]
    rep.add(
        f"Where each estimator breaks: the first severity at which its error passes {BREAK_FACTOR:g}x its error on "
        f"clean images ({res['n']} test images a point; `–`: not within the range). `light` turns the light "
        "out of the training prior (severity x 180 deg about the camera's x axis); `yaw` turns every face to "
        "severity x 90 deg (the prior spans +-45 deg); `scale` draws every face at (1 - severity / 2) times its "
        "scale (the prior spans +-10 %), the framing real photos' crops and heads vary in.\n",
        *table_head(
            "effect", "estimator", "normal error: clean -> worst", "breaks at", "SH error: clean -> worst", "breaks at"
        ),
    )

    from disent.eval.stability import first_past

    def breaks(values):
        if not values or not values[0] > 0:
            return "–", "–"
        at = first_past(sev, values, values[0], BREAK_FACTOR)
        return f"{values[0]:.3g} -> {max(values):.3g}", "–" if at is None else f"{at:g}"

    for effect, curves in res["effects"].items():
        for est, c in curves.items():
            n_range, n_at = breaks(c.get("normal_mean"))
            sh_range, sh_at = breaks(c.get("sh_error"))
            if (n_range, sh_range) != ("–", "–"):  # an estimator of neither (the baseline) has no row
                rep.add(f"| {effect} | {est} | {n_range} | {n_at} | {sh_range} | {sh_at} |")
    rep.add("")
    uv = [(e, est, c) for e, curves in res["effects"].items() for est, c in curves.items() if c.get("uv_error")]
    if uv:  # why the implicit model's normals break: its UV map, or its UV-space normals
        rep.add(
            "Why a UV model's normals break: its UV map against the true one (*uv error*, UV units) and its "
            "UV-space normals looked up at the true UV (`disent.eval.evaluate.uv_metrics`), each read at the "
            f"severity where the normals break: a step whose error has passed {BREAK_FACTOR:g}x its clean value "
            "there has failed.\n",
            *table_head(
                "effect", "estimator", "uv error: clean -> worst", "normals at the true UV (deg)", "normals break in"
            ),
        )
        for effect, est, c in uv:
            at = first_past(sev, c["normal_mean"], c["normal_mean"][0], BREAK_FACTOR)
            looked_up = c["normal_at_true_uv_mean"]
            if at is None:
                where = "–"
            else:
                i = sev.index(at)
                failed = [
                    step
                    for step, curve in (("the UV map", c["uv_error"]), ("the UV-space normals", looked_up))
                    if curve[i] >= BREAK_FACTOR * curve[0]
                ]
                where = " and ".join(failed) or "neither step alone"
                where += (
                    f" (at {at:g}: uv error {c['uv_error'][i]:.3g}, normals {c['normal_mean'][i]:.3g} deg, "
                    f"{looked_up[i]:.3g} at the true UV)"
                )
            rep.add(
                f"| {effect} | {est} | {c['uv_error'][0]:.3g} -> {max(c['uv_error']):.3g} | "
                f"{looked_up[0]:.3g} -> {max(looked_up):.3g} | {where} |"
            )
        rep.add("")


def _stability_bws(rep: Report, res: dict) -> None:
    """The BWS table: shading cast, albedo absorbing shading and where the skin went, per arm and batch size."""
    from disent.eval.stability import BWS_ARMS, bws_arm

    keys = ("true_shading_albedo_tone_corr", "true_shading_albedo_brightness_corr")
    first = res["rows"][0] if res["rows"] else {}
    truth = (
        f" (the true shading: {first[keys[0]]:.2f} and {first[keys[1]]:.2f})" if all(k in first for k in keys) else ""
    )
    floor = first.get("trivial_normal_mean")
    mean_map = f" (the dataset-mean normal map: {floor:.2f} deg)" if floor is not None else ""
    rep.add(
        f"Mean ± std over seeds on {res['n']} test images. BWS pulls each channel's shading mean to 0.75; "
        "*cast* is the spread of the three channel means; *corr(albedo, true shading)* is the correlation of "
        "the estimated albedo with the true shading (0: albedo free of shading). A run saw *steps* x *batch* training "
        "images, so where the steps are fixed a small batch also trains less: *normals* (test split) says "
        f"whether a run learned its geometry at all{mean_map}; rows whose *steps* x *batch* equal the largest "
        "batch's images trained every batch size on the same images (`IMAGES=N ablations/bws.sh`; dashed in the "
        "figure), which separates a small batch's per-face whitening from its shorter training. With BWS on, "
        "E_recon-L's target "
        "L-hat is itself scaled so that its shading has batch mean c (`loss.lhat_white`), a second "
        "whitening; `+ablation=no_bws` turns both off (the paper's ablation: the rows marked *raw L-hat target*), "
        "the rows marked *L-hat target still white* turn off only the BWS term. The two tone and brightness columns "
        "say where each face's skin went (the skin table of claim 4): the correlation over faces of the shading's "
        "mean tone and brightness with the true "
        f"albedo's{truth}; – where the study predates them.\n",
        *table_head(
            "arm",
            "batch",
            "steps",
            "seeds",
            "shading mean r, g, b",
            "cast",
            "corr(albedo, true shading)",
            "corr over faces: shading's tone, skin's tone",
            "the same, brightness",
            "normals (deg)",
        ),
    )

    def ms(vals):  # the table has a seeds column
        return _ms(_ablation.mean_std(vals), ".3f", count=False)

    groups = {}
    for r in res["rows"]:
        groups.setdefault((bws_arm(r), r["batch_size"], r.get("steps")), []).append(r)
    order = list(BWS_ARMS)  # the figure's legend order, then by batch size and steps
    for (key, bs, steps), rs in sorted(
        groups.items(), key=lambda kv: (order.index(kv[0][0]), kv[0][1] or 0, kv[0][2] or 0)
    ):
        arm = BWS_ARMS[key]
        rgb = ", ".join(f"{float(np.mean([r['shading_mean_rgb'][c] for r in rs])):.2f}" for c in range(3))
        steps = "–" if steps is None else steps
        skin = " | ".join(
            ms([r[k] for r in rs]) if all(r.get(k) is not None for r in rs) else "–"
            for k in ("shading_albedo_tone_corr", "shading_albedo_brightness_corr", "normal_mean")
        )
        rep.add(
            f"| {arm} | {bs} | {steps} | {len(rs)} | {rgb} | {ms([r['shading_cast'] for r in rs])} | "
            f"{ms([r['albedo_shading_corr'] for r in rs])} | {skin} |"
        )
    rep.add("")
    _bws_same_images(rep, res["rows"])
    if len({r["batch_size"] for r in res["rows"]}) < 2:
        rep.note(
            "the BWS batch-size sweep (one batch size only in these runs); run the `multirun/bws` sweeps of "
            "`ablations/README.md` for the curve against batch size."
        )


def _bws_same_images(rep: Report, rows: list) -> None:
    """The shading's tone against the skin's per batch size on the fixed-images budget, with BWS and without it."""
    from disent.eval.stability import BWS_ARMS, bws_arm, bws_budgets

    budgets = bws_budgets(rows)
    if len(budgets) < 2 or not all("shading_albedo_tone_corr" in r for r in rows):
        return
    label, same_images = budgets[1]
    arms = {BWS_ARMS[key]: key for key in ((True, True), (False, False))}
    parts = []
    for bs in sorted({r["batch_size"] for r in rows if same_images(r)}):
        tones = {
            arm: [
                r["shading_albedo_tone_corr"]
                for r in rows
                if same_images(r) and r["batch_size"] == bs and bws_arm(r) == key
            ]
            for arm, key in arms.items()
        }
        if all(tones.values()):
            spreads = [_ablation.mean_std(v) for v in tones.values()]
            parts.append(
                f"batch {bs}: "
                + ", ".join(f"{_ms(st)} {arm}" for st, arm in zip(spreads, tones))
                + f", lower with BWS: {verdict(*spreads, 'lower')}"
            )
    if parts:
        rep.add(
            "BWS fixes the mean shading of a batch: at batch 1 that is each face's own mean, which should keep the "
            "skin's tone out of each face's shading, while a larger batch fixes only the batch's mean. On the same "
            f"{label} at every batch size, the correlation over faces of the shading's tone with the skin's (the "
            f"true shading's: {rows[0].get('true_shading_albedo_tone_corr', float('nan')):.2f}), mean ± std over "
            "seeds: " + "; ".join(parts) + ".\n"
        )


def _stability_training(rep: Report, res: dict) -> None:
    """The training-stability table: outcome rates per model, adversarial term and learning rate."""
    from disent.eval import stability as st

    if len({r["lr"] for r in res["rows"]}) < 2:
        rep.note(
            "the learning-rate sweep (one learning rate only in these runs); run the `multirun/lr` sweeps of "
            "`ablations/README.md` for NaN / divergence rate against learning rate."
        )
    rep.add(
        f"Outcomes (`disent.eval.stability.outcome`): *NaN*, a loss term became non-finite (training stops, "
        "`status.json` says so); *diverged*, the last logged total loss above 2x the first; *exploded*, a "
        f"logged total loss above {res.get('spike', st.SPIKE):g}x the run's smallest "
        "(a blow-up before the first "
        "log escapes the previous rule); *collapsed*, the checkpoint's reconstructions vary across "
        f"{res.get('n', 'the')} test images by less than {st.COLLAPSE:g}x the images' own spread (the output "
        "ignores the input). Loss ratios, test recon MSE, normal error and input dependence are medians "
        "over the group's seeds"
        + (f"; the mean test image scores recon MSE {res['reference_mse']:.4f}" if res.get("reference_mse") else "")
        + ".\n",
        *table_head(
            "model",
            "adversarial",
            "lr",
            "runs",
            "NaN",
            "diverged",
            "exploded",
            "collapsed",
            "largest / smallest loss",
            "last / first loss",
            "test recon MSE",
            "normal err (deg)",
            "input dependence",
        ),
    )

    def g(v, fmt=".3g"):
        return "–" if v is None else format(v, fmt)

    for r in res["rows"]:
        rep.add(
            f"| {r['model']} | {r['adversarial']} | {r['lr']} | {r['runs']} | "
            + " | ".join(f"{r.get(f + '_rate', 0.0):.2f}" for f in st.FAILURES)
            + f" | {g(r.get('loss_spread'))} | {g(r.get('loss_ratio'))} | {g(r.get('recon_mse'), '.4f')} | "
            f"{g(r.get('normal_mean'), '.1f')} | {g(r.get('input_dependence'))} |"
        )
    rep.add("")


def sec_stability(rep: Report, eval_dir: Path) -> None:
    from disent.eval import stability as st

    _stability_conditioning(rep, _load_json(eval_dir / "conditioning.json"), eval_dir)
    for name, title, table in (
        ("ood", "Out of distribution: error against severity", _stability_ood),
        ("bws", "Without BWS: shading cast and albedo absorbing shading", _stability_bws),
        ("training", "Training stability: NaN and divergence rate", _stability_training),
    ):
        rep.add(f"### {title}\n")
        res = _load_json(eval_dir / f"{name}.json")
        if not res or (isinstance(res.get("rows"), list) and not res["rows"]):
            rep.note(
                f"no data for `{name}`; run `python -m disent.eval.stability {name}` after the runs it needs "
                "(see `ablations/README.md`)."
            )
            continue
        published_figure(rep, eval_dir / f"{name}.png", name)
        if "budget" in res:
            rep.add(f"_Budget of these runs (their configs): {st.budget_text(res['budget'])}._\n")
        if table is not None:
            table(rep, res)


def load_text(load: dict) -> str:
    """One sentence on the machine's load around a timing run: ``{before, after, cpus}`` 1-minute averages."""
    text = f" Load average {load['before']:.1f} at the start and {load['after']:.1f} at the end on {load['cpus']} CPUs"
    if max(load["before"], load["after"]) > load["cpus"]:
        return text + (
            ": above the CPU count, other work shared the cores and every time is inflated alike, so compare "
            "the times with each other, not with another run's."
        )
    return text + ": at most the CPU count, no other work competed for the cores."


def sec_methods(rep: Report, eval_dir: Path) -> None:
    """Every estimator's time per image against its accuracy, from ``reports/eval/methods.json``."""
    from disent.eval.methods import PANELS

    res = _load_json(eval_dir / "methods.json")
    if not res:
        rep.note("`reports/eval/methods.json`; run `python -m disent.eval.methods`, then publish its folder.")
        return
    rep.add(
        f"Regenerate: `python -m disent.eval.methods --n {res['n']}`, then `python -m disent.report --publish "
        f"FOLDER`. The first {res['n']} SynthFaces test images, every estimator timed in the same run on one "
        "thread (a network at that batch); metrics on the pixels the networks are scored on. The coarse fit is "
        "the simulated pseudo ground truth: it starts from the scene's parameters, so its time is a lower bound "
        "for a real fit; *landmarks + fit* is the real pipeline (dlib and the face model) on the renders, scored "
        "where dlib found the face."
        + (f" Machine: {res['machine']}." if res.get("machine") else "")
        + (load_text(res["load"]) if res.get("load") else "")
        + "\n",
        *table_head("estimator", "ms / image", "images", *(label for _, label, _ in PANELS)),
    )
    for name, r in res["rows"].items():
        t = "constant" if r.get("constant") else f"{1e3 * r['seconds_per_image']:.3g}"
        extra = f" ({100 * r['detection_rate']:.0f} % detected)" if "detection_rate" in r else ""
        cells = " | ".join(f"{r[k]:.3g}" if k in r else "–" for k, _, _ in PANELS)
        rep.add(f"| {name}{extra} | {t} | {r['images']} | {cells} |")
    rep.add("")
    published_figure(rep, eval_dir / "methods.png", "methods on one plane")


def sec_photos(rep: Report, out: Path) -> None:
    """The shipped models on real photos: the domain gap against the pseudo ground truth, beside the training set's
    constants, and the decompositions (``reports/photos/``, published from ``python -m disent.eval.photos``)."""
    from disent.eval.photos import GAP_TEXT, anatomy_table, gap_table

    folder = out / "photos"
    gaps = []
    for path in sorted(folder.glob("domain_gap_*.json")):
        g = _load_json(path)
        if g:
            gaps.append({"tag": path.stem.removeprefix("domain_gap_"), **g})
    if not gaps:
        rep.note(
            "`reports/photos/domain_gap_*.json`; run `python -m disent.eval.photos --run explicit implicit` and "
            "publish its folder."
        )
        return
    rep.add(
        "Regenerate: `python -m disent.eval.photos --run explicit implicit --workers 1`, then `python -m "
        f"disent.report --publish FOLDER`. The bundled photos through the pseudo-GT pipeline (dlib landmarks and the "
        f"face model; its accuracy on renders: `photos/pseudo_gt.md`). {GAP_TEXT}\n",
        *gap_table(gaps),
        "",
        *(anatomy := anatomy_table(gaps)),
        *([""] if anatomy else []),
    )
    for g in gaps:
        for name, alt in (
            (f"decomposition_{g['tag']}", "decomposition of photos"),
            (f"decomposition_{g['tag']}_colour_matched", "decomposition of colour-matched photos"),  # the anatomy's
            (f"relight_{g['tag']}", "relighting of photos"),
            (f"relight_{g['tag']}_colour_matched", "relighting of colour-matched photos"),
        ):
            if (folder / f"{name}.png").is_file():
                rep.image(folder / f"{name}.png", f"{alt}, {g['tag']}")


RECIPE_COLUMNS = (
    ("normal_mean", "normals (deg)", ".2f"),
    ("recon_face_psnr", "face PSNR (dB)", ".2f"),
    ("albedo_si_mse", "albedo si-MSE", ".4f"),
    ("sh_error", "SH error", ".3f"),
)


def sec_recipe(rep: Report, runs: list[Run]) -> None:
    """The training recipe's leave-one-out table: run folders under a ``recipe/`` folder, one per variant
    (folder name), ``recipe/recipe`` the full recipe; each row changes one setting back (overrides column)."""
    rows = {r.origin.name: r for r in runs if is_recipe_run(r) and r.eval}
    ref = rows.get("recipe")
    if ref is None:
        rep.note("no `recipe/recipe` run (ablations/recipe.sh writes the leave-one-out runs).")
        return
    steps, batch = ref.eval.get("steps"), (ref.cfg.get("train") or {}).get("batch_size")
    rep.add(
        f"Each row trains the explicit model for the same {steps} steps of batch {batch} with one setting of the "
        "recipe changed back (the override column), and scores it on the same 256 test images. "
        "Lower is better except for PSNR. The trivial and pseudo-GT rows score the dataset-mean map or light and the "
        "morphable-model fit on the same images.\n"
    )
    rep.add(
        *table_head("variant", "override", "steps", *(c[1] for c in RECIPE_COLUMNS), "train min"),
    )

    def cell(r, key, fmt):
        v, base = r.eval.get(key), ref.eval.get(key)
        if v is None:
            return "–"
        old = key.startswith("albedo") and "albedo_face_si_mse" not in r.eval  # scored before the region change
        return f"{v:{fmt}}" + ("†" if old else "") + ("" if r is ref or base is None else f" ({v - base:+{fmt}})")

    for name in ["recipe", *sorted(n for n in rows if n != "recipe")]:
        r = rows[name]
        changed = [o for o in map(str, r.overrides) if o not in map(str, ref.overrides)]
        rep.add(
            f"| {name} | {' '.join(f'`{o}`' for o in changed) or '–'} | {r.eval.get('steps')} | "
            + " | ".join(cell(r, k, f) for k, _, f in RECIPE_COLUMNS)
            + f" | {(r.eval.get('train_seconds') or 0) / 60:.1f} |"
        )
    e = ref.eval
    rep.add(
        f"| trivial (dataset mean) | – | – | {e.get('trivial_normal_mean', float('nan')):.2f} | – | "
        f"{e.get('trivial_albedo_si_mse', float('nan')):.4f} | {e.get('trivial_sh_error', float('nan')):.3f} | – |",
        f"| pseudo-GT | – | – | {e.get('pseudo_normal_mean', float('nan')):.2f} | – | – | "
        f"{e.get('pseudo_sh_error', float('nan')):.3f} | – |",
        "",
    )
    if any("albedo_face_si_mse" not in r.eval for r in rows.values()):
        rep.add(
            "† scored over the whole true face mask (hair and neck included) by an earlier version; today's "
            "`albedo_si_mse` covers the face inside the pseudo mask (`python -m disent.eval.evaluate RUN` "
            "scores a run again where its checkpoint still loads).\n"
        )


CURVE_PANELS = (  # (val key, trivial key, pseudo-GT key, label); every panel: lower is better except PSNR
    ("normal_mean", "trivial_normal_mean", "pseudo_normal_mean", "normal error (deg)"),
    ("albedo_si_mse", "trivial_albedo_si_mse", None, "albedo scale-inv. MSE"),
    ("sh_error", "trivial_sh_error", "pseudo_sh_error", "SH error"),
    (
        "light_shading_si_mse",
        "trivial_light_shading_si_mse",
        "pseudo_light_shading_si_mse",
        "light on the face (si-MSE)",
    ),
    ("recon_face_psnr", None, None, "face PSNR (dB)"),
)


def val_curves(run: Run) -> list[dict]:
    """The run's periodic ``val`` records, each with ``images`` (step x batch) and ``minutes`` (training wall).
    Albedo values written before the albedo was scored inside the pseudo mask (records without
    ``albedo_face_si_mse``) are left out, so that one line never mixes two definitions."""
    batch = (run.cfg.get("train") or {}).get("batch_size") or 1
    albedo = ("albedo_si_mse", "albedo_global_si_mse", "trivial_albedo_si_mse", "trivial_albedo_global_si_mse")
    out = []
    for r in run.metrics:
        if isinstance(r.get("val"), dict):
            v = {**r["val"], "images": r["step"] * batch, "minutes": r["wall"] / 60}
            if "albedo_face_si_mse" not in v:
                v = {k: x for k, x in v.items() if k not in albedo}
            out.append(v)
    return out


def trained_on_gpu(run: Run) -> str | None:
    """The GPU ``run`` trained on (its ``machine.json``), or None for a CPU run or one that recorded no machine."""
    return (run.machine or {}).get("gpu")


def curve_label(run: Run) -> str:
    """A learning curve's legend label: the seeds of a setting share it; a GPU run names its GPU (its wall minutes
    are not the CPU's)."""
    gpu = trained_on_gpu(run)
    return f"{run.variant}: {setting(run, drop_model=True)}" + (f" ({gpu})" if gpu else "")


def plot_learning_curves(runs: list[Run], path: Path, title: str = "", colour_by_setting: bool = False) -> bool:
    """Each accuracy of the ``val`` records against training images (top) and wall minutes (bottom), one
    line per run (a colour per model, or per model and setting; dash-dotted for a ceiling run), with the trivial
    (dataset-mean) baseline dashed and the pseudo-GT dotted."""
    curves = [(r, val_curves(r)) for r in runs]
    curves = [(r, c) for r, c in curves if c]
    if not curves:
        return False
    plt = _plt()
    fig, axes = plt.subplots(2, len(CURVE_PANELS), figsize=(4 * len(CURVE_PANELS), 6.4), squeeze=False)

    def kind(r):  # what shares a colour: the model (and ablation), or each labelled line
        return curve_label(r) if colour_by_setting else r.variant.removesuffix("+ceiling")

    kinds = sorted({kind(r) for r, _ in curves})
    palette = [f"C{i}" for i in range(10)] if len(kinds) <= 10 else list(plt.get_cmap("tab20").colors)
    for col, (key, trivial, pseudo, label) in enumerate(CURVE_PANELS):
        for row, x in enumerate(("images", "minutes")):
            ax = axes[row][col]
            seen, finals = set(), []
            for r, c in curves:
                pts = [(v[x], v[key]) for v in c if v.get(key) is not None]
                if not pts or (r.ceiling and key == "recon_face_psnr"):  # a ceiling does not train the reconstruction
                    continue
                finals.append(pts[-1][1])
                name = curve_label(r)
                ax.plot(
                    *zip(*pts),
                    color=palette[kinds.index(kind(r)) % len(palette)],  # one colour each, up to 20
                    ls="-." if r.ceiling else "-",
                    lw=2.0 if trained_on_gpu(r) else 1.0,
                    label=None if name in seen else name,
                )
                seen.add(name)
            lines = []
            for ref, style, name in ((trivial, "--", "dataset mean"), (pseudo, ":", "pseudo-GT")):
                vals = [
                    c[-1][ref] for _, c in curves if ref and c[-1].get(ref) is not None and c[-1].get(key) is not None
                ]
                if vals:
                    lines.append(float(np.mean(vals)))
                    ax.axhline(lines[-1], color="k", ls=style, lw=1, label=name)
            if lines and key != "recon_face_psnr":  # the first steps' errors would squash the curves that matter;
                top = max(lines)  # a run that ends far above the reference lines (it broke) stays in view, up to 3x
                ax.set_ylim(top=max(1.5 * top, min(1.1 * max(finals, default=0), 3 * top)))
            ax.set_xlabel("training images" if x == "images" else "training wall minutes")
            if x == "images":  # 250000 runs into its neighbours: 250k
                ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1000:g}k" if v else "0")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    legend = {}  # one legend under the panels: every line's label (the baseline has a curve in the PSNR panels only)
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    rows = (len(legend) + 3) // 4
    fig.set_figheight(6.4 + 0.2 * rows)  # the panels keep their height; the legend adds its rows
    fig.legend(legend.values(), legend.keys(), loc="lower center", ncol=4, fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, (0.2 * rows + 0.1) / (6.4 + 0.2 * rows), 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")  # a legend wider than the panels (long settings) is not clipped
    plt.close(fig)
    return True


def sec_learning_curves(rep: Report, runs: list[Run]) -> None:
    drawn = False
    ablated = {setting(r, drop=("ablation=",)) for r in runs if r.ablations and not is_recipe_run(r)}
    ladder = [r for r in runs if r.plain and on_the_ladder(r)]
    ceilings = {setting(r, drop_model=True) for r in ladder}
    ladder += [r for r in runs if r.ceiling and setting(r, drop_model=True, drop=("loss=",)) in ceilings]
    others = [r for r in runs if r.plain and not on_the_ladder(r) and not is_recipe_run(r)]
    defaults = [r for r in ladder if r.plain and r.model == "explicit" and setting(r, drop_model=True) == "(defaults)"]
    for name, subset, title, by_setting in (
        ("learning_curves.png", ladder, "the budget ladder and its ceilings: validation accuracy in training", True),
        (
            "learning_curves_settings.png",
            others + (defaults if others else []),
            "every other setting (A/B runs, earlier recipes) beside the explicit defaults",
            True,
        ),
        (  # each ablation beside the full model of the setting it ablates
            "learning_curves_ablations.png",
            [
                r
                for r in runs
                if not is_recipe_run(r)
                and (r.ablations or (r.model == "explicit" and r.plain and setting(r) in ablated))
            ],
            "the ablations beside the full explicit model",
            False,
        ),
        (
            "learning_curves_recipe.png",
            [r for r in runs if is_recipe_run(r)],
            "the training recipe's leave-one-out",
            True,
        ),
    ):
        path = rep.fig / name
        if plot_learning_curves(subset, path, f"{title} (64 val images)", by_setting):
            rep.image(path, title)
            drawn = True
    if not drawn:
        rep.note("no run logged `val` records (`train.val_every`).")
        return
    rep.add(
        "_A layer counts as learned only below its dashed line (the dataset-mean map or light, "
        "`disent.eval.trivial`); the dotted line is the pseudo ground truth that supervised it._\n"
    )


FRACTION_TARGETS = {
    "train": 0.55,
    "infer": 0.60,
}  # the explicit model on the CPU: training with D, inference at batch 64
RATIO_TARGET = 0.7  # the implicit model's images/s over the explicit model's, each rate
BENCH_RATES = (
    ("train", "train with D"),
    ("train_past_margin", "train, fakes past D's margin"),
    ("train_no_d", "train without D"),
    ("infer_b1", "infer batch 1"),
    ("infer", "infer batch 64"),
    ("infer_b256", "infer batch 256"),
)  # key prefix in bench.json's models.<name>, label


def _bench_models(models: dict) -> tuple[dict, list]:
    """The models in ``disent.bench.models.MODELS`` order, and the rates of ``BENCH_RATES`` any of them has."""
    from disent.bench.models import MODELS

    models = dict(sorted(models.items(), key=lambda kv: MODELS.index(kv[0]) if kv[0] in MODELS else len(MODELS)))
    return models, [
        (k, label)
        for k, label in BENCH_RATES
        if any(f"{k}_img_s" in m or f"{k}_fraction_of_peak" in m for m in models.values())
    ]


def plot_fractions(rep: Report, models: dict, device: str, threads, name: str = "bench_fractions.png") -> None:
    """Bar chart: each model's achieved FLOP/s as a fraction of the matmul peak of its run."""
    import textwrap

    plt = _plt()
    models, rates = _bench_models(models)
    keys = [k for k, _ in rates]
    fig, ax = plt.subplots(figsize=(7, 2.8))
    width = 0.8 / len(models)
    for j, (model, m) in enumerate(models.items()):
        ax.bar(
            [i + j * width for i in range(len(rates))],
            [m.get(f"{k}_fraction_of_peak", 0) for k, _ in rates],
            width,
            label=model,
        )
    for k, target in FRACTION_TARGETS.items():
        if k in keys and device == "cpu":
            i = keys.index(k)
            ax.hlines(target, i - width / 2, i + width * (len(models) - 0.5), colors="k", linestyles="--", lw=1)
    ax.set_xticks(
        [i + width * (len(models) - 1) / 2 for i in range(len(rates))],
        [textwrap.fill(label, 14) for _, label in rates],
        fontsize=7,
    )
    ax.set_ylabel("fraction of matmul peak")
    ax.set_title(
        f"Achieved FLOP/s over the fp32 matmul peak of the same run ({device}, {threads} threads)"
        + ("; dashed: the explicit model's targets" if device == "cpu" else ""),
        fontsize=8,
    )
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7, ncol=len(models), loc="upper left")
    rep.figure(fig, name, "fraction of peak by model and rate")


PROFILE_GROUPS = {
    "convolutions": ("convolution",),
    "matrix products": ("aten::mm", "aten::addmm", "aten::bmm"),
    "pooling, unpooling": ("max_pool", "max_unpool", "gather", "fill_"),
}  # the rest: "other operators"


def plot_profile(rep: Report, profile: dict, name: str = "bench_profile.png") -> None:
    """Stacked bars: where each model's training step and inference batch spend their self CPU time."""
    plt = _plt()
    groups = [*PROFILE_GROUPS, "other operators"]
    rows = {}
    for key, ops in profile.items():
        share = dict.fromkeys(groups, 0.0)
        for op, ms in ops.items():
            if op in ("total", "convolution_share"):
                continue
            op_name = op.split(" ", 1)[-1]
            group = next((g for g, pats in PROFILE_GROUPS.items() if any(p in op_name for p in pats)), groups[-1])
            share[group] += ms / ops["total"]
        rows[key.removesuffix("_ms").replace("_", " ") + f" ({ops['total']:.0f} ms)"] = share
    fig, ax = plt.subplots(figsize=(7, 0.35 * len(rows) + 1))
    left = np.zeros(len(rows))
    for g in groups:
        widths = np.array([r[g] for r in rows.values()])
        ax.barh(list(rows), widths, left=left, label=g)
        left += widths
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("share of self CPU time (torch.profiler)")
    ax.legend(fontsize=7, ncol=len(groups), loc="lower center", bbox_to_anchor=(0.5, 1.0))
    ax.tick_params(labelsize=7)
    rep.figure(fig, name, "where the time goes, by operator group")


def models_table(models: dict) -> list[str]:
    """Markdown rows, one per model: forward GFLOP per image, then images/s (fraction of peak) per rate."""
    models, rates = _bench_models(models)
    lines = [
        *table_head("model", "GFLOP / image (forward)", *(label for _, label in rates)),
    ]
    for name, m in models.items():
        cells = [
            f"{m[f'{k}_img_s']:.1f} ({m.get(f'{k}_fraction_of_peak', math.nan):.2f})" if f"{k}_img_s" in m else "-"
            for k, _ in rates
        ]
        lines.append(f"| {name} | {m.get('flops_per_image', math.nan) / 1e9:.3f} | " + " | ".join(cells) + " |")
    return lines


def target_checks(bench: dict) -> list[str]:
    """The CPU targets against this run's figures: the explicit model's fractions of peak, the
    implicit/explicit images/s ratios, and the loader against training."""
    explicit, setup = bench.get("models", {}).get("explicit", {}), bench.get("models_setup", {})
    labels, checks = dict(BENCH_RATES), []

    def check(what, value, target):
        checks.append(f"- {what}: {value:.3f} (target >= {target}): **{'met' if value >= target else 'missed'}**")

    for k, target in FRACTION_TARGETS.items():
        if f"{k}_fraction_of_peak" in explicit:
            check(f"explicit, {labels[k]}, fraction of peak", explicit[f"{k}_fraction_of_peak"], target)
    for k, ratio in setup.get("implicit_vs_explicit", {}).items():
        check(f"implicit / explicit images/s, {labels.get(k.removesuffix('_img_s'), k)}", ratio, RATIO_TARGET)
    if "loader_vs_fastest_training" in setup:
        check("loader alone over the fastest training, images/s", setup["loader_vs_fastest_training"], 1.0)
    return checks


def norm_cost_lines(cost: dict) -> list[str]:
    """What the normalisation layers cost (``python -m disent.bench norm_cost``): the explicit model's
    images/s with each ``model.norm`` over none, timed in alternating rounds."""
    labels = dict(BENCH_RATES)
    order = [f"{k}_img_s" for k, _ in BENCH_RATES]
    rates = sorted(next(iter(cost.values())), key=lambda r: order.index(r) if r in order else len(order))
    return [
        "What the normalisation layers cost (`python -m disent.bench norm_cost`): the explicit model's images/s "
        "with each `model.norm` over the same model with none, in alternating rounds. At inference BatchNorm "
        "is folded into the convolutions (`disent/models/kernels.py`).\n",
        *table_head("model.norm", *(labels.get(r.removesuffix("_img_s"), r) for r in rates)),
        *(f"| {norm} | " + " | ".join(f"{ratios[r]:.2f}" for r in rates) + " |" for norm, ratios in cost.items()),
    ]


def sec_bench(rep: Report, out: Path) -> None:
    """Every ``bench*.json`` (``bench.json`` from the CPU, ``bench-cuda.json`` from a GPU), each
    under its device: the models at a glance, the CPU targets, charts, then every figure."""
    paths = sorted(Path(out).glob("bench*.json"), key=lambda p: (p.name != "bench.json", p.name))
    benches = [(p, b) for p in paths if isinstance(b := _load_json(p), dict)]
    if not benches:
        rep.note("`reports/bench.json`; run `python -m disent.bench`.")
        return

    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else json.dumps(v)[:120]

    def flat(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict):
                yield from flat(v, f"{prefix}{k}.")
            else:
                yield f"{prefix}{k}", v

    for path, bench in benches:
        device = str(bench.get("device", "cpu"))
        rep.add(f"### {device} (`reports/{path.name}`)\n")
        env = {k: v for k, v in bench.items() if not isinstance(v, dict)}
        if env:
            rep.add("Machine: " + ", ".join(f"{k}={fmt(v)}" for k, v in env.items()) + "\n")
        if isinstance(loads := bench.get("load_average_1min"), dict):  # the sections measured on this machine
            fresh = {*loads, *(f"{k}_setup" for k in loads), "load_average_1min"}
            kept = [k for k, v in bench.items() if isinstance(v, dict) and k not in fresh]
            rep.add(
                "Measured on that machine (the 1-minute load average as each section was written): "
                + ", ".join(f"{k} ({v:.2f})" for k, v in loads.items())
                + f"; the load counts the benchmark's own {bench.get('threads')} thread(s)."
                + (
                    f" Kept from earlier runs, whose machine this file does not record: {', '.join(kept)}; compare "
                    "their images/s only with each other."
                    if kept
                    else ""
                )
                + "\n"
            )
        models = bench.get("models")
        if isinstance(models, dict) and models:
            rep.add(
                "Images/s (fraction of the matmul peak measured beside each rate). Each rate is timed at its own "
                "moment; on a shared machine compare the fractions, which divide out the load of that moment, "
                "rather than images/s across cells.\n",
                *models_table(models),
                "",
            )
            if device == "cpu" and (checks := target_checks(bench)):
                rep.add("Targets on the CPU:\n", *checks, "")
            plot_fractions(rep, models, device, bench.get("threads"), f"{path.stem}_fractions.png")
        if isinstance(cost := bench.get("norm_cost"), dict) and cost:
            rep.add(*norm_cost_lines(cost), "")
        if isinstance(tta := bench.get("time_to_accuracy"), dict) and tta.get("run"):
            rep.add(time_to_accuracy_text(tta), "")
        if isinstance(bench.get("profile"), dict):
            plot_profile(rep, bench["profile"], f"{path.stem}_profile.png")
        rep.add(f"<details><summary>Every figure in {path.name}</summary>\n")
        for section, vals in bench.items():
            if isinstance(vals, dict):
                rep.add(
                    f"**{section}**\n",
                    *table_head("quantity", "value"),
                    *(f"| {k} | {fmt(v)} |" for k, v in flat(vals)),
                    "",
                )
        rep.add("</details>\n")


def time_to_accuracy_text(tta: dict) -> str:
    """One paragraph of ``python -m disent.bench time_to_accuracy``: when the run's normals beat each target."""
    reached = []
    for key, what in (("trivial", "the dataset-mean map"), ("pseudo_gt", "the pseudo-GT")):
        hit = tta.get(key) or {}
        if hit.get("minutes") is None:
            reached.append(f"{what} never (its {_fmt(hit.get('target'), '.2f')} deg)")
        else:
            reached.append(
                f"{what} after **{hit['minutes']:.1f} training minutes** (step {hit['step']:,}, "
                f"{hit.get('images') or 0:,} images; {hit['normal_mean']:.2f} against {hit['target']:.2f} deg on the "
                f"{hit['source']} images)"
            )
    return (
        f"Time to accuracy (`python -m disent.bench time_to_accuracy --run RUN`, from the run's records): "
        f"`{tta['run']}`'s normals beat {reached[0]}, and {reached[1]}; its best "
        f"{_fmt(tta.get('best_normal_mean'), '.2f')} deg after {_fmt(tta.get('best_minutes'), '.1f')} minutes."
    )


ORDER_TARGET = 0.85  # share of scenes whose lighting order is chosen right on pseudo geometry


def _pct(x) -> str:
    return "–" if x is None else f"{x:.2f}"


def wilson_interval(share: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``share`` observed over ``n`` trials (95 % at ``z = 1.96``)."""
    centre = (share + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(share * (1 - share) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def residual_text(d: Path) -> str:
    """The residual process's fitted constants, one fit per geometry, from ``residual_process.json`` of the
    lighting folder ``d``."""
    from disent.lighting.experiments import GEOMETRY

    fits = _load_json(d / "residual_process.json")
    if not fits:
        return "not fitted in this report's inputs"
    if "rho" in fits:  # one fit, on the pseudo geometry, as studies before the per-geometry fits wrote it
        fits = {"normal_pseudo": fits}
    return "; ".join(
        f"rho {fit['rho']:g}, ell {fit['ell']:g} px from {fit['n_scenes']} {fit['split']} scenes on "
        f"{GEOMETRY[normals].label}"
        for normals, fit in fits.items()
    )


def band2_reading(order: dict, chosen: str) -> str:
    """One sentence on the order study's band-2 diagnostic: on test, how much band 2 the largest candidate fits for
    a true order-1 scene, on true normals, on pseudo normals with the known albedo, and on the ``chosen`` row, against
    the true order-2 lights' ("" where the study predates it)."""
    rows = {
        "true normals (texture model)": "test/texture/normal",
        "pseudo normals with the known albedo": "test/known/normal_pseudo",
        "the chosen row": f"test/{chosen}",
    }
    band2 = {label: order.get(key, {}).get("band2_share") for label, key in rows.items()}
    if not all(band2.values()):
        return ""
    truth = band2["the chosen row"]["true_order2"]
    return (
        " What separates order 1 from order 2 is the light's band 2. On test, the order-2 fit of a true order-1 scene "
        "holds in band 2, as a share of bands 0 and 1: "
        + ", ".join(f"{b['fitted_by_true_order'][1]:.2f} on {label}" for label, b in band2.items())
        + f"; a true order-2 light holds {truth:.2f}. Where the pseudo geometry's error alone puts as much in band 2 "
        "as a true order-2 light has, the scene's evidence cannot tell the two apart."
    )


def known_albedo_reading(order: dict) -> str:
    """One sentence on what the pseudo geometry allows with the albedo's error removed: the known-albedo row on
    pseudo normals best on val, with its val and test accuracy ("" where the study has no such row)."""
    rows = [k for k in order if k.startswith("val/known/normal_pseudo") and f"test/{k[4:]}" in order]
    if not rows:
        return ""
    best = max(rows, key=lambda k: order[k]["evidence"]["accuracy"])
    val, test = (order[f"{split}/{best[4:]}"]["evidence"]["accuracy"] for split in ("val", "test"))
    return (
        f" With the true albedo on the same pseudo geometry (the known-albedo row best on val, `{best[4:]}`) the "
        f"choice reaches {val:.2f} on val and {test:.2f} on test: what the pseudo geometry allows once the albedo's "
        "error is gone, so a better albedo model alone is "
        + ("not expected to bring it to the target on both splits." if min(val, test) < ORDER_TARGET else "enough.")
    )


def sec_lighting(rep: Report, out: Path) -> None:
    """How uncertain L-hat is and which lighting order a scene needs, from ``reports/lighting/*.json``."""
    from disent.lighting.experiments import GEOMETRY

    d = out / "lighting"
    order, cal, cal_p, speed = (
        _load_json(d / f"{n}.json") for n in ("order", "calibration", "calibration_pseudo", "speed")
    )
    if not (order or cal or speed):
        rep.note("`reports/lighting/`; run `python -m disent.lighting task=report`, then publish its folder.")
        return
    rep.add(
        "Regenerate: `python -m disent.lighting task=report` (one core: one torch and one OpenBLAS thread), then "
        "`python -m disent.report --publish OUTPUT_FOLDER`. SynthFaces 64x64; i.i.d. Gaussian noise, std 0.02, "
        "added to each image. Sampler: emcee with an independence proposal (`disent/lighting/posterior.py`).\n"
    )
    if order:
        rep.add(
            "### Lighting model order: model no more than a scene needs\n",
            "Item *i* of the split relit with its own light cut to SH order 0, 1 or 2, 20 scenes per order. "
            "Candidates: order 0, order 1 and 2 in gray or RGB; the smallest model within log 20 of the best "
            "Laplace evidence is chosen (BIC beside it). *Albedo*: known (the reference), constant (what L-hat "
            "assumes), or a PCA texture model fitted with the light (`disent/lighting/texture.py`). *Geometry "
            "noise*: each pixel's variance adds what a normal error of std `normal_sigma` (the pseudo-GT's "
            "measured mean error read as an isotropic tangent Gaussian, not fitted here) does to it under the "
            "candidate's light (`select_order(..., normal_sigma=...)`). *Residual process*: the misfit is "
            "spatially correlated, noise covariance sigma^2 (I + rho exp(-d / ell)) over pixel distance d, "
            "with rho and ell by maximum likelihood on train scenes' residuals at their true light "
            f"({residual_text(d)}; `select_order(..., residual=(rho, ell))`). *Eroded mask*: the pseudo mask less "
            "its edge pixels, where the coarse fit's normals graze and its silhouette leaks onto hair or background "
            "(`disent.lighting.experiments.GEOMETRY`). *uv registered*: the pseudo uv corrected by the affine map "
            "that best registers the texture model to the image, found before any candidate is scored (Gauss-Newton "
            "on the six affine parameters, the light and texture fitted again at each step, coarse to fine, under a "
            "Gaussian prior of the affine maps that take train scenes' pseudo uv onto their true uv; "
            "`disent.lighting.texture.register`). *Oracle* rows put one true layer into the pseudo geometry, "
            "to say which of its errors costs the choice: the true uv (the texture model registered to the face) "
            "or the true normals (`disent.lighting.experiments.GEOMETRY`). *Band 2 fitted*: the median over a true "
            "order's scenes of what the largest candidate (order 2, RGB) puts in SH band 2, as a share of bands 0 "
            "and 1 (`disent.lighting.order.band2_share`), beside the true order-2 lights' median: where an order-1 "
            "scene's fit holds as much band 2 as a true order-2 light, the geometry's error shows as band-2 light "
            "and no criterion built on the fit can tell the two orders apart. Constants were chosen on val; test "
            "only reports; the order study alone: `python -m disent.lighting task=order`.\n",
            *table_head(
                "split",
                "albedo",
                "geometry",
                "evidence confusion (rows: true order 0, 1, 2)",
                "evidence acc.",
                "BIC acc.",
                "band 2 fitted, true order 0 / 1 / 2 (true order-2 lights)",
            ),
        )
        for key, r in order.items():
            split, albedo, geometry = key.split("/", 2)
            normals, _, noise = geometry.partition("+")
            geometry = GEOMETRY[normals].label + (f", {noise.replace('_', ' ')}" if noise else "")
            ev, bic = r["evidence"], r["bic"]
            band2 = r.get("band2_share")  # studies written before it was measured have none
            band2 = (
                " / ".join(f"{v:.2f}" for v in band2["fitted_by_true_order"]) + f" ({band2['true_order2']:.2f})"
                if band2
                else "–"
            )
            rep.add(
                f"| {split} | {albedo} | {geometry} | {ev['confusion']} | {_pct(ev['accuracy'])} | "
                f"{_pct(bic['accuracy'])} | {band2} |"
            )
        realistic = [k for k in order if k.startswith("val/texture/normal_pseudo") and f"test/{k[4:]}" in order]
        if realistic:  # the noise model chosen on val, read on test
            chosen = max(realistic, key=lambda k: order[k]["evidence"]["accuracy"])
            test = order[f"test/{chosen[4:]}"]["evidence"]
            acc, n = test["accuracy"], int(np.sum(test["confusion"]))
            lo, hi = wilson_interval(acc, n)
            rep.add(
                "",
                f"Verdict, pseudo geometry without the true albedo, the noise model best on val "
                f"(`{chosen[4:]}`, val {order[chosen]['evidence']['accuracy']:.2f}), on test: {acc:.2f} (95 % "
                f"interval {lo:.2f}-{hi:.2f} over its {n} scenes) against the target {ORDER_TARGET:.2f}: "
                f"**{'reached' if acc >= ORDER_TARGET else 'not reached'}**. Over {n} scenes a split, accuracies "
                "less than about 0.1 apart are within each other's sampling spread."
                + band2_reading(order, chosen[4:])
                + known_albedo_reading(order)
                + "\n",
            )
        rows = {
            "normal_pseudo_eroded": "on the pseudo geometry",
            "normal_pseudo_registered": "with its uv registered to the image",
            "oracle_uv": "with only its uv made true",
            "oracle_normals": "with only its normals made true",
            "oracle_placement": "with the coarse fit's placement (pose, scale, shift) made true",
            "oracle_shape": "with the coarse fit's shape (identity, expression) made true",
        }
        accuracy = {  # the oracle rows and the pseudo geometry they start from, texture model, i.i.d. noise
            (split, k): order[f"{split}/texture/{k}"]["evidence"]["accuracy"]
            for split in ("val", "test")
            for k in rows
            if f"{split}/texture/{k}" in order
        }
        rows = {k: text for k, text in rows.items() if ("val", k) in accuracy and ("test", k) in accuracy}
        if "normal_pseudo_eroded" in rows and any(k.startswith("oracle") for k in rows):
            oracles = [k for k in rows if k.startswith("oracle")]
            reached = [k for k in oracles if accuracy["test", k] >= ORDER_TARGET]
            rep.add(
                "Where the pseudo geometry's error comes from (texture model, i.i.d. noise, val/test accuracy): "
                + ", ".join(f"{accuracy['val', k]:.2f}/{accuracy['test', k]:.2f} {text}" for k, text in rows.items())
                + ". "
                + (
                    f"Made true alone, {' and '.join(reached)} reaches the target on test.\n"
                    if reached
                    else "Nothing made true alone brings the test accuracy to the target; the largest gain (val and "
                    f"test together) comes {rows[max(oracles, key=lambda k: accuracy['val', k] + accuracy['test', k])]}"
                    ".\n"
                )
            )
        for name in ("order_confusion", "order_confusion_val"):
            if (d / f"{name}.png").exists():
                rep.image(d / f"{name}.png", name)
        if (registration := _load_json(d / "registration.json")) and (d / "registration.png").exists():
            rep.add(
                "The texture model fitted through the pseudo, registered and true uv on val scenes under order-1 "
                f"light (`disent.lighting.experiments.plot_registration`); uv error, rms per axis over the shown "
                f"scenes: {registration['normal_pseudo_eroded']:.1f} px pseudo, "
                f"{registration['normal_pseudo_registered']:.1f} px registered.\n"
            )
            rep.image(d / "registration.png", "registration")
    if cal or cal_p:
        rep.add(
            "### Calibration of the posterior\n",
            "Known albedo; share of the true SH coefficients inside the 68 % and 95 % credible intervals "
            "(a calibrated posterior: 0.68 and 0.95) and the RMS of their z-scores (calibrated: 1), with "
            "effects at severity 0.5.\n",
            *table_head(
                "condition / likelihood",
                "true normals: 68 % / 95 % (z-RMS)",
                "pseudo normals + mask: 68 % / 95 % (z-RMS)",
            ),
        )
        cal, cal_p = cal or {}, cal_p or {}
        for key in dict.fromkeys(
            k for c in (cal, cal_p) for k, v in c.items() if isinstance(v, dict) and "inside68" in v
        ):
            cells = [
                f"{_pct(c[key]['inside68'])} / {_pct(c[key]['inside95'])} ({c[key]['z_rms']:.1f})" if key in c else "–"
                for c in (cal, cal_p)
            ]
            rep.add(f"| {key.replace('/', ' / ')} | {cells[0]} | {cells[1]} |")
        rep.add("")
        for name in ("calibration", "calibration_pseudo"):
            if (d / f"{name}.png").exists():
                rep.image(d / f"{name}.png", name)
    for name in ("widths", "example_corner", "example_shading_sd"):
        if (d / f"{name}.png").exists():
            rep.image(d / f"{name}.png", name)
    if speed:
        rep.add(
            "### Speed\n",
            f"One core, test item 0 ({speed['n_pixels']} face pixels): L-hat by least squares "
            f"{speed['ls_ms_per_image']:.2f} ms per image (batch {speed['ls_batch']}); the posterior "
            f"{speed['posterior_gaussian_s']:.2f} s with a Gaussian likelihood "
            f"({speed['posterior_gaussian_steps']:.0f} "
            f"steps), {speed['posterior_student_t_s']:.2f} s with Student-t ({speed['posterior_student_t_steps']:.0f} "
            "steps). Also `python -m disent.bench lighting`.\n",
        )


def _git_revision() -> str:
    try:
        return (
            subprocess.run(
                ["git", "rev-parse", "--short", "HEAD"],
                capture_output=True,
                text=True,
                timeout=10,
                cwd=Path(__file__).parent,
            ).stdout.strip()
            or "unknown"
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"


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
    rep = Report(out, previous, only=sections)
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
    built = f"`{_git_revision()}`, {_dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}"
    rep.add(
        "# disent report\n",
        "All numbers are measured on SynthFaces (its ground truth); nothing is copied from the paper except where "
        "marked *paper*. Each section comes from the build in the table below that names it (`python -m "
        "disent.report` at that revision), from the run folders under its roots and the records of earlier runs in "
        f"`{_rel(records, out)}/` (config, git revision, metrics and eval of each ended run the report has read, "
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
    for title, fn, needs in SECTIONS.values():
        rep.section(title, fn, *(inputs[k] for k in needs))
    path = out / name
    path.write_text("\n".join(rep.lines) + "\n")
    return path


SECTIONS = {  # name (--sections): title, builder, its inputs; in the report's order
    section_name(fn): (title, fn, needs)
    for title, fn, needs in (
        ("At a glance: the targets", sec_targets, ("runs",)),
        ("Runs", sec_runs, ("runs",)),
        ("Floor and ceiling: what each layer can reach", sec_ceiling, ("runs",)),
        ("The paper's claims, measured", sec_claims, ("runs", "eval_dir")),
        ("Teaser: input, recon, albedo, normal, shading, matte", sec_teaser, ("runs", "n_vis")),
        ("Lighting stability: SH variance (supplement protocol)", sec_sh_variance, ("eval_dir",)),
        ("Ablations", sec_ablation, ("runs",)),
        ("Stability where methods fail", sec_stability, ("eval_dir",)),
        ("Training recipe: leave-one-out", sec_recipe, ("runs",)),
        ("Learning curves", sec_learning_curves, ("runs",)),
        ("Real photos: the domain gap", sec_photos, ("out",)),
        ("Methods on one plane: time against accuracy", sec_methods, ("eval_dir",)),
        ("Benchmarks (`reports/bench*.json`)", sec_bench, ("out",)),
        ("L-hat uncertainty and lighting model order", sec_lighting, ("out",)),
    )
}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
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


if __name__ == "__main__":
    main()

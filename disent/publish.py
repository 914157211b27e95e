"""What reaches ``reports/``: a tool folder's results published there (``--publish``), and the records of ended
runs (``reports/runs.jsonl``), one row per run with its learning curve thinned to what the report draws.  A run is
named by its id there, never by its folder (:func:`disent.runs.portable`).  On top, beside the report."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

from disent.runs import TRAIN_SPEED_KEY, Run, portable, run_ref, run_speed
from disent.storage import atomic_write, load_json, read_jsonl

# Each tool writes into its own run folder; `python -m disent.report --publish FOLDER` copies what the report
# cites into reports/<PUBLISH_TO[tool]>/.  Weights (*.pt) and bookkeeping files are never published.
PUBLISH_TO = {
    "edit": "edit",
    "lighting": "lighting",
    "photos": "photos",
    "eval": "eval",
    "bench": ".",
    "sheet": "figures",
}  # a tool not named here (python -m disent.photos writes "decompose" folders) is never published
NOT_PUBLISHED = ("git.txt", "command.txt", ".tool")  # and weights (.pt), logs (.log), Hydra's .hydra/


def publish(folder, reports="reports") -> list[Path]:
    """Copy a tool folder's results into ``reports/`` (where its ``.tool`` says); returns the files written.
    A folder that is not a tool folder, or holds no results, is an error: nothing published is replaced by
    nothing."""
    folder = Path(folder)
    marker = folder / ".tool"
    if not marker.is_file():
        raise FileNotFoundError(
            f"{folder} is not a tool folder (no .tool file); tools write one, e.g. "
            "python -m disent.edit measure explicit"
        )
    tool = marker.read_text().strip()
    if tool not in PUBLISH_TO:
        raise ValueError(f"{marker}: the results of {tool!r} are not published; publishable: {', '.join(PUBLISH_TO)}")
    files = [
        p
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name not in NOT_PUBLISHED and p.suffix not in (".pt", ".log") and ".hydra" not in p.parts
    ]
    if not files:
        raise FileNotFoundError(f"{folder} holds no results to publish")
    dest = Path(reports) / PUBLISH_TO[tool]
    if tool == "edit":
        drop_remeasured(folder, dest)
    written = []
    for p in files:
        target = dest / p.relative_to(folder)
        target.parent.mkdir(parents=True, exist_ok=True)
        if p.suffix == ".png":  # pictures of faces: a 256-colour dithered palette keeps reports/ small
            compact_png(p, target)
        elif p.suffix == ".json":  # a run is named by its id in reports/, never by its folder
            new = _rounded_all(portable_runs(json.loads(p.read_text())), EVAL_DIGITS)
            if tool == "bench" and target.exists():  # the sections of this run replace theirs
                new = {**json.loads(target.read_text()), **new}
            atomic_write(target, lambda f: f.write(json.dumps(new, sort_keys=True, separators=(",", ":")).encode()))
        else:
            shutil.copyfile(p, target)
        written.append(target)
    return written


PUBLISHED_WIDTH = 900  # px


def compact_png(src: Path, dest: Path) -> None:
    """``src`` written to ``dest`` as a PNG at most :data:`PUBLISHED_WIDTH` px wide (a tool figure's 64-px faces
    keep every pixel) in 256 colours (a median-cut palette, Floyd-Steinberg dithered): about a quarter of its size;
    a PNG that is one already is copied."""
    from PIL import Image

    with Image.open(src) as im:
        if im.mode == "P":
            if Path(src).resolve() != Path(dest).resolve():
                shutil.copyfile(src, dest)
            return
        rgb = im.convert("RGB")
    if rgb.width > PUBLISHED_WIDTH:
        height = round(rgb.height * PUBLISHED_WIDTH / rgb.width)
        rgb = rgb.resize((PUBLISHED_WIDTH, height), Image.Resampling.LANCZOS)
    palette = rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    picture = rgb.quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG)
    atomic_write(dest, lambda f: picture.save(f, format="PNG", optimize=True))


def drop_remeasured(folder: Path, dest: Path) -> None:
    """Remove the published edit results (``dest/<name>/edit.json``) of each run that ``folder`` measured again
    under another name: a run's newer measurement replaces its older one, so no run counts twice."""

    def measured(root):
        found = {}
        for p in root.glob("*/edit.json"):
            if ref := run_ref((load_json(p) or {}).get("run")):  # a run, not a shipped model's name
                found.setdefault(ref, []).append(p.parent)
        return found

    again = measured(folder)
    for run, published in measured(dest).items():
        for old in published:
            if run in again and old.name not in {new.name for new in again[run]}:
                shutil.rmtree(old)


CURVE_EVERY = 5  # of the training log's loss rows, every 5th is kept (each validation record is kept)
CURVE_KEYS = ("step", "epoch", "wall", "minutes", "images_per_s", "total", "UV")  # what the report reads of a loss row
# what the learning-curve figure draws of each validation record, and its reference lines (the same at every record:
# kept in the last one)
CURVE_VAL_KEYS = ("normal_mean", "recon_face_psnr", "albedo_face_si_mse", "albedo_si_mse", "sh_error")
CURVE_VAL_KEYS += ("light_shading_si_mse",)
CURVE_REFERENCE_KEYS = ("trivial_normal_mean", "pseudo_normal_mean", "trivial_albedo_si_mse", "trivial_sh_error")
CURVE_REFERENCE_KEYS += ("pseudo_sh_error", "trivial_light_shading_si_mse", "pseudo_light_shading_si_mse")


EVAL_DIGITS = 7  # significant digits a record keeps of eval.json and a published JSON (replicates agree to 1e-6)


def _rounded(x, digits: int = 5):
    """A curve's value to ``digits`` significant digits (a figure draws no more)."""
    return float(f"{x:.{digits}g}") if isinstance(x, float) and math.isfinite(x) else x


def _rounded_all(value, digits: int):
    """Every float in ``value`` (nested dicts and lists) to ``digits`` significant digits."""
    if isinstance(value, dict):
        return {k: _rounded_all(v, digits) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded_all(v, digits) for v in value]
    return _rounded(value, digits)


def thinned_curve(metrics: list[dict]) -> list[dict]:
    """The learning curve a record keeps: every validation record (the values the figure draws,
    :data:`CURVE_VAL_KEYS`, and in the last one its reference lines, :data:`CURVE_REFERENCE_KEYS`), and of the loss
    rows every :data:`CURVE_EVERY`-th and the last, with the keys the report reads (:data:`CURVE_KEYS`), each to 5
    significant digits."""
    losses = [i for i, r in enumerate(metrics) if not isinstance(r.get("val"), dict)]
    kept = set(losses[::CURVE_EVERY] + losses[-1:])
    last_val = max((i for i, r in enumerate(metrics) if isinstance(r.get("val"), dict)), default=None)
    out = []
    for i, r in enumerate(metrics):
        row = {k: _rounded(r[k]) for k in CURVE_KEYS if k in r}
        if isinstance(r.get("val"), dict):
            keys = CURVE_VAL_KEYS + (CURVE_REFERENCE_KEYS if i == last_val else ())
            out.append({**row, "val": {k: _rounded(r["val"][k]) for k in keys if k in r["val"]}})
        elif i in kept:
            out.append(row)
    return out


def portable_runs(value):
    """A tool's JSON result with each ``run`` field that names a run folder replaced by ``run:ID`` (:func:`portable`):
    what :func:`publish` copies into ``reports/``."""
    if isinstance(value, dict):
        return {k: portable(v) if k == "run" else portable_runs(v) for k, v in value.items()}
    if isinstance(value, list):
        return [portable_runs(v) for v in value]
    return value


def record_row(run: Run) -> dict:
    """``run`` as one row of ``reports/runs.jsonl``: what it is (config, overrides, Hydra's group choices), how it
    ended (status from its whole log, eval, the median training speed), where it trained (revision, machine), and
    its learning curve thinned (:func:`thinned_curve`); paths become run ids (:func:`portable`)."""
    return portable(
        {
            "id": run.id,
            "model": run.model,
            "seed": run.seed,
            "status": run.status,
            "revision": run.revision,
            "recipe": run.recipe,
            "overrides": [str(o) for o in run.overrides],
            "choices": run.choices,
            "config": run.cfg,
            "eval": _rounded_all(run.eval, EVAL_DIGITS),
            "ended": run.ended,
            "machine": run.machine,
            "images_per_s": run_speed(run, TRAIN_SPEED_KEY),
            "curve": thinned_curve(run.metrics),
        }
    )


def write_records(runs, path) -> int:
    """Add the ended runs among ``runs`` (not ``incomplete``; run folders, not rows) to the records file ``path``,
    replacing a row of the same id; the file stays sorted by id and is written atomically.  Returns the rows added."""
    rows = {row["id"]: row for row in read_jsonl(path)}
    new = [record_row(r) for r in runs if r.record is None and r.status != "incomplete"]
    rows.update((row["id"], row) for row in new)
    text = "".join(json.dumps(rows[k], sort_keys=True, separators=(",", ":")) + "\n" for k in sorted(rows))
    atomic_write(Path(path), lambda f: f.write(text.encode()))
    return len(new)

"""The ablation table: every variant (model + ablations) as mean +- std over seeds.

``python -m disent.eval.ablation [ROOT ...] [--out FOLDER]`` reads run folders (default ``multirun/`` and
``outputs/``), writes ``ablation.json`` into a tool folder and prints the table.
The caption states the training budget read from the runs' own configs.
"""

from __future__ import annotations

import argparse
import json
import math

from disent.runs import RUN_ROOTS, Run, find_runs, setting
from disent.storage import dotted

# (key in eval.json, column title, lower is better)
COLUMNS = (
    ("recon_mse", "recon MSE", True),
    ("recon_face_psnr", "face PSNR", False),
    ("recon_face_ssim", "face SSIM", False),
    ("normal_mean", "normal err (deg)", True),
    ("pseudo_normal_mean", "pseudo-GT err (deg)", True),
    ("albedo_si_mse", "albedo SI-MSE", True),
    ("sh_error", "SH err", True),
)
MODEL_ORDER = ("baseline", "explicit", "implicit")
BUDGET_KEYS = (
    "train.steps",
    "train.max_steps",
    "train.epochs",
    "train.batch_size",
    "data.size",
    "data.train_size",
    "data.resolution",
)


def mean_std(values) -> dict | None:
    """``{mean, std (ddof 1; 0 for one value), n}`` of the finite numbers in ``values``; None if there are none."""
    v = [x for x in values if isinstance(x, (int, float)) and math.isfinite(x)]
    if not v:
        return None
    m = sum(v) / len(v)
    s = math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return {"mean": m, "std": s, "n": len(v)}


def seed_key(run, i: int):
    """What makes ``run`` (the ``i``-th of a list) one seed of one setting: its setting with its model
    (:func:`disent.runs.setting`) and its seed.  Runs sharing it are replicates (the same setting trained again at
    another revision or on another machine), not more seeds; a run without a seed is its own."""
    seed = getattr(run, "seed", None)
    return ("seed", setting(run), seed) if isinstance(run, Run) and seed is not None else ("run", i)


def seed_mean_std(runs, key: str) -> dict | None:
    """:func:`mean_std` of ``key`` over the seeds of ``runs``, each seed's replicates (:func:`seed_key`) averaged
    into one value.  ``runs``: how many runs gave a value (>= ``n``)."""
    by_seed: dict = {}
    for i, r in enumerate(runs):
        v = r.value(key)
        if isinstance(v, (int, float)) and math.isfinite(v):
            by_seed.setdefault(seed_key(r, i), []).append(v)
    st = mean_std([sum(v) / len(v) for v in by_seed.values()])
    if st is not None:
        st["runs"] = sum(map(len, by_seed.values()))
    return st


def budget(runs: list[Run]) -> dict:
    """The training budget the runs share: each budget key with its set of values."""
    out = {}
    for key in BUDGET_KEYS:
        vals = sorted({str(v) for r in runs if (v := dotted(r.cfg, key)) is not None})
        if vals:
            out[key] = vals[0] if len(vals) == 1 else vals
    exps = sorted({str(r.choices.get("experiment")) for r in runs if r.choices.get("experiment")})
    if exps:
        out["experiment"] = exps[0] if len(exps) == 1 else exps
    return out


def ablation_table(runs: list[Run]) -> dict:
    """``{"rows": [{variant, seeds, status, <key>: {mean,std,n}}], "budget": {...}}`` over finished runs."""
    by_variant = {}
    for r in runs:
        by_variant.setdefault(r.variant, []).append(r)

    def order(v):
        model, *abl = v.split("+")
        return (MODEL_ORDER.index(model) if model in MODEL_ORDER else 99, len(abl), v)

    rows = []
    for v in sorted(by_variant, key=order):
        rs = by_variant[v]
        ok = [r for r in rs if r.status == "ok"]
        row = {
            "variant": v,
            "seeds": sorted({r.seed for r in ok if r.seed is not None}),
            "runs": len(rs),
            "failed": {
                s: sum(r.status == s for r in rs)
                for s in ("nan", "diverged", "incomplete")
                if any(r.status == s for r in rs)
            },
        }
        for key, _, _ in COLUMNS:
            row[key] = seed_mean_std(ok, key)
        row["train_images_per_s"] = seed_mean_std(ok, "images_per_s")
        rows.append(row)
    return {"rows": rows, "budget": budget(runs)}


def mean_std_text(mean: float, std: float | None, fmt: str = "auto") -> str:
    """``mean ± std`` (``mean`` alone where ``std`` is None), both in ``fmt``; ``auto``: to the same decimal place,
    two where the mean is 1 or more (25.98 ± 0.10 dB), else the mean's fourth significant digit (0.003712 ±
    0.000140).  Every table's spread is written by this."""
    if fmt == "auto":
        places = 2 if abs(mean) >= 1 or mean == 0 or not math.isfinite(mean) else 3 - math.floor(math.log10(abs(mean)))
        fmt = f".{places}f"
    return f"{mean:{fmt}}" if std is None else f"{mean:{fmt}} ± {std:{fmt}}"


def _fmt(s):
    return "–" if s is None else mean_std_text(s["mean"], s["std"])


def to_markdown(table: dict) -> str:
    """The table as Markdown, best mean per column in bold, budget in the caption."""
    rows = table["rows"]
    if not rows:
        return "_No runs found: run the suite (see `ablations/README.md`)._\n"
    best = {}
    for key, _, low in COLUMNS:
        if key.startswith("pseudo_"):  # a reference (the supervision's own error), not a contestant
            continue
        vals = [r[key]["mean"] for r in rows if r[key]]
        if vals:
            best[key] = min(vals) if low else max(vals)
    head = "| variant | seeds | " + " | ".join(t + (" ↓" if low else " ↑") for _, t, low in COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 2)]
    for r in rows:
        cells = []
        for key, _, _ in COLUMNS:
            c = _fmt(r[key])
            if r[key] and best.get(key) == r[key]["mean"]:
                c = f"**{c}**"
            cells.append(c)
        seeds = f"{len(r['seeds'])}/{r['runs']}" + (
            f" ({', '.join(f'{n} {s}' for s, n in r['failed'].items())})" if r["failed"] else ""
        )
        lines.append(f"| {r['variant']} | {seeds} | " + " | ".join(cells) + " |")
    b = ", ".join(f"{k}={v}" for k, v in table["budget"].items()) or "not recorded in the run configs"
    caption = (
        f"Mean ± std over seeds, a seed's repeated runs averaged (seeds of the finished runs / all runs). Budget: {b}. "
        "Errors against SynthFaces ground truth on the test split; SH error after per-image scale alignment; "
        "pseudo-GT err is the pseudo normals' own error on the same pixels."
    )
    return "\n".join(lines) + f"\n\n_{caption}_\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("roots", nargs="*", default=list(RUN_ROOTS))
    p.add_argument("--out", default=None, help="output folder (default: outputs/eval/<date>/<time>-<pid>/)")
    a = p.parse_args(argv)
    from disent.storage import tool_folder

    table = ablation_table(find_runs(a.roots))
    md = to_markdown(table)
    out = tool_folder("eval", a.out)
    (out / "ablation.json").write_text(json.dumps(table, indent=1))
    print(md)
    print(f"wrote {out}/ablation.json (the report's Ablations section tables every budget: python -m disent.report)")


if __name__ == "__main__":
    main()

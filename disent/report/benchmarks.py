"""The benchmark section (``reports/bench*.json``, :mod:`disent.bench`): rates, fractions of peak, profiles."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from disent.images import pyplot, wrapped
from disent.report.document import Report
from disent.report.tables import fmt_value, table_head
from disent.storage import load_json

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
    plt = pyplot()
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
        [wrapped(label, 14) for _, label in rates],
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
    plt = pyplot()
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
        rows[key.removesuffix("spread_text").replace("_", " ") + f" ({ops['total']:.0f} ms)"] = share
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
    benches = [(p, b) for p in paths if isinstance(b := load_json(p), dict)]
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
        if device != "cpu":
            rep.add(suite_text(bench.get("suite")), "")
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


SUITE_TARGET_MIN, TOGETHER_TARGET_IMG_S = 15, 20_000  # issue targets: the 33 long runs, one process's runs


def suite_text(suite: dict | None) -> str:
    """The long-rung suite on this card: a slice's images per wall second across the runs of one process and the
    33 runs' projected minutes (``ablations/gpu_check.sh``), against the targets; or that it is not measured."""
    if not suite or not suite.get("images_per_s"):
        return (
            f"_Not measured on this card: the 33-run long-rung suite's wall time (target {SUITE_TARGET_MIN} min) and "
            f"explicit training across the runs of one process (target {TOGETHER_TARGET_IMG_S:,} images/s). "
            "`ablations/gpu_check.sh OUT` trains a slice of it together, with batches rendered on the card, and "
            "projects the whole._"
        )
    rate, minutes = suite["images_per_s"], suite["suite_projected_min"]
    return (
        f"The long-rung suite on this card (`ablations/gpu_check.sh`): a slice of {len(suite['runs'])} runs trained "
        f"{suite['images']:,} images in {suite['wall_s']:.0f} s of wall time, set-up and evaluation included: "
        f"**{rate:,.0f} images/s** across the runs (target {TOGETHER_TARGET_IMG_S:,}; "
        f"{'met' if rate >= TOGETHER_TARGET_IMG_S else 'missed'}). At that rate the 33 long runs take "
        f"**{minutes:.0f} min** (target {SUITE_TARGET_MIN}; {'met' if minutes <= SUITE_TARGET_MIN else 'missed'})."
    )


def time_to_accuracy_text(tta: dict) -> str:
    """One paragraph of ``python -m disent.bench time_to_accuracy``: when the run's normals beat each target."""
    reached = []
    for key, what in (("trivial", "the dataset-mean map"), ("pseudo_gt", "the pseudo-GT")):
        hit = tta.get(key) or {}
        if hit.get("minutes") is None:
            reached.append(f"{what} never (its {fmt_value(hit.get('target'), '.2f')} deg)")
        else:
            reached.append(
                f"{what} after **{hit['minutes']:.1f} training minutes** (step {hit['step']:,}, "
                f"{hit.get('images') or 0:,} images; {hit['normal_mean']:.2f} against {hit['target']:.2f} deg on the "
                f"{hit['source']} images)"
            )
    return (
        f"Time to accuracy (`python -m disent.bench time_to_accuracy --run RUN`, from the run's records): "
        f"`{tta['run']}`'s normals beat {reached[0]}, and {reached[1]}; its best "
        f"{fmt_value(tta.get('best_normal_mean'), '.2f')} deg after {fmt_value(tta.get('best_minutes'), '.1f')} "
        f"minutes."
    )

"""Where the methods fail, measured as curves (JSON + PNG in a tool folder, published to ``reports/eval/``).

1. ``bws``: without batch-wise white shading (BWS, Sec. 4.2) does shading collapse or take a
   colour cast, and does albedo absorb shading?  Shading mean per channel over the face and
   the correlation between estimated albedo and true shading, for runs with and without BWS
   and against the training batch size over which BWS averages.
2. ``conditioning``: the least-squares L-hat against yaw (frontal to profile) and against the
   face-mask size: condition number of the normal design ``A^T A`` and SH error.  The yaw
   or mask fraction where the median condition number (and, separately, the median SH error)
   first exceeds ``BLOWUP`` x its frontal / full-mask value is reported as the blow-up point.
3. ``ood``: error against severity for each SynthFaces effect (``specular, cast_shadow,
   noise, occluder``) and for lights outside the prior (``light``: the light turned about
   the camera's x axis by ``severity x 180`` degrees, from above towards below and behind),
   for each model and for least squares.
4. ``training``: NaN and divergence rate over seeds against learning rate, per model, with
   and without the adversarial loss, read from run folders.

``python -m disent.eval.stability [conditioning ood bws training]`` (default: all).  ``bws`` and
``training`` read their own sweeps (``BWS_ROOTS``, ``TRAINING_ROOTS``: the commands are in
``ablations/README.md``), so runs of other budgets or learning rates never mix into their curves;
each result carries the budget read from its runs' configs.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from pathlib import Path

import torch

from disent.data import get_batch
from disent.eval.metrics import sh_error
from disent.eval.scoring import batches, bws_stats, metrics_from_outputs, predict
from disent.regions import face_mask
from disent.render import design_condition, fit_sh, rotate_sh

BLOWUP = 10.0  # a condition number this many times the well-posed one marks the blow-up
YAWS = (0, 10, 20, 30, 40, 45, 50, 60, 70, 80, 90)
MASK_FRACTIONS = (1.0, 0.7, 0.5, 0.3, 0.2, 0.1, 0.05, 0.02)
SEVERITIES = (0.0, 0.25, 0.5, 0.75, 1.0)
EFFECTS = ("specular", "cast_shadow", "noise", "occluder", "light", "yaw", "scale")
MAX_YAW = 90.0  # the yaw effect at severity 1 (the training prior spans +-45 degrees)
MAX_SHRINK = 0.5  # the scale effect at severity 1 draws each face at half its scale (the prior spans +-10 %)
MIN_PIXELS = 9  # 9 unknowns per channel
ORACLE_NOISE = 0.02  # sensor noise of the oracle fit (images in [0, 1])
LS_ESTIMATORS = ("ls_pseudo", "ls_true", "ls_oracle_noisy")
# explicit model against train.batch_size: with BWS, without, and without BWS and with the raw L-hat target
# (loss.lhat_white=false: E_recon-L's default target is L-hat scaled to BWS's shading mean, a second whitening)
BWS_ROOTS = ("multirun/bws", "multirun/bws_off", "multirun/bws_off_raw")
TRAINING_ROOTS = ("multirun/lr", "multirun/lr_no_adv")  # every model against train.lr, with / without adversary


def _median(x: torch.Tensor) -> float:
    return x.double().median().item()


def _ls_errors(batch: dict, pseudo_mask=None, true_mask=None) -> dict:
    """Design condition and aligned SH error of L-hat for three set-ups:

    ``ls_pseudo`` (pseudo normals and mask, constant albedo: the paper's L-hat), ``ls_true``
    (true normals, face mask, constant albedo) and ``ls_oracle_noisy`` (true normals and true
    albedo, the image plus Gaussian noise of ``ORACLE_NOISE``): the last isolates how the
    design's conditioning amplifies noise, since the noise-free oracle fit is exact.
    """
    pm = batch["mask_pseudo"] if pseudo_mask is None else pseudo_mask
    tm = face_mask(batch["matte"]) if true_mask is None else true_mask
    g = torch.Generator().manual_seed(0)
    noisy = batch["image"] + ORACLE_NOISE * torch.randn(batch["image"].shape, generator=g)
    out = {}
    for name, image, normal, mask, albedo in (
        ("ls_pseudo", batch["image"], batch["normal_pseudo"], pm, None),
        ("ls_true", batch["image"], batch["normal"], tm, None),
        ("ls_oracle_noisy", noisy, batch["normal"], tm, batch["albedo"]),
    ):
        sh, _ = fit_sh(image, normal, mask, albedo=albedo, min_pixels=MIN_PIXELS)
        out[f"{name}_cond"] = design_condition(normal.double(), mask.double())
        out[f"{name}_sh_error"] = sh_error(sh, batch["sh"], reduction="none")
    return out


def _summarize(per_image: dict) -> dict:
    return {k: {"median": _median(v), "p90": v.double().quantile(0.9).item()} for k, v in per_image.items()}


def first_past(xs, values, reference: float, factor: float = BLOWUP):
    """First x whose value exceeds ``factor x reference`` or is not finite (None if never)."""
    for x, v in zip(xs, values):
        if not math.isfinite(v) or v > factor * reference:
            return x
    return None


# ----------------------------------------------------------------------------- 2. conditioning
def conditioning_vs_yaw(dataset, yaws=YAWS, n: int = 16) -> dict:
    """L-hat conditioning and error for the first ``n`` faces turned to each yaw (pitch = roll = 0)."""
    rows = []
    for yaw in yaws:
        try:
            batch = get_batch(dataset, range(n), pose=torch.tensor([float(yaw), 0.0, 0.0]))
        except (ValueError, NotImplementedError) as e:  # a generator that refuses a pose beyond its range
            rows.append({"yaw": yaw, "error": str(e)})
            continue
        rows.append(
            {
                "yaw": yaw,
                "face_pixels": _median(face_mask(batch["matte"]).flatten(1).sum(1)),
                **_summarize(_ls_errors(batch)),
            }
        )
    return _with_blowups(rows, "yaw", n)


def _with_blowups(rows: list, axis: str, n: int) -> dict:
    """The study's rows plus, per LS estimator, where its condition number and SH error first reach
    ``BLOWUP`` times their value at the first row of ``axis``."""
    ok = [r for r in rows if "error" not in r]
    res = {"rows": rows, "n": n, "blowup_factor": BLOWUP}
    for est in LS_ESTIMATORS:
        for q in ("cond", "sh_error") if ok else ():
            res[f"{est}_blowup_{axis}" + ("" if q == "cond" else "_error")] = first_past(
                [r[axis] for r in ok], [r[f"{est}_{q}"]["median"] for r in ok], ok[0][f"{est}_{q}"]["median"]
            )
    return res


def shrink_mask(mask: torch.Tensor, fraction: float) -> torch.Tensor:
    """Keep the ``fraction`` of each image's mask nearest its centroid (a smaller, rounder face crop)."""
    B, _, H, W = mask.shape
    m = mask[:, 0] > 0.5
    yy, xx = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    cnt = m.flatten(1).sum(1).clamp_min(1).double()
    cy = (m * yy).flatten(1).sum(1) / cnt
    cx = (m * xx).flatten(1).sum(1) / cnt
    d = (yy - cy[:, None, None]) ** 2 + (xx - cx[:, None, None]) ** 2
    d = torch.where(m, d, torch.inf).flatten(1)
    k = (cnt * fraction).ceil().long().clamp_min(1)
    kth = d.sort(1).values.gather(1, (k - 1)[:, None])  # distance of the k-th nearest face pixel
    return ((d <= kth) & m.flatten(1)).reshape(B, 1, H, W).to(mask.dtype)


def conditioning_vs_mask(dataset, fractions=MASK_FRACTIONS, n: int = 32) -> dict:
    """L-hat conditioning and error as the face mask shrinks towards its centre (frontal-to-random poses as sampled)."""
    batch = next(iter(batches(dataset, n, n)))
    rows = []
    for f in fractions:
        pm, tm = shrink_mask(batch["mask_pseudo"], f), shrink_mask(face_mask(batch["matte"]), f)
        try:
            stats = _summarize(_ls_errors(batch, pm, tm))
        except ValueError as e:  # fewer than MIN_PIXELS pixels
            rows.append({"fraction": f, "error": str(e)})
            continue
        rows.append({"fraction": f, "face_pixels": _median(tm.flatten(1).sum(1)), **stats})
    return _with_blowups(rows, "fraction", n)


# ----------------------------------------------------------------------------- 3. out of distribution
def tilt_light(sh: torch.Tensor, severity: float) -> torch.Tensor:
    """The light ``sh [B,C,9]`` turned about the camera x axis by ``severity x 180`` degrees."""
    a = math.pi * severity
    R = torch.tensor([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]], dtype=torch.float64)
    return rotate_sh(sh.double(), R).to(sh.dtype)


def ood_batch(dataset_cls, effect: str, severity: float, n: int, resolution: int = 64) -> dict:
    """``n`` test items with one effect at ``severity`` (``light``: the tilted light; ``yaw``: every face turned
    to ``severity x MAX_YAW`` degrees, pitch = roll = 0; ``scale``: every face drawn at ``1 - severity x
    MAX_SHRINK`` times its scale, its pseudo-GT fit with it)."""
    if effect in ("light", "yaw", "scale"):
        ds = dataset_cls(split="test", resolution=resolution, seed=0)
        if effect == "yaw":
            return get_batch(ds, range(n), pose=torch.tensor([severity * MAX_YAW, 0.0, 0.0]))
        if effect == "scale":
            return get_batch(ds, range(n), scale=ds.params(range(n))["scale"] * (1 - severity * MAX_SHRINK))
        return get_batch(ds, range(n), sh=tilt_light(get_batch(ds, range(n))["sh"], severity))
    ds = dataset_cls(split="test", resolution=resolution, seed=0, effects={effect: severity} if severity > 0 else None)
    return get_batch(ds, range(n))


OOD_KEYS = ("recon_face_mse", "normal_mean", "albedo_si_mse", "sh_error", "uv_error", "normal_at_true_uv_mean")


def ood_curves(
    dataset_cls, models: dict, effects=EFFECTS, severities=SEVERITIES, n: int = 32, resolution: int = 64
) -> dict:
    """Error against severity per effect: least squares (pseudo and true normals) and each model."""
    res = {"severities": list(severities), "n": n, "effects": {}}
    for effect in effects:
        curves = {}
        for s in severities:
            batch = ood_batch(dataset_cls, effect, s, n, resolution)
            ls = _ls_errors(batch)
            for est in LS_ESTIMATORS:
                curves.setdefault(est, {}).setdefault("sh_error", []).append(ls[f"{est}_sh_error"].mean().item())
            for name, model in models.items():
                out = predict(model, batch["image"])
                m = metrics_from_outputs(out, batch)
                for k in OOD_KEYS:
                    if k in m:
                        curves.setdefault(name, {}).setdefault(k, []).append(m[k])
        res["effects"][effect] = curves
    return res


# ----------------------------------------------------------------------------- 1. BWS
def bws_study(runs, dataset, n: int = 64) -> dict:
    """:func:`bws_stats` for every finished run of the explicit/implicit models, with its BWS setting and batch size."""
    from disent.config import loss_setting
    from disent.eval.ablation import budget
    from disent.runs import load_models

    rows, used = [], []
    batch = next(iter(batches(dataset, n, n)))
    for r in runs:
        if r.model not in ("explicit", "implicit") or r.checkpoint is None or r.status != "ok":
            continue
        model = next(iter(load_models([r], [r.variant]).values()), None)
        if model is None:
            continue
        out = predict(model, batch["image"])
        bs = r.cfg.get("train", {}).get("batch_size") if isinstance(r.cfg.get("train"), dict) else None
        steps = (r.eval or {}).get("steps")
        loss = r.cfg.get("loss") if isinstance(r.cfg.get("loss"), dict) else {}
        bws = "no_bws" not in r.ablations and bool((loss.get("weights") or {}).get("BWS", 1.0))
        rows.append(
            {
                "run": str(r.path),
                "variant": r.variant,
                "model": r.model,
                "seed": r.seed,
                "bws": bws,
                "lhat_white": bool(loss_setting(loss, "lhat_white")),
                "batch_size": bs,
                "steps": steps,
                "normal_mean": (r.eval or {}).get("normal_mean"),  # test split: is the model trained at all?
                "trivial_normal_mean": (r.eval or {}).get("trivial_normal_mean"),
                **bws_stats(out, batch),
            }
        )
        used.append(r)
    return {"rows": rows, "n": n, "budget": budget(used)}


# ----------------------------------------------------------------------------- 4. training
SPIKE = 1e3  # a logged total loss this many times the run's smallest one marks an explosion
COLLAPSE = 0.01  # output spread across images below this share of the input's: the output ignores the input


def mean_image_mse(dataset, n: int) -> float:
    """Reconstruction MSE of the mean image of the first ``n`` items, the best constant output: a run
    no better than it on the same test images has collapsed (it learnt nothing about its input)."""
    img = next(iter(batches(dataset, n, n)))["image"].double()
    return ((img - img.mean(0, keepdim=True)) ** 2).mean().item()


def input_dependence(model, images: torch.Tensor) -> float:
    """Spread of ``model``'s reconstructions across ``images`` over the images' own spread (std over the
    batch, averaged over pixels): about 1 for a model that follows its input, 0 for a dead one."""
    recon = predict(model, images)["recon"].double()
    return (recon.std(0).mean() / images.double().std(0).mean().clamp_min(1e-12)).item()


def outcome(run, dependence=None) -> str:
    """How a training run ended: ``nan`` / ``diverged`` (:attr:`Run.status`), ``exploded`` (finite,
    but a logged total loss reached ``SPIKE`` x the run's smallest: the blow-up can happen before the
    first log, which the last-over-first rule then misses), ``collapsed`` (finished, but its output no
    longer depends on its input: ``dependence`` from :func:`input_dependence` below ``COLLAPSE``),
    ``ok``, or ``incomplete``."""
    st = run.status
    if st != "ok":
        return st
    key = "total" if any("total" in r for r in run.metrics) else "loss"
    losses = [r[key] for r in run.metrics if isinstance(r.get(key), (int, float)) and math.isfinite(r[key])]
    if losses and min(losses) > 0 and max(losses) > SPIKE * min(losses):
        return "exploded"
    if dependence is not None and dependence < COLLAPSE:
        return "collapsed"
    return "ok"


FAILURES = ("nan", "diverged", "exploded", "collapsed")


def loss_ratio(run):
    """Last over first logged total loss of a run (None when fewer than two finite values were logged)."""
    key = "total" if any("total" in r for r in run.metrics) else "loss"
    losses = [r[key] for r in run.metrics if isinstance(r.get(key), (int, float)) and math.isfinite(r[key])]
    return losses[-1] / losses[0] if len(losses) >= 2 and losses[0] > 0 else None


def _median_or_none(xs):
    xs = sorted(x for x in xs if x is not None and math.isfinite(x))
    return xs[len(xs) // 2] if xs else None


def training_stability(runs, images=None, reference_mse=None) -> dict:
    """Failure rates over seeds for each (model, adversarial on/off, learning rate): ``nan_rate``,
    ``diverged_rate``, ``exploded_rate``, ``collapsed_rate`` (:func:`outcome`; the last needs test
    ``images`` to run each checkpoint on), with medians of the last/first and largest/smallest logged
    total loss, of the test recon MSE and of the input dependence.  ``reference_mse`` (the mean test
    image's recon MSE) is kept for the plot."""
    from disent.eval.ablation import budget
    from disent.models import load_run

    def dependence(r):
        if images is None or r.checkpoint is None or r.status != "ok":
            return None
        model, _ = load_run(r.path)
        return input_dependence(model.eval(), images)

    groups = {}
    for r in runs:
        if r.status == "incomplete" or r.ablations not in ([], ["no_adv"]):
            continue
        groups.setdefault((r.model, r.adversarial, r.lr), []).append(r)
    rows = []
    for (m, adv, lr), rs in sorted(groups.items(), key=str):
        dep = [dependence(r) for r in rs]
        s = [outcome(r, d) for r, d in zip(rs, dep)]

        def spread(r):  # largest over smallest logged total loss: the quantity the explosion rule thresholds
            key = "total" if any("total" in x for x in r.metrics) else "loss"
            ls = [x[key] for x in r.metrics if isinstance(x.get(key), (int, float)) and math.isfinite(x[key])]
            return max(ls) / min(ls) if len(ls) >= 2 and min(ls) > 0 else None

        rows.append(
            {
                "model": m,
                "adversarial": adv,
                "lr": lr,
                "runs": len(s),
                **{f"{f}_rate": s.count(f) / len(s) for f in FAILURES},
                "loss_ratio": _median_or_none(loss_ratio(r) for r in rs),
                "loss_spread": _median_or_none(spread(r) for r in rs),
                "recon_mse": _median_or_none(r.value("recon_mse") for r in rs),
                "normal_mean": _median_or_none(r.value("normal_mean") for r in rs),
                "input_dependence": _median_or_none(dep),
            }
        )
    return {
        "rows": rows,
        "budget": budget([r for rs in groups.values() for r in rs]),
        "reference_mse": reference_mse,
        "spike": SPIKE,
    }


# ----------------------------------------------------------------------------- plots
def _plt():
    from disent.images import pyplot

    plt = pyplot()

    return plt


def budget_text(budget) -> str:
    """``key=value, ...`` of a result's ``budget`` (the runs' own configs), for titles and captions."""

    def num(v):
        try:
            return (0, float(v), "")
        except ValueError:
            return (1, 0.0, str(v))

    if not budget:
        return "budget not recorded"
    return ", ".join(
        f"{k.split('.')[-1]}={'/'.join(sorted(map(str, v), key=num)) if isinstance(v, list) else v}"
        for k, v in budget.items()
    )


def _save(fig, path):
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    _plt().close(fig)


def plot_conditioning(yaw: dict, mask: dict, path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(8, 5.5), sharex="col")
    for col, (res, key, label) in enumerate(
        ((yaw, "yaw", "yaw (degrees)"), (mask, "fraction", "share of face mask kept"))
    ):
        ok = [r for r in res["rows"] if "error" not in r]
        xs = [r[key] for r in ok]
        for k, (est, style) in enumerate(zip(LS_ESTIMATORS, ("o-", "s--", "^:"))):
            axes[0, col].plot(xs, [r[f"{est}_cond"]["median"] for r in ok], style, label=est)
            axes[1, col].plot(xs, [r[f"{est}_sh_error"]["median"] for r in ok], style, label=est)
            b = res.get(f"{est}_blowup_{key if key == 'yaw' else 'fraction'}")
            if b is not None:
                axes[0, col].axvline(b, color=f"C{k}", lw=0.8, ls=":")
        axes[0, col].set_yscale("log")
        axes[1, col].set_yscale("log")
        axes[0, col].set_ylabel("cond(A^T A), median")
        axes[1, col].set_ylabel("relative SH error (aligned), median")
        axes[1, col].set_xlabel(label)
        if key == "fraction":
            axes[1, col].invert_xaxis()
        axes[0, col].legend(fontsize=7)
    fig.suptitle(f"L-hat conditioning (dotted: median cond > {BLOWUP:g}x the well-posed value)", fontsize=9)
    _save(fig, path)


def plot_ood(res: dict, path) -> None:
    plt = _plt()
    effects = list(res["effects"])
    keys = ("sh_error", "normal_mean", "albedo_si_mse", "recon_face_mse")
    fig, axes = plt.subplots(len(keys), len(effects), figsize=(2.6 * len(effects), 2.0 * len(keys)), squeeze=False)
    names = list(dict.fromkeys(n for e in effects for n in res["effects"][e]))
    colour = {n: f"C{i % 10}" for i, n in enumerate(names)}  # one colour per estimator in every panel
    titles = {"yaw": f"yaw (severity x {MAX_YAW:g} deg)", "scale": f"scale (x 1 - {MAX_SHRINK:g} severity)"}
    for j, e in enumerate(effects):
        for i, k in enumerate(keys):
            ax = axes[i, j]
            for name, c in res["effects"][e].items():
                if k in c:
                    ax.plot(res["severities"], c[k], "o-", ms=3, color=colour[name], label=name)
            if i == 0:
                ax.set_title(titles.get(e, e), fontsize=9)
            if j == 0:
                ax.set_ylabel(k, fontsize=8)
            if i == len(keys) - 1:
                ax.set_xlabel("severity")
    for i in range(len(keys)):
        if axes[i, 0].get_legend_handles_labels()[0]:
            axes[i, 0].legend(fontsize=6)
    _save(fig, path)


# the BWS study's arms by (BWS term on, E_recon-L's L-hat target whitened), as the figure and the report name them
BWS_ARMS = {
    (True, True): "with BWS",
    (False, True): "without BWS (L-hat target still white)",
    (False, False): "without BWS, raw L-hat target",
}


def bws_arm(row: dict) -> tuple:
    """A BWS study row's arm (``ablations/bws.sh``): (BWS term on, E_recon-L's L-hat target whitened)."""
    return row["bws"], row.get("lhat_white", True)


def bws_budgets(rows: list) -> list:
    """The BWS study's training budgets, ``[(label, keep)]``: every batch size at the largest batch's steps (a
    small batch then also sees fewer images) and, where the study has runs for it, every batch size on the
    largest batch's images (``ablations/bws.sh`` with IMAGES)."""
    sized = [r for r in rows if r["batch_size"] is not None and r.get("steps") is not None]
    if not sized:
        return [("", lambda r: r["batch_size"] is not None)]
    top = max(sized, key=lambda r: r["batch_size"])
    steps, images = top["steps"], top["steps"] * top["batch_size"]
    budgets = [(f"{steps} steps", lambda r: r.get("steps") == steps)]
    if any(r["steps"] != steps and r["steps"] * r["batch_size"] == images for r in sized):
        budgets.append((f"{images:,} images", lambda r: (r.get("steps") or 0) * r["batch_size"] == images))
    return budgets


def plot_bws(res: dict, path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 5, figsize=(20, 3.8))
    rows = res["rows"]
    style = {(True, True): ("o", "C0"), (False, True): ("x", "C1"), (False, False): ("^", "C2")}  # marker, colour
    # (but in the first panel: a colour per channel)
    for (key, arm), (k, budget) in itertools.product(BWS_ARMS.items(), enumerate(bws_budgets(rows))):
        marker, color = style[key]
        by_bs = {}
        for r in rows:
            if bws_arm(r) == key and r["batch_size"] is not None and budget[1](r):
                by_bs.setdefault(r["batch_size"], []).append(r)
        if len(by_bs) < 1 + k:  # the fixed-images line (k = 1) needs a batch size besides the largest
            continue
        ls = ("-", "--")[k]
        bs = sorted(by_bs)

        def mean(key, c=None):  # over seeds
            return [sum(r[key] if c is None else r[key][c] for r in by_bs[b]) / len(by_bs[b]) for b in bs]

        seeds = max(len(v) for v in by_bs.values())
        label = f"{arm}{', ' + budget[0] if budget[0] else ''}, {seeds} seed{'s' if seeds > 1 else ''}"
        for c, channel in enumerate(("r", "g", "b")):
            axes[0].plot(
                bs,
                mean("shading_mean_rgb", c),
                marker + ls,
                color=channel,
                label=f"{label} ({channel})" if c == 0 else None,
            )
        axes[1].plot(bs, mean("shading_cast"), marker + ls, color=color, label=label)
        axes[2].plot(bs, mean("albedo_shading_corr"), marker + ls, color=color, label=label)
        if all("shading_albedo_tone_corr" in r for b in bs for r in by_bs[b]):  # studies scored before it lack it
            axes[3].plot(bs, mean("shading_albedo_tone_corr"), marker + ls, color=color, label=label)
        if all(r.get("normal_mean") is not None for b in bs for r in by_bs[b]):
            axes[4].plot(bs, mean("normal_mean"), marker + ls, color=color, label=label)
    axes[0].axhline(0.75, color="k", lw=0.6, ls=":")
    truth = [r["true_shading_albedo_tone_corr"] for r in rows if "true_shading_albedo_tone_corr" in r]
    if truth:
        axes[3].axhline(truth[0], color="k", lw=0.6, ls=":", label="true shading")
    floor = [r["trivial_normal_mean"] for r in rows if r.get("trivial_normal_mean") is not None]
    if floor:  # above it a run has not learned its geometry: its other panels describe an untrained model
        axes[4].axhline(floor[0], color="k", lw=0.6, ls=":", label="dataset-mean normal map")
    steps_text = " (solid) and ".join(label for label, _ in bws_budgets(rows) if label)
    steps_text += " (dashed)" if " and " in steps_text else ""
    for ax, t in zip(
        axes,
        (
            "shading mean per channel (BWS target 0.75)",
            "colour cast (max - min channel mean)",
            "corr(albedo, true shading)",
            "corr over faces: shading's tone, skin's tone",
            "normals, test (deg): did the run learn its geometry?",
        ),
    ):
        ax.set_xscale("log")
        ax.set_xlabel(
            "training batch size (BWS averages over it)"
            + (f"\nevery batch size trained for {steps_text}" if steps_text else ""),
            fontsize=7,
        )
        ax.set_title(t, fontsize=8)
        if ax.has_data():
            ax.legend(fontsize=6)
        else:
            ax.set_axis_off()
    fig.suptitle(
        f"BWS against batch size, mean over seeds ({budget_text(res.get('budget'))}; {res.get('n', '?')} test images)",
        fontsize=8,
    )
    _save(fig, path)


def failure_rate(row: dict) -> float:
    """Share of a group's runs that failed in any way (:data:`FAILURES`)."""
    return sum(row.get(f"{f}_rate", 0.0) for f in FAILURES)


def plot_training(res: dict, path) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    models = sorted({r["model"] for r in res["rows"]})
    panels = (
        (None, "share of seeds failed\n(NaN, diverged, exploded or collapsed)"),
        ("loss_spread", "largest / smallest logged total loss (median)"),
        ("recon_mse", "test recon MSE (median)"),
    )
    for k, m in enumerate(models):
        for adv, ls in ((True, "-"), (False, "--")):
            sel = sorted(
                (r for r in res["rows"] if r["model"] == m and r["adversarial"] == adv and r["lr"]),
                key=lambda r: r["lr"],
            )
            if not sel:
                continue
            label = f"{m} {'adv' if adv else 'no adv'}"
            for ax, (key, _) in zip(axes, panels):
                shift = 1 + 0.05 * (2 * k + (not adv) - len(models))  # side by side where curves coincide
                pts = [(r["lr"] * shift, failure_rate(r) if key is None else r.get(key)) for r in sel]
                pts = [p for p in pts if p[1] is not None]
                ax.plot(
                    [p[0] for p in pts], [p[1] for p in pts], ("o" if adv else "x") + ls, color=f"C{k}", label=label
                )
    for ax, (key, ylabel) in zip(axes, panels):
        ax.set_xscale("log")
        ax.set_xlabel("learning rate")
        ax.set_ylabel(ylabel, fontsize=8)
        if key is not None:
            ax.set_yscale("log")
    axes[0].set_ylim(-0.05, 1.05)
    axes[0].legend(fontsize=6)
    axes[1].axhline(res.get("spike", SPIKE), color="k", lw=0.6, ls=":")
    if res.get("reference_mse"):
        axes[2].axhline(res["reference_mse"], color="k", lw=0.6, ls=":")
        axes[2].set_title("dotted: the mean test image's MSE (reference)", fontsize=8)
    axes[1].set_title("dotted: explosion line", fontsize=8)
    axes[0].set_title(f"collapsed: output spread < {COLLAPSE:g} x input spread", fontsize=8)
    fig.suptitle(f"Training stability ({budget_text(res.get('budget'))})", fontsize=8)
    _save(fig, path)


# ----------------------------------------------------------------------------- command
def main(argv=None):
    from disent.runs import RUN_ROOTS, find_runs, load_models
    from disent.storage import tool_folder

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("studies", nargs="*", default=["conditioning", "ood", "bws", "training"])
    p.add_argument("--out", default=None, help="output folder (default: outputs/eval/<date>/<time>-<pid>/)")
    p.add_argument("--n", type=int, default=32, help="images per point")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--roots", nargs="*", default=list(RUN_ROOTS), help="folders searched for runs (ood: the models)")
    p.add_argument("--bws-roots", nargs="*", default=list(BWS_ROOTS), help="the BWS batch-size sweeps")
    p.add_argument("--training-roots", nargs="*", default=list(TRAINING_ROOTS), help="the learning-rate sweeps")
    a = p.parse_args(argv)
    torch.manual_seed(0)
    out = tool_folder("eval", a.out)
    runs = find_runs(a.roots) if "ood" in a.studies else []

    def write(name, res):
        (out / f"{name}.json").write_text(json.dumps(res, indent=1))
        print(f"wrote {out / name}.json")

    if "conditioning" in a.studies or "ood" in a.studies or "bws" in a.studies:
        from disent.data import SynthFaces
    if "conditioning" in a.studies:
        test = SynthFaces(split="test", resolution=a.resolution, seed=0)
        yaw, mask = conditioning_vs_yaw(test, n=a.n // 2), conditioning_vs_mask(test, n=a.n)
        write("conditioning", {"yaw": yaw, "mask": mask})
        plot_conditioning(yaw, mask, out / "conditioning.png")
        for est in LS_ESTIMATORS:
            print(
                f"{est}: x{BLOWUP:g} condition at yaw {yaw.get(est + '_blowup_yaw')}, mask fraction "
                f"{mask.get(est + '_blowup_fraction')}; x{BLOWUP:g} SH error at yaw "
                f"{yaw.get(est + '_blowup_yaw_error')}, "
                f"mask fraction {mask.get(est + '_blowup_fraction_error')}"
            )
    if "ood" in a.studies:
        res = ood_curves(SynthFaces, load_models(runs), n=a.n, resolution=a.resolution)
        write("ood", res)
        plot_ood(res, out / "ood.png")
    if "bws" in a.studies:
        res = bws_study(find_runs(a.bws_roots), SynthFaces(split="test", resolution=a.resolution, seed=0), n=2 * a.n)
        if res["rows"]:  # no runs: nothing written, so publishing never replaces a study with an empty one
            write("bws", res)
            plot_bws(res, out / "bws.png")
        else:
            print(f"bws: no runs under {' '.join(a.bws_roots)}; nothing written")
    if "training" in a.studies:
        from disent.data import SynthFaces

        truns = find_runs(a.training_roots)
        n_eval = sorted({int(r.eval["n_eval"]) for r in truns if r.eval and r.eval.get("n_eval")})
        test = SynthFaces(split="test", resolution=a.resolution, seed=0)
        ref = mean_image_mse(test, n_eval[0]) if len(n_eval) == 1 else None
        res = {**training_stability(truns, next(iter(batches(test, a.n, a.n)))["image"], ref), "n": a.n}
        if res["rows"]:
            write("training", res)
            plot_training(res, out / "training.png")
        else:
            print(f"training: no runs under {' '.join(a.training_roots)}; nothing written")


if __name__ == "__main__":
    main()

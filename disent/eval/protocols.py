"""The paper's lighting-stability protocol (supplement, "Quantitative Experiments").

On the ``lightbank`` split (fixed light conditions x identities x poses), each estimator
gives one SH estimate per image; for every light condition we take the variance of each
coefficient across identities and poses, then average over conditions and RGB.  The
paper reports 0.36 for a 3DMM least-squares fit and 0.16 for its network's Z_L.

Estimators, side by side:

* ``ls_pseudo``: the paper's L-hat, ``fit_sh`` with the pseudo normals over the pseudo mask
  (constant albedo, Sec. 4.2), the 3DMM baseline;
* ``ls_true``: the same least squares with the true normals over the true face mask;
* ``ls_oracle``: least squares with true normals and true albedo (a check: near zero variance);
* ``true``: the generator's SH (exactly zero variance by construction);
* one entry per trained model: its Z_L (``outputs["sh"]``).

The raw variance depends on each estimator's scale (constant-albedo fits absorb skin tone,
Z_L has its own scale), so ``relative`` divides it by the estimator's mean squared
coefficient over the whole split: a scale-free companion number.  A constant estimator has
zero variance and says nothing about the light, so two more numbers sit beside it:
``within_share``, the within-condition variance over the variance across all images (1: the
estimate ignores the light; 0: it depends on the light only), and the SH error against the truth.

A face's normals cover part of the sphere, so some SH directions barely change its shading and no image of it
pins them down (:func:`disent.eval.metrics.sh_error_split`).  An estimator's spread in those directions
says nothing about the light, so ``variance_shown`` / ``variance_hidden`` split the within-condition variance
(each estimate scaled to the truth in shading first, a share of the true light's squared norm) by the directions
the face shows and those it hides (:func:`sh_variance_shown_hidden`), and ``sh_error_shown`` / ``sh_error_hidden``
split the error the same way.  ``mean_light`` (the training split's mean true light, the trivial baseline) sits
beside the estimators: its only spread is its per-image scale.

``python -m disent.eval.protocols`` writes ``sh_variance.json`` and its bar chart (a tool folder, published
to ``reports/eval/``).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

from disent.eval.metrics import scale_in_shading, sh_error, sh_error_split, sh_gram, shown_hidden_energy
from disent.eval.scoring import batches, predict
from disent.regions import face_mask
from disent.render import SH_NAMES, fit_sh


def sh_variance(sh: torch.Tensor, condition: torch.Tensor) -> dict:
    """Within-condition variance of SH estimates ``sh [N,C,9]`` grouped by ``condition [N]``.

    Variance is unbiased (ddof 1) over the images of each condition; conditions with fewer
    than 2 images are skipped.  Returns ``per_coeff`` (9 values averaged over conditions and
    channels), ``mean`` (their mean, the paper's number) and ``relative`` (``mean`` divided by
    the estimator's mean squared coefficient).
    """
    if sh.dim() != 3 or sh.shape[-1] != 9 or condition.shape != sh.shape[:1]:
        raise ValueError(f"need sh [N,C,9] and condition [N], got {tuple(sh.shape)} and {tuple(condition.shape)}")
    x = sh.double()
    ids, inv, counts = torch.unique(condition, return_inverse=True, return_counts=True)
    K = len(ids)
    s1 = torch.zeros(K, *x.shape[1:], dtype=x.dtype).index_add_(0, inv, x)
    s2 = torch.zeros(K, *x.shape[1:], dtype=x.dtype).index_add_(0, inv, x * x)
    n = counts.double().reshape(K, 1, 1)
    keep = counts >= 2
    if not keep.any():
        raise ValueError("sh_variance needs a condition with at least 2 images")
    var = ((s2 - s1 * s1 / n) / (n - 1).clamp_min(1)).clamp_min(0)[keep]  # [K',C,9]
    per_coeff = var.mean((0, 1))
    mean = per_coeff.mean().item()
    scale = x.pow(2).mean().item()
    total = x[keep[inv]].var(0).mean().item()  # variance over all images, conditions pooled
    return {
        "per_coeff": per_coeff.tolist(),
        "mean": mean,
        "relative": mean / scale if scale > 0 else float("nan"),
        "within_share": mean / total if total > 0 else float("nan"),
        "n_images": int(counts[keep].sum()),
        "n_conditions": int(keep.sum()),
    }


def sh_variance_shown_hidden(
    sh: torch.Tensor, truth: torch.Tensor, gram: torch.Tensor, condition: torch.Tensor, fraction: float = 0.01
) -> dict:
    """Within-condition variance of ``sh [N,C,9]`` split by what each face shows: ``{"shown", "hidden"}``.

    Each estimate is scaled to the truth ``[N,C,9]`` in shading (:func:`~disent.eval.metrics.scale_in_shading`
    with the face's ``gram [N,9,9]``, :func:`~disent.eval.metrics.sh_gram`); its deviation from its condition's
    mean splits over its own face's SH directions (:func:`~disent.eval.metrics.shown_hidden_energy`), as a share
    of the true light's squared norm.  Each part is summed over a condition's images over ``n - 1`` (unbiased) and
    averaged over the conditions with at least 2 images, as :func:`sh_variance` averages; ``shown + hidden`` is
    the within-condition variance of the scaled estimates, summed over coefficients and channels."""
    x = scale_in_shading(sh, truth, gram)
    ids, inv, counts = torch.unique(condition, return_inverse=True, return_counts=True)
    mean = torch.zeros(len(ids), *x.shape[1:], dtype=x.dtype).index_add_(0, inv, x) / counts.double()[:, None, None]
    keep = counts >= 2
    if not keep.any():
        raise ValueError("sh_variance_shown_hidden needs a condition with at least 2 images")
    norm = truth.double().pow(2).sum((1, 2))
    shown, hidden = (
        (torch.zeros(len(ids), dtype=x.dtype).index_add_(0, inv, part / norm)[keep] / (counts[keep] - 1)).mean().item()
        for part in shown_hidden_energy(x - mean[inv], gram, fraction)
    )
    return {"shown": shown, "hidden": hidden}


def ls_estimates(batch: dict) -> dict:
    """Least-squares SH of one batch for the three LS estimators (and the truth)."""
    image, face = batch["image"], face_mask(batch["matte"])
    return {
        "ls_pseudo": fit_sh(image, batch["normal_pseudo"], batch["mask_pseudo"])[0],
        "ls_true": fit_sh(image, batch["normal"], face)[0],
        "ls_oracle": fit_sh(image, batch["normal"], face, albedo=batch["albedo"])[0],
        "true": batch["sh"],
    }


def collect_sh(dataset, models: dict | None = None, limit: int | None = None, batch_size: int = 128):
    """SH estimates of every estimator on ``dataset`` -> ``({name: [N,C,9]}, sh_true [N,C,9], light_id [N],
    gram [N,9,9])`` (``gram``: each face's :func:`~disent.eval.metrics.sh_gram` over its true normals)."""
    models = dict(models or {})
    parts, truth, cond, gram = {}, [], [], []
    for batch in batches(dataset, batch_size, limit):
        est = ls_estimates(batch)
        for name, model in list(models.items()):
            out = predict(model, batch["image"])
            if "sh" not in out:  # the baseline autoencoder has no lighting code
                del models[name]
                continue
            est[name] = out["sh"]
        for k, v in est.items():
            parts.setdefault(k, []).append(v.detach().double())
        truth.append(batch["sh"].double())
        cond.append(batch["light_id"])
        gram.append(sh_gram(batch["normal"], face_mask(batch["matte"])))
    return {k: torch.cat(v) for k, v in parts.items()}, torch.cat(truth), torch.cat(cond), torch.cat(gram)


def sh_variance_protocol(
    dataset, models: dict | None = None, limit: int | None = None, mean_light: torch.Tensor | None = None
) -> dict:
    """The supplement's table: variance (and aligned SH error) of every estimator on ``dataset``, each split by
    what the faces show; ``mean_light [C,9]`` (:func:`disent.eval.trivial.dataset_means`' ``sh``) adds the
    constant estimator ``mean_light``."""
    est, truth, cond, gram = collect_sh(dataset, models, limit)
    if (cond < 0).any():
        raise ValueError("sh_variance_protocol needs fixed light conditions (light_id >= 0): use split='lightbank'")
    if mean_light is not None:
        est["mean_light"] = mean_light.double().expand_as(truth)
    out = {}
    for name, sh in est.items():
        spread, error = sh_variance_shown_hidden(sh, truth, gram, cond), sh_error_split(sh, truth, gram)
        out[name] = {
            **sh_variance(sh, cond),
            "sh_error": sh_error(sh, truth),
            **{f"variance_{k}": v for k, v in spread.items()},
            **{f"sh_error_{k}": v for k, v in error.items()},
        }
    return {"estimators": out, "coefficients": list(SH_NAMES), "paper": {"ls_3dmm": 0.36, "network": 0.16}}


# rows of the table with zero variance by construction, not plotted: the checks and the constant mean light
CHECKS = ("true", "ls_oracle", "mean_light")
FITTED = ("ls_pseudo", "ls_true")  # the least-squares estimators; every other row is a trained network's


def sh_variance_groups(result: dict) -> dict:
    """``{label: [estimator rows]}``: the protocol's estimators with the seeds of one trained setting together
    (``result["runs"]``, from ``--every-run``), each other estimator alone; the checks left out."""
    runs = result.get("runs") or {}
    groups: dict = {}
    for name, v in result["estimators"].items():
        if name in CHECKS:
            continue
        info = runs.get(name)
        groups.setdefault(f"{info['model']} {info['setting']}" if info else name, []).append(v)
    return groups


def plot_sh_variance(result: dict, path) -> None:
    """Grouped bars of per-coefficient variance, one colour per estimator (the supplement's figure); a trained
    setting's bar is the mean over its seeds, its whisker their range.  Left the raw variance, right divided by
    each estimator's mean squared coefficient."""
    from disent.images import pyplot

    plt = pyplot()
    import numpy as np

    groups = sh_variance_groups(result)
    x = np.arange(9)
    width = 0.8 / max(len(groups), 1)
    legend_in = 0.16 * (len(groups) + 1)  # one legend line per bar colour, below the panels
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6 + legend_in))
    for ax, key in zip(axes, ("mean", "relative")):
        for i, (name, rows) in enumerate(groups.items()):
            bars = np.array([np.array(v["per_coeff"]) * (v[key] / v["mean"] if v["mean"] > 0 else 1.0) for v in rows])
            mid = bars.mean(0)
            whisker = [mid - bars.min(0), bars.max(0) - mid] if len(rows) > 1 else None
            seeds = f", {len(rows)} seeds" if len(rows) > 1 else ""
            value = float(np.mean([v[key] for v in rows]))
            ax.bar(
                x + (i - (len(groups) - 1) / 2) * width,
                mid,
                width,
                yerr=whisker,
                error_kw={"lw": 0.6},
                color=plt.cm.tab20(i % 20),  # one colour a bar up to 20 estimators
                label=f"{name}{seeds} ({value:.3g})",
            )
        ax.set_xticks(x, result.get("coefficients", SH_NAMES))
        ax.set_yscale("log")
        ax.set_ylabel("variance" if key == "mean" else "variance / mean squared coefficient")
    axes[0].set_title("SH variance within a light condition (mean over conditions and RGB)", fontsize=9)
    axes[1].set_title("the same, scale-free", fontsize=9)
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower left", ncol=1, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, legend_in / (3.6 + legend_in), 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def row_name(info: dict) -> str:
    """The name of a trained model's row: its model, setting and seed."""
    return f"{info['model']} {info['setting']} seed {info['seed']}"


def keep_rows(new: dict, old: dict, loaded: dict | None = None) -> dict:
    """``new`` with the trained models' rows of ``old`` that it does not measure again: measurements of runs whose
    folders are gone survive a re-run.  An old row's setting is read against today's ``conf/`` from its run's
    folder or record (``loaded``: runs by id; :func:`disent.runs.measured_setting`) and the row renamed by it,
    so that a default changed since neither merges it with today's runs of the same old label nor lets them
    replace it.  Measured again: the same run folder, or the same model, setting (today's) and seed.  A row
    whose run is gone, folder and record, keeps its label, retyped from the ``conf/`` of the git revision that
    ``old`` was written at (its ``revision``, or the row's own where it has one: a row no revision could retype
    keeps its label and says so with ``revision: null``; :func:`disent.runs.retyped_label`), and its folder's name
    joins its name where that is taken."""
    from disent.runs import measured_setting, retyped_label, run_ref

    runs = dict(new.get("runs") or {})
    folders = {run_ref(i["run"]) for i in runs.values()}
    measured = {(i["model"], i["setting"], i["seed"]) for i in runs.values()}
    estimators = dict(new["estimators"])
    for name, info in (old.get("runs") or {}).items():
        if name not in old["estimators"] or run_ref(info["run"]) in folders:
            continue
        then = info.get("revision", old.get("revision"))  # whose conf/ the row's label was read against
        today = measured_setting(info, loaded)
        if today is not None:
            if (info["model"], today, info["seed"]) in measured:
                continue
            measured.add((info["model"], today, info["seed"]))
        elif then:  # its run is gone: its label read against then's conf/
            today = retyped_label(info["setting"], then, info["model"])
        if today is None:  # as labelled then; not against the revision the new JSON names
            info = {**info, "revision": then}
        else:
            info = {k: v for k, v in info.items() if k != "revision"} | {"setting": today}
        key = name if today is None else row_name(info)
        if key in estimators:
            key = f"{key} ({Path(info['run']).name})"
        estimators[key], runs[key] = old["estimators"][name], info
    return {**new, "estimators": estimators, "runs": runs}


def main(argv=None):
    from disent.data import SynthFaces
    from disent.runs import RECORDS, RUN_ROOTS, find_runs, load_models
    from disent.storage import head_revision, tool_folder

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=None, help="output folder (default: outputs/eval/<date>/<time>-<pid>/)")
    p.add_argument("--limit", type=int, default=None, help="first N lightbank images (default: all)")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--roots", nargs="*", default=None, help="folders searched for runs (default: outputs/ multirun/)")
    p.add_argument(
        "--runs", nargs="*", default=None, help="run folders (default: seed-0 run of each model under --roots)"
    )
    p.add_argument(
        "--every-run",
        action="store_true",
        help="score every finished plain run under --roots (the seeds of a setting side by side), not one a model",
    )
    p.add_argument(
        "--keep",
        type=Path,
        default=None,
        metavar="JSON",
        help="a published sh_variance.json (reports/eval/): its rows of trained models not measured again here "
        "are kept (their run folders may be gone), each named by its setting read today from its folder or from "
        "its record beside the JSON (reports/runs.jsonl); a model of the same model, setting and seed is replaced",
    )
    a = p.parse_args(argv)
    torch.manual_seed(0)
    runs = {}
    if a.every_run:
        from disent.models import load_run
        from disent.runs import setting

        for r in find_runs(a.roots or RUN_ROOTS):
            if r.status == "ok" and r.checkpoint and r.plain and r.model != "baseline":  # the baseline has no light
                info = {"model": r.model, "setting": setting(r, drop_model=True), "seed": r.seed, "run": str(r.path)}
                runs[row_name(info)] = (r, info)
        models = {name: load_run(r.path)[0] for name, (r, _) in runs.items()}
    else:
        models = load_models(a.runs if a.runs is not None else find_runs(a.roots or RUN_ROOTS))
    from disent.eval.trivial import dataset_means

    ds = SynthFaces(split="lightbank", resolution=a.resolution, seed=0)
    mean_light = dataset_means(SynthFaces(split="train", resolution=a.resolution, seed=0))["sh"]
    res = sh_variance_protocol(ds, models, a.limit, mean_light)
    res["split"], res["resolution"] = "lightbank", a.resolution
    res["revision"] = head_revision()  # whose conf/ the rows' settings are read against (keep_rows)
    if runs:  # which trained model each network row is, for the report's verdict over seeds
        res["runs"] = {name: info for name, (_, info) in runs.items()}
    if a.keep is not None:
        records = a.keep.resolve().parent.parent / RECORDS  # reports/runs.jsonl: runs whose folders are gone
        loaded = {r.id: r for r in find_runs(a.roots or RUN_ROOTS, records)}
        res = keep_rows(res, json.loads(a.keep.read_text()), loaded)
    out = tool_folder("eval", a.out)
    (out / "sh_variance.json").write_text(json.dumps(res, indent=1))
    plot_sh_variance(res, out / "sh_variance.png")
    for k, v in res["estimators"].items():
        print(
            f"{k:28s} variance {v['mean']:.4g}  relative {v['relative']:.4g}  within {v['within_share']:.3g}  "
            f"sh_error {v['sh_error']:.4g}  shown: variance {v.get('variance_shown', math.nan):.4g} "
            f"error {v.get('sh_error_shown', math.nan):.4g}  "
            f"({v['n_conditions']} conditions, {v['n_images']} images)"
        )


if __name__ == "__main__":
    main()

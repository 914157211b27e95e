"""Methods on one plane: per-image time against accuracy for every estimator of the suite, in one run.

    python -m disent.eval.methods [--n 64] [--runs explicit implicit baseline] [--posterior 8] [--out FOLDER]

On the first ``n`` SynthFaces test images, each estimator is timed on this machine at one thread (seconds
per image; a network at batch ``n``) and scored against the true layers on the pixels the models are
scored on (:func:`disent.regions.decomposed_region`):

- **mean map / mean light**: the training split's dataset means (constants: no time per image);
- **coarse fit**: SynthFaces' simulated morphable-model fit, the pseudo ground truth that supervises the
  networks (``scenes.render_pseudo``: its normals, and L-hat on them).  It starts from the scene's
  parameters, not from the image, so its time is the rendering's only: a lower bound for a real fit;
- **landmarks + fit**: the real pipeline of :mod:`disent.data.photos.pseudo_gt` on the render: dlib's 68
  landmarks, the face model fitted to them, its normals and L-hat; scored on the images where dlib finds the
  face (the detection rate is recorded);
- **L-hat**: least squares on the coarse fit's normals and mask with a constant albedo (``render.fit_sh``);
- **posterior mean**: the emcee posterior of the light on the same pixels (``--posterior`` images);
- **networks**: the explicit, implicit and baseline models (run folders or shipped names).

Writes ``methods.json`` and ``methods.png`` (normal error, SH error and face PSNR against time, the Pareto
front of each panel drawn) into a tool folder, published to ``reports/eval/``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import torch

from disent.eval.scoring import metrics_from_outputs, predict
from disent.images import to_uint8
from disent.storage import cpu_name

PANELS = (
    ("normal_mean", "normal error (deg)", False),
    ("sh_error", "SH error", False),
    ("recon_face_psnr", "face PSNR (dB)", True),
)  # (metric, label, higher is better)


def subset(batch: dict, keep) -> dict:
    return {k: v[keep] for k, v in batch.items() if torch.is_tensor(v)}


def timed(fn, *args):
    """``(fn(*args), seconds)``."""
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def coarse_fit(test, n: int) -> tuple[dict, float]:
    """SynthFaces' simulated coarse fit of the first ``n`` test images: (its maps, seconds per image)."""
    from disent.data.synth.scenes import render_pseudo

    image = test.get_batch(range(n))["image"]
    params = test.params(range(n))
    maps, seconds = timed(render_pseudo, image, params, image.shape[-1])
    return maps, seconds / n


def landmark_fit(images: torch.Tensor) -> tuple[list, dict, float]:
    """dlib + face-model fit on each render: (indices where a face was found, their maps, seconds per image)."""
    from disent.data.photos import pseudo_gt as pg

    R = images.shape[-1]
    settings = pg.PseudoGTSettings(resolution=R)
    detector, model = pg.landmark_detector(settings), pg.face_model_fitter(settings)
    found, maps, t0 = [], [], time.perf_counter()
    for i, img in enumerate(images):
        rgb = to_uint8(img, "srgb")  # as a photo is stored
        try:
            landmarks, _ = detector(rgb)
            fit = pg.fit_landmarks(landmarks, R, settings, model)
            maps.append(pg.maps_from_fit(fit, img.numpy(), model))
        except pg.Skip:
            continue
        found.append(i)
    seconds = (time.perf_counter() - t0) / len(images)
    stacked = {k: torch.as_tensor(np.stack([m[k] for m in maps])).float() for k in maps[0]} if maps else {}
    return found, stacked, seconds


def posterior_means(gt: dict, k: int) -> tuple[torch.Tensor, float, list]:
    """Posterior mean light of the first ``k`` images on the coarse fit's normals and mask (constant albedo):
    (means, seconds per image, the sampler's steps per image)."""
    from disent.lighting.posterior import prepare, sample_posterior

    means, steps, t0 = [], [], time.perf_counter()
    for i in range(k):
        data = prepare(gt["image"][i], gt["normal_pseudo"][i], gt["mask_pseudo"][i])
        post = sample_posterior(data, seed=i)
        means.append(torch.as_tensor(post.mean).float())
        steps.append(post.diagnostics["n_steps"])
    return torch.stack(means), (time.perf_counter() - t0) / k, steps


def pareto(points: list[tuple[float, float]], higher_better: bool) -> list[int]:
    """Indices of the points no other point beats in both time (lower) and the metric."""
    sign = -1 if higher_better else 1
    return [
        i
        for i, (t, v) in enumerate(points)
        if not any((t2 <= t and sign * v2 <= sign * v) and (t2, v2) != (t, v) for t2, v2 in points)
    ]


def measure(runs, n: int = 64, n_posterior: int = 8, seed: int = 0) -> dict:
    """Every estimator's seconds per image and metrics on the first ``n`` test images."""
    from disent.data import SynthFaces
    from disent.eval.trivial import dataset_means
    from disent.models import load_run
    from disent.render import fit_sh

    torch.set_num_threads(1)
    test = SynthFaces("test", 64, seed)
    gt = test.get_batch(range(n))
    rows = {}
    load_before = os.getloadavg()[0]  # other work on the machine inflates every time alike; the report says how much

    def score(name, out, seconds, images=n, keep=None, **extra):
        g = gt if keep is None else subset(gt, keep)
        m = metrics_from_outputs(out, g)
        rows[name] = {
            "seconds_per_image": seconds,
            "images": images,
            **extra,
            **{k: m[k] for k, _, _ in PANELS if k in m},
        }

    means = dataset_means(SynthFaces("train", 64, seed))  # as eval.json's trivial baselines
    score(
        "mean map / mean light",
        {"normal": means["normal"].expand_as(gt["normal"]), "sh": means["sh"].expand_as(gt["sh"])},
        0.0,
        constant=True,
    )
    maps, sec = coarse_fit(test, n)
    score("coarse fit (simulated pseudo-GT)", {"normal": maps["normal_pseudo"], "sh": maps["sh_pseudo"]}, sec)
    lhat, sec = timed(fit_sh, gt["image"], gt["normal_pseudo"], gt["mask_pseudo"])
    score("L-hat on the coarse fit", {"sh": lhat[0]}, sec / n)
    try:
        found, fitted, sec = landmark_fit(gt["image"])
    except ImportError as e:  # dlib is the optional photos extra
        print(f"landmarks + fit left out: {e} (pip install -e '.[photos]')")
        found = []
    if found:
        score(
            "landmarks + fit (dlib)",
            {"normal": fitted["normal_pseudo"], "sh": fitted["sh_pseudo"]},
            sec,
            images=len(found),
            keep=torch.tensor(found),
            detection_rate=len(found) / n,
        )
    k = min(n_posterior, n)
    if k > 0:
        post, sec, steps = posterior_means(gt, k)
        score("posterior mean (emcee)", {"sh": post}, sec, images=k, keep=torch.arange(k), sampler_steps=steps)
    for run in runs:
        model, cfg = load_run(run)
        predict(model, gt["image"][:2])  # warm-up
        out, sec = timed(predict, model, gt["image"])
        name = f"{cfg.model.name} network" + ("" if str(run) == cfg.model.name else f" ({run})")
        score(name, {k: v for k, v in out.items() if k in ("normal", "sh", "recon")}, sec / n)
    load = {"before": load_before, "after": os.getloadavg()[0], "cpus": os.cpu_count()}
    return {"n": n, "threads": 1, "machine": cpu_name(), "load": load, "rows": rows}


def plot(res: dict, path) -> None:
    from disent.images import pyplot

    plt = pyplot()

    rows = res["rows"]
    colour = {n: plt.cm.tab10(k % 10) for k, n in enumerate(rows)}  # one colour per estimator on every panel
    floor = min([r["seconds_per_image"] for r in rows.values() if r["seconds_per_image"] > 0] or [1e-3]) / 10
    fig, axes = plt.subplots(1, len(PANELS), figsize=(5 * len(PANELS), 4.2))
    for ax, (key, label, higher) in zip(axes, PANELS):
        named = [(n, max(r["seconds_per_image"], floor), r[key]) for n, r in rows.items() if key in r]
        front = sorted((named[i] for i in pareto([(t, v) for _, t, v in named], higher)), key=lambda q: q[1])
        ax.step([q[1] for q in front], [q[2] for q in front], where="post", color="0.7", lw=1, zorder=0)
        for n, t, v in named:
            ax.scatter(t, v, s=40, color=colour[n], edgecolor="k" if (n, t, v) in front else "none")
        ax.set_xscale("log")
        ax.set_xlabel("seconds per image (one thread; constants at the left edge)")
        ax.set_ylabel(label + (" (higher is better)" if higher else " (lower is better)"))
    handles = [plt.Line2D([], [], marker="o", ls="", color=colour[n], label=n) for n in rows]
    handles.append(plt.Line2D([], [], color="0.7", label="Pareto front (points outlined)"))
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"Estimators on {res['n']} SynthFaces test images, one machine, one run", fontsize=9)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> None:
    from disent.runtime import single_core
    from disent.storage import tool_folder

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=64, help="test images")
    p.add_argument(
        "--runs",
        nargs="*",
        default=["explicit", "implicit", "baseline"],
        help="run folders or shipped names of the networks",
    )
    p.add_argument("--posterior", type=int, default=8, help="images for the emcee posterior (about 0.5 s each)")
    p.add_argument("--out", default=None, help="output folder (default: outputs/eval/<date>/<time>-<pid>/)")
    a = p.parse_args(argv)
    out = tool_folder("eval", a.out)
    with single_core():  # one torch thread and one OpenBLAS thread for every estimator
        res = measure(a.runs, a.n, a.posterior)
    (out / "methods.json").write_text(json.dumps(res, indent=1))
    plot(res, out / "methods.png")
    for name, r in res["rows"].items():
        print(
            f"{name:34s} {r['seconds_per_image'] * 1e3:9.2f} ms/image  "
            + "  ".join(f"{k} {r[k]:.4g}" for k, _, _ in PANELS if k in r)
        )
    print(f"wrote {out}; publish it with: python -m disent.report --publish {out}")


if __name__ == "__main__":
    main()

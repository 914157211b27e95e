"""Experiments on SynthFaces for the report: posterior width, calibration, order choice, where L-hat's error comes
from, speed (``python -m disent.lighting task=report`` runs them all: :func:`run_all`).  Each concern has its
module: :mod:`~disent.lighting.geometry`, :mod:`~disent.lighting.calibration`, :mod:`~disent.lighting.sources`,
:mod:`~disent.lighting.order_study`; this one draws one image's figures, times the fits and runs them all.

Every experiment fits the known-albedo model ``image = albedo * S(n, L) + noise`` on the true
normals and matte, so that the sampled L is the scene's SH light and can be checked against
it; i.i.d. Gaussian noise of std ``noise`` is added to the image with a fixed seed.  Outputs
go to the run folder (JSON and PNG); ``python -m disent.report --publish FOLDER`` copies them to
``reports/lighting/``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from disent.lighting.calibration import calibration, plot_calibration, plot_widths, widths
from disent.lighting.geometry import GEOMETRY, item_data, save_json, scene_geometry
from disent.lighting.order import select_order
from disent.lighting.order_study import (
    chosen_noise_model,
    order_data,
    order_failure_regions,
    order_study,
    plot_order_accuracy,
    plot_order_failures,
    plot_registration,
    read_study,
    row_key,
)
from disent.lighting.posterior import N_COEFFS, sample_posterior
from disent.lighting.sources import lhat_sources
from disent.lighting.texture import trained_network
from disent.render import fit_sh


# ----------------------------------------------------------------------------- one image
def figures_for(post, item: dict, data, stem: Path, normal_key: str = "normal") -> list[Path]:
    """Corner plot (channel-summed light and log sigma) and the shading uncertainty map."""
    import corner

    from disent.images import pyplot

    plt = pyplot()

    K = N_COEFFS[post.order]
    names = [f"L{k + 1}" for k in range(K)]
    samples = np.column_stack([post.sh[:, :, :K].sum(1), post.log_sigma])
    fig = corner.corner(
        samples,
        labels=[f"$\\Sigma_c {n}$" for n in names] + [r"$\log\sigma$"],
        truths=None if "sh" not in item else list(item["sh"].double().sum(0)[:K].numpy()) + [None],
        quantiles=[0.16, 0.5, 0.84],
        show_titles=False,
    )
    corner_path = stem.with_name(stem.name + "_corner.png")
    fig.savefig(corner_path, dpi=50)
    plt.close(fig)
    mean, sd = post.shading_map(item[normal_key])
    inside = np.zeros(data.shape[0] * data.shape[1], bool)
    inside[data.index] = True
    inside = inside.reshape(data.shape)
    fig, axes = plt.subplots(1, 3, figsize=(9, 3.2))
    axes[0].imshow(item["image"].permute(1, 2, 0).clamp(0, 1).numpy())
    axes[0].set_title("image")
    axes[1].imshow(np.where(inside, mean.mean(0), np.nan), cmap="gray")
    axes[1].set_title("posterior mean shading")
    im = axes[2].imshow(np.where(inside, sd.mean(0), np.nan), cmap="magma")
    axes[2].set_title("posterior sd of shading")
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    map_path = stem.with_name(stem.name + "_shading_sd.png")
    fig.savefig(map_path, dpi=100)
    plt.close(fig)
    return [corner_path, map_path]


# ----------------------------------------------------------------------------- speed
def speed(ds=None, batch: int = 256, rounds: int = 3) -> dict:
    """Least-squares L-hat per image (batched ``fit_sh``) and the posterior (27 params, 64x64)."""
    from disent.bench import median_time
    from disent.data import SynthFaces

    ds = ds or SynthFaces("test", 64)
    item = ds[0]
    image = item["image"][None].expand(batch, -1, -1, -1).contiguous()
    normal = item["normal"][None].expand(batch, -1, -1, -1).contiguous()
    matte = item["matte"][None].expand(batch, -1, -1, -1).contiguous()
    ls = median_time(lambda: fit_sh(image, normal, matte), rounds)
    cpu = []  # CPU time too: on a shared machine wall time counts other people's work
    for _ in range(rounds):
        c0 = time.process_time()
        fit_sh(image, normal, matte)
        cpu.append(time.process_time() - c0)
    data = item_data(item, 0.02, 0)
    out = {
        "threads": torch.get_num_threads(),
        "ls_batch": batch,
        "ls_ms_per_image": 1000 * ls / batch,
        "ls_cpu_ms_per_image": 1000 * float(np.median(cpu)) / batch,
        "n_pixels": data.n_pixels,
    }
    for likelihood in ("gaussian", "student_t"):
        diag = [sample_posterior(data, likelihood=likelihood, seed=s).diagnostics for s in range(rounds)]
        out[f"posterior_{likelihood}_s"] = float(np.median([d["seconds"] for d in diag]))
        out[f"posterior_{likelihood}_cpu_s"] = float(np.median([d["cpu_seconds"] for d in diag]))
        out[f"posterior_{likelihood}_steps"] = float(np.median([d["n_steps"] for d in diag]))
    return out | {"order_choice_s": order_choice_speed(ds, rounds), "order_choice_items": rounds}


# the geometries whose order choice speed() times: the pseudo rows a photo can use, and the networks' best
SPEED_GEOMETRIES = (
    "normal_pseudo_registered",
    "normal_pseudo_placed",
    "normal_pseudo_placed_registered",
    "network_explicit_placed",
)


def order_choice_speed(ds, rounds: int = 3, geometries=SPEED_GEOMETRIES) -> dict:
    """``{geometry: seconds}``: the median over test items ``0..rounds-1`` of ``ds`` of one order choice without
    the true albedo (the geometry's maps, the texture model, the five candidates under the residual process), one
    core, the network's weights loaded beforehand."""
    for name in {GEOMETRY[g].network for g in geometries} - {""}:
        trained_network(name)
    times = {}
    for g in geometries:
        seconds = []
        for i in range(rounds):
            start = time.perf_counter()
            item = scene_geometry(ds, i, ds[i], g, 0.02, i)
            data, texture = order_data(item, 0.02, i, "texture", g)
            select_order(data, texture=texture, residual=(3.0, 1.0))
            seconds.append(time.perf_counter() - start)
        times[g] = float(np.median(seconds))
    return times


# ----------------------------------------------------------------------------- all of it
def order_report(
    out: Path,
    split: str = "test",
    resolution: int = 64,
    seed: int = 0,
    quick: bool = False,
    only=None,
    keep: Path | None = None,
    splits=None,
    n_per_order: int = 20,
    geometry: str | None = None,
) -> dict:
    """The report's order study on val and ``split`` (or on ``splits``) with ``n_per_order`` scenes per true order,
    its accuracy figure (:func:`plot_order_accuracy`; ``python -m disent.lighting task=order``; also part of
    :func:`run_all`), the registration figure (:func:`plot_registration`) and, for the row of the texture model on
    ``geometry`` with its noise model best on val, the scenes it gets wrong (:func:`plot_order_failures`) and where
    their misfit lies (:func:`order_failure_regions`, on val and ``split``); ``only``, ``keep``: compute only some
    rows and copy the rest (:func:`order_study`)."""
    from disent.data import SynthFaces

    n = 2 if quick else 1
    study = order_study(
        out,
        tuple(splits or ("val", split)),
        n_per_order=n_per_order // n,
        resolution=resolution,
        seed=seed,
        n_train_scenes=18 // n,
        only=only,
        keep=keep,
    )
    plot_order_accuracy(study, out / "order_accuracy.png")
    val = SynthFaces("val", resolution, seed)
    save_json("registration", plot_registration(val, out / "registration.png"), out)
    if geometry:
        model = chosen_noise_model("texture", geometry, out)[0]
        row = row_key(("texture", geometry) + ((model,) if model != "iid" else ()))
        written = read_study(out)  # the study as written, with its residual fits
        if failures := plot_order_failures(val, written, row, out / "order_failures.png"):
            save_json("order_failures", failures, out)
        regions = {
            s: order_failure_regions(val if s == "val" else SynthFaces(s, resolution, seed), written, row, s)
            for s in dict.fromkeys(("val", split))
        }
        if any(regions.values()):
            save_json("order_failure_regions", regions, out)
    return study


def run_all(
    out: Path,
    split: str = "test",
    resolution: int = 64,
    seed: int = 0,
    quick: bool = False,
    geometry: str | None = None,
) -> dict:
    """Every experiment of the report's lighting section; writes ``out/*`` (JSON and PNG), which
    ``python -m disent.report --publish OUT`` copies to ``reports/lighting/``."""
    from disent.data import SynthFaces
    from disent.runtime import single_core

    with single_core():
        return _run_all(SynthFaces(split, resolution, seed), Path(out), resolution, seed, quick, geometry)


def _run_all(ds, out: Path, resolution: int, seed: int, quick: bool, geometry: str | None = None) -> dict:
    from disent.data import SynthFaces

    split = ds.split
    out.mkdir(parents=True, exist_ok=True)
    summary, t0 = {}, time.perf_counter()
    n = 2 if quick else 1

    item = ds[0]
    data = item_data(item, 0.02, 0)
    post = sample_posterior(data)
    figures_for(post, item, data, out / "example")
    summary["example"] = post.summary() | {"true_sh": item["sh"].tolist()}
    save_json("example", summary["example"], out)

    summary["widths"] = widths(ds, n_faces=2 // n)
    save_json("widths", summary["widths"], out)
    plot_widths(summary["widths"], out / "widths.png")

    summary["calibration"] = calibration(ds, n_images=10 // n)
    save_json("calibration", summary["calibration"], out)
    plot_calibration(summary["calibration"], out / "calibration.png")

    summary["calibration_pseudo"] = calibration(
        ds, n_images=8 // n, normals="normal_pseudo", conditions=("lambertian", "specular", "cast_shadow")
    )
    save_json("calibration_pseudo", summary["calibration_pseudo"], out)
    plot_calibration(summary["calibration_pseudo"], out / "calibration_pseudo.png")

    summary["order"] = order_report(out, split, resolution, seed, quick, geometry=geometry)

    summary["lhat_sources"] = lhat_sources(ds, SynthFaces("train", resolution, seed))
    save_json("lhat_sources", summary["lhat_sources"], out)

    summary["speed"] = speed(ds)
    save_json("speed", summary["speed"], out)
    summary["seconds"] = time.perf_counter() - t0
    save_json("summary", {k: v for k, v in summary.items() if k != "example"}, out)
    return summary

"""The posterior's widths and calibration: how wide L-hat's emcee posterior is on a face, and whether its
credible intervals hold the true light as often as they claim."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from disent.lighting.geometry import band_width, item_data
from disent.lighting.posterior import sample_posterior


# ----------------------------------------------------------------------------- widths
def central_mask(matte: torch.Tensor, fraction: float) -> torch.Tensor:
    """The ``fraction`` of matte pixels nearest the matte's centroid."""
    m = matte[0] > 0.5
    ys, xs = torch.nonzero(m, as_tuple=True)
    d = (ys - ys.float().mean()) ** 2 + (xs - xs.float().mean()) ** 2
    keep = d <= torch.quantile(d.float(), fraction)
    out = torch.zeros_like(m)
    out[ys[keep], xs[keep]] = True
    return out[None].float()


def widths(ds, n_faces: int = 3, noise: float = 0.02) -> dict:
    """68 % interval width per SH band against yaw, mask fraction and noise (Gaussian likelihood)."""
    res = {"yaw": {}, "mask_fraction": {}, "noise": {}}
    for face in range(n_faces):
        for yaw in (0, 20, 40, 60, 80):
            item = ds.sample(face, pose=(float(yaw), 0.0, 0.0))
            res["yaw"].setdefault(yaw, []).append(band_width(sample_posterior(item_data(item, noise, face))))
        item = ds.sample(face)
        for frac in (1.0, 0.5, 0.25, 0.1):
            post = sample_posterior(item_data(item, noise, face, mask=central_mask(item["matte"], frac)))
            res["mask_fraction"].setdefault(frac, []).append(band_width(post))
        for sigma in (0.005, 0.01, 0.02, 0.05):
            res["noise"].setdefault(sigma, []).append(band_width(sample_posterior(item_data(item, sigma, face))))
    return {
        axis: {str(k): {b: float(np.mean([r[b] for r in v])) for b in v[0]} for k, v in d.items()}
        for axis, d in res.items()
    }


def plot_widths(w: dict, path: Path) -> None:
    from disent.images import pyplot

    plt = pyplot()

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    for ax, (axis, label) in zip(
        axes, [("yaw", "yaw (deg)"), ("mask_fraction", "mask fraction"), ("noise", "noise std")]
    ):
        xs = [float(k) for k in w[axis]]
        for b in ("band0", "band1", "band2"):
            ax.plot(xs, [w[axis][k][b] for k in w[axis]], "o-", label=f"SH band {b[-1]}")
        ax.set_xlabel(label)
        ax.set_yscale("log")
        if axis == "noise":
            ax.set_xscale("log")
            ax.set_xticks(xs, [f"{x:g}" for x in xs])
            ax.minorticks_off()
    axes[0].set_ylabel("mean 68% interval width")
    axes[0].legend()
    fig.suptitle("Posterior width of the SH light (known albedo, Gaussian likelihood)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- calibration
def calibration(
    ds,
    n_images: int = 12,
    noise: float = 0.02,
    severity: float = 0.5,
    conditions=("lambertian", "specular", "cast_shadow", "specular+cast_shadow"),
    normals: str = "normal",
) -> dict:
    """Share of true SH coefficients inside the 68 % / 95 % intervals, per likelihood and effect.

    ``z_rms`` is the RMS of (posterior mean - truth) / posterior sd: 1 when calibrated, larger
    when the intervals are overconfident.
    """
    out = {}
    for condition in conditions:
        effects = None if condition == "lambertian" else {e: severity for e in condition.split("+")}
        for likelihood in ("gaussian", "student_t"):
            inside = {0.68: [], 0.95: []}
            z, conv = [], []
            for i in range(n_images):
                item = ds.sample(i, effects=effects) if effects else ds[i]
                post = sample_posterior(item_data(item, noise, i, normals=normals), likelihood=likelihood, seed=i)
                truth = item["sh"].double().numpy()
                for level in inside:
                    lo, hi = post.interval(level)
                    inside[level].append(((truth >= lo) & (truth <= hi)).ravel())
                z.append(((post.mean - truth) / post.std).ravel())
                conv.append(post.diagnostics["converged"])
            z = np.concatenate(z)
            out[f"{condition}/{likelihood}"] = {
                "inside68": float(np.concatenate(inside[0.68]).mean()),
                "inside95": float(np.concatenate(inside[0.95]).mean()),
                "z_rms": float(np.sqrt(np.mean(z**2))),
                "n_coefficients": int(z.size),
                "converged": float(np.mean(conv)),
            }
    out["settings"] = {"n_images": n_images, "noise": noise, "severity": severity, "normals": normals}
    return out


def plot_calibration(c: dict, path: Path) -> None:
    from disent.images import pyplot

    plt = pyplot()

    keys = [k for k in c if k != "settings"]
    fig, ax = plt.subplots(figsize=(10, 3.6))
    x = np.arange(len(keys))
    ax.bar(x - 0.2, [c[k]["inside68"] for k in keys], 0.4, label="inside 68% interval")
    ax.bar(x + 0.2, [c[k]["inside95"] for k in keys], 0.4, label="inside 95% interval")
    ax.axhline(0.68, color="C0", ls="--", lw=1)
    ax.axhline(0.95, color="C1", ls="--", lw=1)
    ax.set_xticks(x, [k.replace("/", "\n").replace("+", "+\n") for k in keys], fontsize=8)
    ax.set_ylim(0, 1)
    ax.set_ylabel("share of true coefficients")
    ax.set_title(
        f"Calibration of the SH-light intervals ({c['settings'].get('normals', 'normal')}, "
        f"{c['settings']['n_images']} images, noise "
        f"{c['settings']['noise']}, effect severity {c['settings']['severity']})"
    )
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)

"""The pseudo-GT pipeline on the photos that ship with the dependencies, for the report.

    python -m disent.data.photos [--out FOLDER] [--workers 2]

Photos: scikit-image's ``astronaut``, matplotlib's ``grace_hopper`` sample and the 100 faces
of scikit-image's ``lfw_subset`` (25x25 gray crops, bundled with scikit-image; its other 100
images are non-faces and measure false detections).  Writes ``pseudo_gt.json`` (landmark
success rate, fit residual in pixels) and ``pseudo_gt.png`` (pseudo normals and mask over each
photo).  Trained models on the same crops: :mod:`disent.eval.photos`.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from disent.data.photos import pseudo_gt as pg
from disent.images import to_uint8
from disent.storage import tool_folder

N_LFW_FACES = 100  # lfw_subset: images 0-99 are faces, 100-199 are not


def bundled_photos(folder: Path) -> dict[str, list[Path]]:
    """Write the bundled photos as files under ``folder``: {source: [paths]}."""
    import matplotlib.cbook as cbook
    from PIL import Image
    from skimage import data

    folder.mkdir(parents=True, exist_ok=True)
    out = {"astronaut": [folder / "astronaut.png"], "grace_hopper": [folder / "grace_hopper.jpg"]}
    if not out["astronaut"][0].exists():
        Image.fromarray(data.astronaut()).save(out["astronaut"][0])
    if not out["grace_hopper"][0].exists():
        out["grace_hopper"][0].write_bytes(
            Path(cbook.get_sample_data("grace_hopper.jpg", asfileobj=False)).read_bytes()
        )
    lfw = data.lfw_subset()  # [200, 25, 25] float in [0, 1]
    for name, sl in (("lfw_faces", slice(0, N_LFW_FACES)), ("lfw_nonfaces", slice(N_LFW_FACES, None))):
        out[name] = []
        for i, im in enumerate(lfw[sl], sl.start):
            p = folder / f"lfw_{i:03d}.png"
            if not p.exists():
                Image.fromarray(np.rint(im * 255).astype(np.uint8)).save(p)
            out[name].append(p)
    return out


def statistics(records_by_source: dict) -> dict:
    """Per source: images, landmark success rate, fit residual (crop and photo pixels)."""
    out = {}
    for src, recs in records_by_source.items():
        used = [r for r in recs if r.used]
        res = np.array([r.residual_px for r in used])
        res_photo = np.array([r.residual_photo_px for r in used])
        out[src] = {
            "images": len(recs),
            "used": len(used),
            "success_rate": len(used) / max(1, len(recs)),
            "skip_reasons": pg.summarize(recs)["skip_reasons"],
            "residual_px_median": float(np.median(res)) if len(res) else None,
            "residual_px_mean": float(res.mean()) if len(res) else None,
            "residual_photo_px_median": float(np.median(res_photo)) if len(res) else None,
        }
    return out


GROUPS = {
    "jaw": slice(0, 17),
    "brows": slice(17, 27),
    "nose": slice(27, 36),
    "eyes": slice(36, 48),
    "mouth": slice(48, 68),
}


def fitted_pose(records: list) -> dict:
    """Median and spread of the fitted yaw and pitch (degrees) over used records."""
    if not records:
        return {}
    pose = np.degrees(np.stack([pg.load_cached(r)["params"][:2] for r in records]))
    return {
        "yaw_median": float(np.median(pose[:, 0])),
        "pitch_median": float(np.median(pose[:, 1])),
        "yaw_iqr": float(np.subtract(*np.percentile(pose[:, 0], [75, 25]))),
        "pitch_iqr": float(np.subtract(*np.percentile(pose[:, 1], [75, 25]))),
    }


def synth_landmark_check(settings: pg.PseudoGTSettings, n: int = 64) -> dict:
    """dlib on SynthFaces' own test renders, whose exact landmarks are known: detection rate,
    distance of dlib's landmarks to the face model's landmark vertices (per group, crop pixels),
    and the pose error of fits from dlib's landmarks against fits from the exact ones.
    This separates what dlib and the model mean by each landmark from the photo domain."""
    from disent.data import SynthFaces

    R = settings.resolution
    ds = SynthFaces("test", R, size=n)
    fitter = pg.face_model_fitter(settings)
    exact = fitter.synth_landmarks(ds.params(range(n)), R)
    images = [to_uint8(im, "srgb") for im in ds.get_batch(range(n))["image"]]  # encoded as a photo is stored
    det = pg.landmark_detector(settings)
    dist, dpose = [], []
    for img, lm in zip(images, exact):
        try:
            found, _ = det(img)
        except pg.Skip:
            continue
        dist.append(np.linalg.norm(found - lm, axis=1))
        a = pg.pseudo_gt_from_landmarks(img, found, settings)["params"]
        b = pg.pseudo_gt_from_landmarks(img, lm, settings)["params"]
        dpose.append(np.degrees(a[:2] - b[:2]))
    out = {"images": n, "detected": len(dist), "detection_rate": len(dist) / n}
    if dist:
        d, dp = np.array(dist), np.array(dpose)
        out["landmark_distance_px"] = {g: float(d[:, sl].mean()) for g, sl in GROUPS.items()}
        out["landmark_distance_px"]["all"] = float(d.mean())
        out["pose_error_deg"] = {
            "yaw_mean": float(dp[:, 0].mean()),
            "pitch_mean": float(dp[:, 1].mean()),
            "yaw_std": float(dp[:, 0].std()),
            "pitch_std": float(dp[:, 1].std()),
        }
    return out


def overlay_figure(records: list, path: Path, resolution: int, cols: int = 8):
    """Per photo: the crop with dlib (green) and fitted (red) landmarks, the pseudo normals
    blended over the photo, the mask outline, and the L-hat shading of the pseudo normals."""
    from disent.images import pyplot

    plt = pyplot()
    import torch

    from disent.render import sh_shading

    n = len(records)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows * 3, cols, figsize=(1.6 * cols, 1.6 * 3 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for k, rec in enumerate(records):
        z = pg.load_cached(rec)
        img = z["image"].astype(np.float32) / 255
        mask = z["mask_pseudo"][0].astype(np.float32)
        normal = z["normal_pseudo"].astype(np.float32).transpose(1, 2, 0)
        shade = (
            sh_shading(
                torch.from_numpy(z["normal_pseudo"].astype(np.float32))[None], torch.from_numpy(z["sh_pseudo"])[None]
            )[0]
            .numpy()
            .transpose(1, 2, 0)
        )
        r, c = 3 * (k // cols), k % cols
        a = axes[r, c]
        a.imshow(img)
        a.plot(*z["landmarks"].T, ".", color="lime", ms=1.5)
        a.plot(*z["landmarks_fit"].T, ".", color="red", ms=1.5)
        a.set_title(f"{Path(rec.path).stem}\n{rec.residual_px:.2f} px", fontsize=6)
        blend = img * (1 - 0.7 * mask[..., None]) + 0.7 * mask[..., None] * (normal * 0.5 + 0.5)
        axes[r + 1, c].imshow(np.clip(blend, 0, 1))
        axes[r + 1, c].contour(mask, [0.5], colors="yellow", linewidths=0.6)
        axes[r + 2, c].imshow(np.clip(shade * mask[..., None] + img * (1 - mask[..., None]), 0, 1))
    fig.suptitle(
        "pseudo ground truth on bundled photos: landmarks (dlib green, fit red) / "
        f"normal_pseudo + mask_pseudo / L-hat shading ({resolution}px crops)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


def markdown(stats: dict) -> str:
    """The report table of :func:`statistics` plus the SynthFaces landmark check."""
    f = lambda x, d=2: "-" if x is None else f"{x:.{d}f}"  # noqa: E731
    lines = [
        "| photos | images | landmarks found | fit residual, crop px (median) | photo px (median) | "
        "fitted yaw / pitch, deg (median) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for src in ("astronaut", "grace_hopper", "lfw_faces", "lfw_nonfaces"):
        s, pose = stats[src], stats[src].get("fitted_pose_deg") or {}
        lines.append(
            f"| {src} | {s['images']} | {s['used']} ({100 * s['success_rate']:.0f}%) | "
            f"{f(s['residual_px_median'])} | {f(s['residual_photo_px_median'])} | "
            f"{f(pose.get('yaw_median'), 1)} / {f(pose.get('pitch_median'), 1)} |"
        )
    c = stats["synthfaces_dlib_check"]
    lines += [
        "",
        f"dlib on {c['images']} SynthFaces test renders ({stats['settings']['resolution']} px): "
        f"{c['detected']} found ({100 * c['detection_rate']:.0f}%).",
    ]
    if c["detected"]:
        d, e = c["landmark_distance_px"], c["pose_error_deg"]
        lines.append(
            "Distance of dlib's landmarks to the face model's landmark vertices (crop px): "
            + ", ".join(f"{k} {v:.1f}" for k, v in d.items())
            + f". Fits from dlib's landmarks vs from the exact ones: yaw {e['yaw_mean']:+.1f} ± "
            f"{e['yaw_std']:.1f}, pitch {e['pitch_mean']:+.1f} ± {e['pitch_std']:.1f} deg."
        )
    return "\n".join(lines) + "\n"


def run_study(out, resolution: int = 64, workers: int = 2, cache_dir=None) -> list:
    """Pseudo ground truth of the bundled photos: ``pseudo_gt.json`` and ``pseudo_gt.png`` in
    ``out`` (a tool folder: :func:`disent.storage.tool_folder`); returns the records of the photos it could use
    (for :mod:`disent.eval.photos`)."""
    settings = pg.PseudoGTSettings(resolution=resolution)
    cache = Path(cache_dir) if cache_dir else pg.default_cache_dir()
    photos = bundled_photos(cache / "bundled_photos")
    paths = [p for ps in photos.values() for p in ps]
    records, summary = pg.prepare(paths, settings, cache, workers=workers)
    by_src, i = {}, 0
    for src, ps in photos.items():
        by_src[src] = records[i : i + len(ps)]
        i += len(ps)
    stats = statistics(by_src)
    for src in photos:
        stats[src]["fitted_pose_deg"] = fitted_pose([r for r in by_src[src] if r.used])
    stats["synthfaces_dlib_check"] = synth_landmark_check(settings)
    stats["settings"] = {k: getattr(settings, k) for k in settings.__dataclass_fields__}
    (out / "pseudo_gt.json").write_text(json.dumps(stats, indent=2) + "\n")
    shown = [r for src in ("astronaut", "grace_hopper", "lfw_faces") for r in by_src[src] if r.used][:24]
    overlay_figure(shown, out / "pseudo_gt.png", resolution)
    for src in photos:
        s = stats[src]
        print(
            f"{src:14s} {s['used']:3d}/{s['images']:3d} used ({100 * s['success_rate']:.0f}%)  "
            f"fit residual median {s['residual_px_median'] or float('nan'):.2f} px (crop), "
            f"{s['residual_photo_px_median'] or float('nan'):.2f} px (photo)  skipped: {s['skip_reasons']}"
        )
    print("fitted pose on LFW (deg):", json.dumps(stats["lfw_faces"]["fitted_pose_deg"]))
    print("dlib on SynthFaces renders:", json.dumps(stats["synthfaces_dlib_check"]))
    print(markdown(stats))
    print(f"wrote {out / 'pseudo_gt.json'} and {out / 'pseudo_gt.png'}")
    return [r for r in records if r.used]


def arguments(description: str) -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=None, help="output folder (default: outputs/photos/<date>/<time>-<pid>/)")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cache-dir", default=None)
    return ap


def main(argv=None):
    args = arguments(__doc__).parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    run_study(tool_folder("photos", args.out), args.resolution, args.workers, args.cache_dir)


if __name__ == "__main__":
    main()

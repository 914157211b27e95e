"""Trained models on real photos: decomposition, relighting, and the domain gap in numbers.

    python -m disent.eval.photos --run RUN_DIR|NAME [...] [--out FOLDER] [--workers 2]

A model trained on SynthFaces is applied to the aligned photo crops of the pseudo-GT pipeline.
Real photos have no intrinsic ground truth, so the gap is measured on what both domains
share, each against the *pseudo* ground truth (the same landmark-fit rendering on both):
reconstruction error, the angle between predicted normals and ``normal_pseudo`` inside
``mask_pseudo``, the overlap of the predicted matte with ``mask_pseudo``, the SH error
against ``sh_pseudo`` and the light's shading through ``normal_pseudo`` against L-hat's; the same numbers on
SynthFaces' test split are the reference.  A photo's pixels are stored sRGB-encoded; they are decoded to linear
radiance, SynthFaces' and the image model's space, before the pseudo-GT fit or a model sees them
(:func:`~disent.data.photos.pseudo_gt.crop_pixels`).  The crops are those of the bundled photos' pseudo-GT study
(:mod:`disent.data.photos.study`), which this command runs first.

What the gap is made of is measured one difference at a time (``anatomy``): SynthFaces turned gray, the photos
as stored (sRGB-encoded, not decoded), the photos' crops reframed, and the photos with their face's colour
statistics matched to SynthFaces' (:func:`colour_matched`: per channel, the affine map that gives the pixels inside
``mask_pseudo`` the training faces' mean and std), a preprocessing any photo through the pseudo-GT pipeline can
have.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from disent.data.photos import pseudo_gt as pg
from disent.images import linear_to_srgb, on_matte, over_max, to_array

RELIGHT_NAMES = ("flash_az-60", "flash_az+0", "flash_az+60", "top", "rim_both")


def photo_batch(records: list) -> dict:
    """Stack the cached crops (decoded to linear radiance, :func:`~disent.data.photos.pseudo_gt.crop_pixels`) and
    pseudo ground truth of used records as float32 tensors."""
    zs = [pg.load_cached(r) for r in records]
    f = lambda k: torch.from_numpy(np.stack([z[k] for z in zs]).astype(np.float32))  # noqa: E731
    return {
        "image": torch.from_numpy(np.stack([pg.crop_pixels(z["image"]) for z in zs])),
        "normal_pseudo": f("normal_pseudo"),
        "mask_pseudo": f("mask_pseudo"),
        "sh_pseudo": f("sh_pseudo"),
    }


COLOUR_FACES = 256  # training faces whose mean colour statistics the photos are matched to (colour_matched)
ZOOMS = (0.8, 0.9, 1.0, 1.1, 1.25)  # the photo crops magnified about their centre (1: the pseudo-GT template's framing)


def grayscale(image: torch.Tensor) -> torch.Tensor:
    """``image [B,3,H,W]`` as its luma (ITU-R BT.601) in all three channels: an LFW photo's colour."""
    luma = (image * image.new_tensor([0.299, 0.587, 0.114])[:, None, None]).sum(1, keepdim=True)
    return luma.expand_as(image).contiguous()


def zoomed(batch: dict, zoom: float) -> dict:
    """The photo ``batch`` (:func:`photo_batch`) magnified ``zoom`` times about the crop's centre: the image
    (its edge pixels repeated past the crop), ``normal_pseudo`` and ``mask_pseudo`` alike."""
    image = batch["image"]
    theta = image.new_tensor([[1 / zoom, 0, 0], [0, 1 / zoom, 0]]).expand(len(image), 2, 3)
    grid = F.affine_grid(theta, list(image.shape), align_corners=False)

    def warp(x, mode, padding):
        return F.grid_sample(x, grid, mode=mode, padding_mode=padding, align_corners=False)

    return {
        **batch,
        "image": warp(image, "bilinear", "border"),
        "normal_pseudo": F.normalize(warp(batch["normal_pseudo"], "bilinear", "zeros"), dim=1),
        "mask_pseudo": warp(batch["mask_pseudo"], "nearest", "zeros"),
    }


def face_colour(batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """``(mean [B,3], std [B,3])`` of each image's pixels inside its ``mask_pseudo``, per channel."""
    mask = (batch["mask_pseudo"] > 0.5).to(batch["image"].dtype)
    n = mask.sum((2, 3)).clamp_min(1)
    mean = (batch["image"] * mask).sum((2, 3)) / n
    std = (((batch["image"] - mean[..., None, None]) ** 2 * mask).sum((2, 3)) / n).sqrt()
    return mean, std


@lru_cache(maxsize=2)  # one rendering per resolution, shared by every run apply_run measures
def colour_target(resolution: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(mean [3], std [3])``: :func:`face_colour` of the first :data:`COLOUR_FACES` SynthFaces training faces,
    averaged, the statistics :func:`colour_matched` gives a photo's face."""
    from disent.data import SynthFaces

    train = SynthFaces("train", resolution, size=COLOUR_FACES).get_batch(range(COLOUR_FACES))
    return tuple(x.mean(0) for x in face_colour(train))


def colour_matched(batch: dict, target: tuple) -> dict:
    """``batch`` with each image mapped, per channel, by the affine map that gives its face (``mask_pseudo``) the
    ``target = (mean [3], std [3])`` colour statistics (:func:`face_colour` of the training faces, averaged),
    clamped to [0, 1]."""
    mean, std = face_colour(batch)
    gain = target[1] / std.clamp_min(1e-3)
    image = (batch["image"] - mean[..., None, None]) * gain[..., None, None] + target[0][:, None, None]
    return {**batch, "image": image.clamp(0, 1)}


@torch.no_grad()
def gap_metrics(model, batch: dict, trivial: dict | None = None) -> dict:
    """Reconstruction and agreement with the pseudo ground truth, for one domain.  With ``trivial``
    (:func:`disent.eval.trivial.dataset_means` of the training data) also ``trivial_*``: the training set's mean
    normal map and mean L-hat scored the same way, the constants a network must beat to have read the image."""
    from disent.eval.metrics import (
        light_shading_si_mse,
        mask_iou,
        normal_angular_error,
        reconstruction_metrics,
        sh_error,
    )

    out = model(batch["image"])
    rec = reconstruction_metrics(out["recon"].clamp(0, 1), batch["image"])
    m = {"n": len(batch["image"]), "recon_mse": rec["mse"], "recon_psnr": rec["psnr"]}
    if "normal" in out:
        mask = batch["mask_pseudo"] > 0.5
        m["normal_vs_pseudo_deg"] = normal_angular_error(out["normal"], batch["normal_pseudo"], mask)["mean"]
        matte = out["matte"] > 0.5
        m["matte_covers_mask_pseudo"] = float((matte & mask).sum() / mask.sum())
        m["matte_iou_mask_pseudo"] = mask_iou(out["matte"], batch["mask_pseudo"])
        m["sh_vs_pseudo_mse"] = sh_error(out["sh"], batch["sh_pseudo"])

        # the light as the face shows it: its shading through normal_pseudo against L-hat's, which leaves out the
        # SH directions the face hides (there L-hat's least squares is arbitrary); per image and channel scale-free
        def light_on_face(sh):
            return light_shading_si_mse(sh, batch["sh_pseudo"], batch["normal_pseudo"], mask)

        m["light_vs_pseudo_shading_si_mse"] = light_on_face(out["sh"])
        if trivial is not None:
            normal = trivial["normal"].expand_as(out["normal"])
            m["trivial_normal_vs_pseudo_deg"] = normal_angular_error(normal, batch["normal_pseudo"], mask)["mean"]
            m["trivial_sh_vs_pseudo_mse"] = sh_error(trivial["sh_pseudo"].expand_as(out["sh"]), batch["sh_pseudo"])
            m["trivial_light_vs_pseudo_shading_si_mse"] = light_on_face(trivial["sh_pseudo"].expand_as(out["sh"]))
    return m


@torch.no_grad()
def figures(model, batch: dict, names: list[str], out: Path, tag: str, budget: str = ""):
    """``decomposition_<tag>.png`` and (models with a light code) ``relight_<tag>.png``; the colour pictures (input,
    recon, albedo, relit) sRGB-encoded, as the photos were stored."""
    from disent.images import pyplot

    plt = pyplot()

    from disent.edit.relight import named_light, relight

    res = model(batch["image"])
    cols = [("input", batch["image"], "srgb"), ("recon", res["recon"], "srgb")]  # colour pictures shown as photos are
    if "normal" in res:  # the face layers where the model's own matte claims the face, as in the teaser
        cols += [
            ("matte", res["matte"], "gray"),
            ("normal", on_matte(res, "normal"), "normal"),
            ("normal_pseudo", batch["normal_pseudo"], "normal"),
            ("albedo", on_matte(res, "albedo"), "srgb"),
            ("shading / max", over_max(on_matte(res, "shading")), "rgb"),
        ]
    n = len(names)
    fig, axes = plt.subplots(n, len(cols), figsize=(1.3 * len(cols), 1.3 * n), squeeze=False)
    for i in range(n):
        for j, (title, x, kind) in enumerate(cols):
            axes[i, j].imshow(to_array(x[i], kind))
            axes[i, j].axis("off")
            if i == 0:
                axes[i, j].set_title(title, fontsize=7)
        axes[i, 0].text(-2, 32, names[i], fontsize=5, ha="right", va="center")
    where = "; normal, albedo and shading where its matte > 0.5" if "normal" in res else ""
    fig.suptitle(f"{tag} on real photos (trained on SynthFaces{budget}){where}", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"decomposition_{tag}.png", dpi=150)
    plt.close(fig)
    if "sh" not in res:
        return
    fig, axes = plt.subplots(
        n, 1 + len(RELIGHT_NAMES), figsize=(1.3 * (1 + len(RELIGHT_NAMES)), 1.3 * n), squeeze=False
    )
    relit = [relight(model, batch["image"], named_light(k).expand(n, -1, -1), method="transfer") for k in RELIGHT_NAMES]
    for i in range(n):
        for j, (title, x) in enumerate([("input", batch["image"])] + list(zip(RELIGHT_NAMES, relit))):
            axes[i, j].imshow(to_array(x[i], "srgb"))
            axes[i, j].axis("off")
            if i == 0:
                axes[i, j].set_title(title, fontsize=7)
    fig.suptitle(f"{tag}{budget}: lighting transfer with detailed albedo (Sec. 5.3) onto real photos", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"relight_{tag}.png", dpi=150)
    plt.close(fig)


@lru_cache(maxsize=2)
def synth_means(resolution: int) -> dict:
    """:func:`disent.eval.trivial.dataset_means` of the SynthFaces training split, once per resolution."""
    from disent.data import SynthFaces
    from disent.eval.trivial import dataset_means

    return dataset_means(SynthFaces("train", resolution))


def apply_run(run_dir, records: list, out: Path, n_show: int = 8) -> dict:
    """Figures and gap numbers (``domain_gap_<tag>.json``) of one trained run on the photo records."""
    from disent.data import SynthFaces
    from disent.models import load_run
    from disent.runs import folder_id

    model, cfg = load_run(run_dir)
    tag = f"{cfg.model.name}_" + ("shipped" if model.shipped else f"run-{folder_id(run_dir)}")
    res = int(cfg.data.resolution)
    if pg.load_cached(records[0])["image"].shape[0] != res:
        raise ValueError(f"run {run_dir} is at {res} px; rerun the photos at --resolution {res}")
    photos = photo_batch(records)
    synth = SynthFaces("test", res, size=len(records)).get_batch(range(len(records)))
    budget = {"train_size": cfg.data.get("train_size"), "steps": model.trained_steps}
    trivial = synth_means(res) if cfg.data.name == "synth" else None
    matched = colour_matched(photos, colour_target(res))
    gap = {
        "run": str(run_dir),
        "model": cfg.model.name,
        "trained_on": cfg.data.name,
        "training": budget,
        "photo_pixels": "linear",  # decoded from sRGB (results without this key read the stored sRGB codes)
        "photos": gap_metrics(model, photos, trivial),
        "synthfaces_test": gap_metrics(model, synth, trivial),
        "anatomy": {  # what the gap is made of: the photos' colour, and the framing of their crops
            "synthfaces_test_grayscale": gap_metrics(model, {**synth, "image": grayscale(synth["image"])}, trivial),
            "photos_srgb": gap_metrics(model, {**photos, "image": linear_to_srgb(photos["image"])}, trivial),
            "photos_zoom": {f"{z:g}": gap_metrics(model, zoomed(photos, z), trivial) for z in ZOOMS},
            "photos_colour_matched": gap_metrics(model, matched, trivial),  # its PSNR: against the matched input
        },
        "tag": tag,
    }
    (out / f"domain_gap_{tag}.json").write_text(json.dumps(gap, indent=2) + "\n")
    show = [r for r in records if not Path(r.path).stem.startswith("lfw")][:2] + [
        r for r in records if Path(r.path).stem.startswith("lfw")
    ][: n_show - 2]
    shown = [records.index(r) for r in show]
    for batch, suffix in ((photos, ""), (matched, "_colour_matched")):
        figures(
            model,
            {k: v[shown] for k, v in batch.items()},
            [Path(r.path).stem for r in show],
            out,
            tag + suffix,
            f": {budget['train_size']} images, {steps_text(budget)}",
        )
    for dom in ("photos", "synthfaces_test"):
        print(f"{tag} {dom:16s} " + "  ".join(f"{k} {v:.4g}" for k, v in gap[dom].items()))
    return gap


def steps_text(budget: dict) -> str:
    """How long a model trained: its checkpoint's steps (results written before they were recorded: the config)."""
    if budget.get("steps") is not None:
        return f"{budget['steps']:,} steps"
    return f"{budget.get('max_steps') or str(budget.get('epochs')) + ' epochs of'} steps"


def main(argv=None):
    import logging

    from disent.data.photos.study import arguments, run_study
    from disent.storage import tool_folder

    ap = arguments(__doc__)
    ap.add_argument(
        "--run",
        nargs="+",
        required=True,
        help="trained run folders or shipped names to apply to the crops; 'auto': the plain explicit "
        "and implicit runs under outputs/ and multirun/ (disent.runs.pick_runs)",
    )
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    out = tool_folder("photos", args.out)
    records = run_study(out, args.resolution, args.workers, args.cache_dir)
    runs = args.run
    if runs == ["auto"]:
        from disent.runs import find_runs, pick_runs

        runs = [r.path for k, r in pick_runs(find_runs()).items() if k in ("explicit", "implicit")]
        print("runs:", [str(r) for r in runs] or "none found")
    for run in runs:  # domain_gap_<tag>.json and the figures; the report draws the tables from the JSON
        apply_run(run, records, out)
    print(f"wrote {out}; publish it with: python -m disent.report --publish {out}")


if __name__ == "__main__":
    main()

"""Scoring a model's outputs against SynthFaces' truth: the metrics of every layer on the region it is scored on,
the batches and the model's outputs over a split.  Below the training loop (its validation records read it); the
evaluation of a run, ``eval.json``, is :mod:`disent.eval.evaluate`."""

from __future__ import annotations

import time

import torch
from torch.utils.data import DataLoader, Subset

from disent.eval.metrics import (
    aligned_normal_error,
    angular_error_deg,
    completed_sh,
    light_shading_si_mse,
    log_shading_agreement,
    mask_iou,
    normal_angular_error,
    normal_spread,
    pattern_corr,
    reconstruction_metrics,
    region_depth,
    scale_invariant_mse,
    scale_invariant_mse_bands,
    sh_error,
    sh_error_shown_hidden,
    sh_gram,
    shading_contrast,
)
from disent.regions import FACE_THRESHOLD, decomposed_region, face_mask
from disent.render import sh_shading


def batches(dataset, batch_size: int = 64, limit: int | None = None, indices=None):
    """Collated dict batches of the first ``limit`` items (or of ``indices``), in order, no workers."""
    if indices is None:
        indices = range(len(dataset) if limit is None else min(limit, len(dataset)))
    return DataLoader(Subset(dataset, list(indices)), batch_size=batch_size, shuffle=False, num_workers=0)


@torch.no_grad()
def predict(model, image: torch.Tensor) -> dict:
    """``model(image)`` in eval mode without gradients."""
    was_training = model.training
    model.eval()
    try:
        return model(image)
    finally:
        model.train(was_training)


def _cat(parts):
    return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}


def model_outputs(
    model,
    dataset,
    limit: int = 256,
    batch_size: int = 64,
    keys=("recon", "normal", "albedo", "shading", "sh", "matte", "uv", "normal_uv"),
):
    """Concatenated model outputs and ground truth over the first ``limit`` items, plus images/s."""
    outs, gts, seconds = [], [], 0.0
    for batch in batches(dataset, batch_size, limit):
        t0 = time.perf_counter()
        out = predict(model, batch["image"])
        seconds += time.perf_counter() - t0
        outs.append({k: out[k].float() for k in keys if k in out})
        gts.append({k: v for k, v in batch.items() if torch.is_tensor(v)})
    out, gt = _cat(outs), _cat(gts)
    return out, gt, len(gt["image"]) / max(seconds, 1e-12)


# metric suffix -> part of disent.eval.metrics.log_shading_agreement, each the median over faces and channels
AGREEMENT_KEYS = {"contrast": "slope", "pattern_corr": "corr", "contrast_ratio": "ratio", "log_error": "error"}
PSEUDO_ERROR_BINS = (0, 5, 10, 20, 180)  # degrees of the pseudo-GT's own error: nearly right ... far off


def normal_metrics(normal: torch.Tensor, gt: dict) -> dict:
    """``normal_*``: the angular error of ``normal`` against the true normals; ``pseudo_normal_*``:
    the pseudo-GT's, on the same pixels (:func:`decomposed_region`); ``normal_spread`` and ``true_normal_spread``
    (:func:`~disent.eval.metrics.normal_spread`); ``normal_aligned_mean``, ``_angle`` and ``_det``: the error left
    after the best rotation or mirror of the whole frame (:func:`~disent.eval.metrics.aligned_normal_error`);
    ``normal_mean_where_pseudo_LO_HI``, ``pseudo_normal_mean_...``
    and ``share_...``: both errors, and the pixels' share, where the pseudo-GT errs by LO to HI degrees
    (:data:`PSEUDO_ERROR_BINS`)."""
    both = decomposed_region(gt)
    m = {f"normal_{k}": v for k, v in normal_angular_error(normal, gt["normal"], both).items()}
    m.update(
        {f"pseudo_normal_{k}": v for k, v in normal_angular_error(gt["normal_pseudo"], gt["normal"], both).items()}
    )
    # a collapse check: a model trained without E_recon-N can put one flat normal on every pixel (its albedo then
    # takes the shading); the spread about each image's mean normal shows it, beside the truth's
    m["normal_spread"], m["true_normal_spread"] = normal_spread(normal, both), normal_spread(gt["normal"], both)
    # and a frame check: what is left once one rotation or mirror of the whole frame is forgiven
    m.update({f"normal_aligned_{k}": v for k, v in aligned_normal_error(normal, gt["normal"], both).items()})
    # how the network goes beyond the fit: both errors on the pixels binned by the pseudo-GT's own error
    scored = both[:, 0] > 0.5
    errors = {
        k: angular_error_deg(n, gt["normal"]).double() for k, n in (("normal", normal), ("pseudo", gt["normal_pseudo"]))
    }
    for lo, hi in zip(PSEUDO_ERROR_BINS, PSEUDO_ERROR_BINS[1:]):
        where = scored & (errors["pseudo"] >= lo) & (errors["pseudo"] < hi)
        if where.any():
            tag = f"where_pseudo_{lo}_{hi}"
            m[f"normal_mean_{tag}"] = errors["normal"][where].mean().item()
            m[f"pseudo_normal_mean_{tag}"] = errors["pseudo"][where].mean().item()
            m[f"share_{tag}"] = (where.sum() / scored.sum()).item()
    return m


def _corr_over_faces(x: torch.Tensor, y: torch.Tensor) -> float:
    """Pearson's correlation over the batch of two per-face values ``[B, K]``, averaged over the K columns; 0 for
    a column that does not vary (beyond float32 rounding, 1e-6 of its size; a batch of one face)."""
    x, y = x.double(), y.double()
    flat = (x.std(0, correction=0) <= 1e-6 * x.abs().mean(0)) | (y.std(0, correction=0) <= 1e-6 * y.abs().mean(0))
    x, y = x - x.mean(0), y - y.mean(0)
    corr = (x * y).sum(0) / ((x**2).sum(0) * (y**2).sum(0)).sqrt().clamp_min(1e-300)
    return torch.where(flat, torch.zeros_like(corr), corr).mean().item()


def face_colour(x: torch.Tensor, region: torch.Tensor) -> torch.Tensor:
    """``[B, 3]``: each face's mean colour of ``x [B, C, H, W]`` (one channel: gray) inside ``region [B,1,H,W]``."""
    return (x.expand(-1, 3, -1, -1) * region).sum((2, 3)) / region.sum((2, 3)).clamp_min(1)


def skin_in_shading(shading_rgb: torch.Tensor, skin_rgb: torch.Tensor) -> dict:
    """Where each face's skin went, from the faces' mean shading and true albedo colours ``[B, 3]``: ``tone``, the
    correlation over faces of their chromaticities (each channel over the three's sum), and ``brightness``, of their
    mean luminance; near 0 when the shading carries only the light, towards 1 when it carries the skin."""
    return {
        "tone": _corr_over_faces(
            shading_rgb / shading_rgb.sum(1, keepdim=True).clamp_min(1e-12),
            skin_rgb / skin_rgb.sum(1, keepdim=True).clamp_min(1e-12),
        ),
        "brightness": _corr_over_faces(shading_rgb.mean(1, True), skin_rgb.mean(1, True)),
    }


ALBEDO_CEILING = 0.95  # an albedo value this close to the sigmoid's 1 is pinned there: its pattern is clipped


def ceiling_share(albedo: torch.Tensor, region: torch.Tensor, ceiling: float = ALBEDO_CEILING) -> float:
    """The share of an albedo's values ``[B,C,H,W]`` inside ``region [B,1,H,W]`` (pixels and channels) at or above
    ``ceiling``: where a model puts the face's brightness in the shading, its albedo is pinned at the sigmoid's 1
    there and is flat whatever the skin does."""
    w = (region > 0.5).expand_as(albedo)
    return ((albedo >= ceiling) & w).sum().item() / max(w.sum().item(), 1)


def bws_stats(out: dict, gt: dict) -> dict:
    """Shading mean per channel over the true face, corr(estimated albedo, true shading), and where each face's
    skin tone and brightness went.

    ``albedo_shading_corr`` is Pearson's over face pixels of each image (luminance, i.e. the channel
    mean), averaged over images: near 0 when albedo is free of shading, towards 1 when it
    absorbs it.  BWS pushes the shading mean over the batch to c = 0.75 per channel, which leaves each face free
    to put its own skin in the shading: ``shading_albedo_tone_corr`` and ``shading_albedo_brightness_corr`` are
    :func:`skin_in_shading` on the pixels of :func:`decomposed_region` (where the albedo is scored); near 0 when the
    shading carries only the light, towards 1 when it carries the skin.  ``true_shading_albedo_*`` are the same for
    the true shading: what the scenes' lights give.
    """
    face = face_mask(gt["matte"])
    w = face.flatten(1)
    n = w.sum(1).clamp_min(1)
    mean_c = ((out["shading"].expand(-1, 3, -1, -1) * face).flatten(2).sum(2) / n[:, None]).mean(0)  # [3]
    skin_region = decomposed_region(gt)  # the face without hair and neck, as the albedo is scored
    skin = face_colour(gt["albedo"], skin_region)
    tone = {}
    for prefix, shading in (("", out["shading"]), ("true_", gt["shading"])):
        for what, corr in skin_in_shading(face_colour(shading, skin_region), skin).items():
            tone[f"{prefix}shading_albedo_{what}_corr"] = corr
    return {
        "shading_mean_rgb": mean_c.tolist(),
        "shading_cast": (mean_c.max() - mean_c.min()).item(),
        "albedo_shading_corr": pattern_corr(out["albedo"].mean(1, True), gt["shading"].mean(1, True), face),
        **tone,
    }


def albedo_metrics(out: dict, gt: dict, region: torch.Tensor, face: torch.Tensor) -> dict:
    """The albedo's metrics of :func:`metrics_from_outputs` (``albedo_*``, its detailed albedo's, and the same with
    one input of its shading made true)."""
    m = {}
    if "albedo" in out:
        m["albedo_si_mse"] = scale_invariant_mse(out["albedo"], gt["albedo"], region)
        m["albedo_global_si_mse"] = scale_invariant_mse(out["albedo"], gt["albedo"], region, per_image=False)
        m["albedo_colour_si_mse"] = scale_invariant_mse(out["albedo"], gt["albedo"], region, per_channel=False)
        m["albedo_face_si_mse"] = scale_invariant_mse(out["albedo"], gt["albedo"], face)
        m["albedo_pattern_corr"] = pattern_corr(out["albedo"], gt["albedo"], region)
        bands = scale_invariant_mse_bands(out["albedo"], gt["albedo"], region)
        m["albedo_coarse_si_mse"], m["albedo_fine_si_mse"] = bands["coarse"], bands["fine"]
        for prefix, albedo in (("", out["albedo"]), ("true_", gt["albedo"])):
            m[f"{prefix}albedo_ceiling_share"] = ceiling_share(albedo, region)
    if {"albedo", "shading"} <= set(out) and {"albedo", "image"} <= set(gt):
        # Sec. 5.3's "detailed" albedo, Eq. 2 solved for A with the model's own shading: I / S_e keeps every detail
        # of the image, and every error of S_e (the relighting transfer renders with it)
        from disent.render import detailed_albedo

        image = gt["image"].to(out["shading"].dtype)
        m["albedo_detailed_si_mse"] = scale_invariant_mse(
            detailed_albedo(image, out["shading"], out["albedo"]), gt["albedo"], region
        )
        if {"normal", "sh"} <= set(out) and {"normal", "sh"} <= set(gt):  # S(N, L) of Eq. 4 with N or L made true
            for name, normal, sh in (
                ("true_light", out["normal"], gt["sh"]),
                ("true_normals", gt["normal"], out["sh"]),
            ):
                shading = sh_shading(normal.to(image.dtype), sh.to(image.dtype))
                detailed = detailed_albedo(image, shading, out["albedo"])
                m[f"albedo_detailed_{name}_si_mse"] = scale_invariant_mse(detailed, gt["albedo"], region)
    return m


def light_metrics(out: dict, gt: dict, region: torch.Tensor) -> dict:
    """The light's metrics of :func:`metrics_from_outputs` (``sh_error*``, ``*light_shading_si_mse``, the shown and
    hidden split, the contrast parts), for the network's light, L-hat and the taught target."""
    m = {}
    if "sh" in out:
        m["sh_error"] = sh_error(out["sh"], gt["sh"])
        m["pseudo_sh_error"] = sh_error(gt["sh_pseudo"], gt["sh"])
        m["sh_error_coefficients"] = sh_error(out["sh"], gt["sh"], reduction="coefficients")
        # the network's light, L-hat and the target it was taught where that is not L-hat (sh_target), each as
        # this face shows it: its shading through the true normals (Eq. 4), which leaves out the SH directions a
        # face's normals cannot reveal; per image and channel scale-invariant
        lights = {
            "": out["sh"],
            "pseudo_": gt["sh_pseudo"],
            **({"target_": gt["sh_target"]} if "sh_target" in gt else {}),
        }
        for prefix, sh in lights.items():
            m[f"{prefix}light_shading_si_mse"] = light_shading_si_mse(sh, gt["sh"], gt["normal"], region)
            # the coefficients split by what the face shows: only the shown part is identifiable from an image
            split = sh_error_shown_hidden(sh, gt["sh"], gt["normal"], region)
            m[f"{prefix}sh_error_shown"], m[f"{prefix}sh_error_hidden"] = split["shown"], split["hidden"]
            agree = shading_contrast(sh, gt["sh"], gt["normal"], region)
            m.update({f"{prefix}light_{k}": agree[v].median().item() for k, v in AGREEMENT_KEYS.items()})
    return m


def metrics_from_outputs(out: dict, gt: dict) -> dict:
    """Flat metric dict from model outputs and ground truth (same keys as SynthFaces items).

    ``recon_*`` on the whole image, ``recon_face_*`` under the true face mask.  On the pixels of
    :func:`decomposed_region`: ``normal_*`` the model's angular error against the true normals and
    ``pseudo_normal_*`` the pseudo-GT's; ``albedo_si_mse`` (a scale per image and channel),
    ``albedo_global_si_mse`` (a scale per channel for all images), ``albedo_colour_si_mse`` (one scale per image for
    the three channels: the skin's colour must be in the albedo, not in the shading), ``albedo_coarse_si_mse`` and
    ``albedo_fine_si_mse`` (``albedo_si_mse``'s error above and below a 2-px blur), ``albedo_detailed_si_mse`` (the
    detailed albedo of Sec. 5.3, the image over the model's shading), and the same with one input of that shading
    made true, to say which holds the albedo back: ``albedo_detailed_true_light_si_mse`` (the model's normals under
    the true light) and ``albedo_detailed_true_normals_si_mse`` (the model's light on the true normals),
    ``shading_si_mse`` and ``shading_colour_si_mse`` (one scale per image for the three channels: the shading must
    have the light's colour, not the skin's).  For reference
    ``albedo_face_si_mse``: the albedo over the whole true face mask, hair and neck included.
    ``albedo_pattern_corr``: Pearson's correlation with the true albedo per image and channel (higher is better;
    forgives contrast too, :func:`~disent.eval.metrics.pattern_corr`).  ``albedo_ceiling_share`` (and the truth's,
    ``true_albedo_ceiling_share``): the share of the scored values at the albedo sigmoid's ceiling
    (:func:`ceiling_share`).
    ``sh_error`` after the per-image scale alignment, and ``sh_error_coefficients`` its share per coefficient;
    ``light_shading_si_mse``: the light's shading through the true normals against the true shading;
    ``sh_error_shown`` and ``sh_error_hidden``: the coefficients' error split between the SH directions the face's
    normals show and those they hide (:func:`~disent.eval.metrics.sh_error_shown_hidden`); ``light_contrast``: how
    much of the true shading's contrast the light's shading shows there, through the true normals, the median over
    faces and channels of :func:`~disent.eval.metrics.shading_contrast`'s slope (1: the truth's; below 1: the rest
    left to the albedo), parted into ``light_pattern_corr`` (its log shading's correlation with the truth's) and
    ``light_contrast_ratio`` (its magnitude), and ``light_log_error``, what both leave wrong (the squared difference
    of the centred log shadings as a share of the truth's spread); ``shading_contrast``, ``shading_pattern_corr``,
    ``shading_contrast_ratio`` and ``shading_log_error``: the same for the model's own shading (its normals too)
    against the true shading. ``target_light_shading_si_mse``, ``target_sh_error_shown`` and ``_hidden`` and
    ``target_light_*``: the same for E_recon-L's target where the evaluation is handed one (``sh_target`` in ``gt``,
    :func:`evaluate_model`'s ``light_target``).
    ``matte_iou``: the matte's IoU with the true face region ``mask_face`` (the skin a 3DMM covers: what the matte's
    supervision M-hat estimates; not hair, ears or neck), and ``pseudo_matte_iou`` M-hat's own, both cut at 0.5
    (:func:`~disent.eval.metrics.mask_iou`; higher is better); ``matte_soft_edge`` and the rest of
    :func:`matte_edge_metrics`: where the matte is soft, and whether it is M-hat's expectation there.
    ``uv_error`` and the rest of :func:`uv_metrics` where the model draws a UV map (the implicit model).
    """
    m = {}
    face = face_mask(gt["matte"])
    for name, mask in (("recon", None), ("recon_face", face)) if "recon" in out else ():
        for k, v in reconstruction_metrics(out["recon"].clamp(0, 1), gt["image"], mask).items():
            m[f"{name}_{k}"] = v
    if "normal" in out:
        m.update(normal_metrics(out["normal"], gt))
    region = decomposed_region(gt)
    m.update(albedo_metrics(out, gt, region, face))
    if "shading" in out and "shading" in gt:  # (the validation batch carries no true shading)
        shading = out["shading"].expand_as(gt["shading"])
        m["shading_si_mse"] = scale_invariant_mse(shading, gt["shading"], region)
        m["shading_colour_si_mse"] = scale_invariant_mse(shading, gt["shading"], region, per_channel=False)
        agree = log_shading_agreement(shading, gt["shading"], region)
        m.update({f"shading_{k}": agree[v].median().item() for k, v in AGREEMENT_KEYS.items()})
    m.update(light_metrics(out, gt, region))
    if {"albedo", "shading"} <= set(out) and "shading" in gt:
        m.update(bws_stats(out, gt))
    if "matte" in out and "mask_face" in gt:  # the matte against the face region M-hat estimates (Sec. 3.3)
        m["matte_iou"] = mask_iou(out["matte"], gt["mask_face"])
        m["pseudo_matte_iou"] = mask_iou(gt["mask_pseudo"], gt["mask_face"])
        m.update(matte_edge_metrics(out["matte"], gt))
    if "uv" in out and "uv" in gt:
        m.update(uv_metrics(out, gt, region))
    return m


MATTE_EDGE = 2  # px: the face region's edge band (depth <= MATTE_EDGE); its inside lies deeper than 2 * MATTE_EDGE


def matte_edge_metrics(matte: torch.Tensor, gt: dict) -> dict:
    """Where the matte is soft, and why, by depth inside the true face region ``mask_face``
    (:func:`~disent.eval.metrics.region_depth`): ``matte_soft_edge`` and ``matte_soft_inner``, the share of its edge
    band (depth <= :data:`MATTE_EDGE` px) and of its inside (deeper than twice that) where the matte is under
    :data:`FACE_THRESHOLD`; ``matte_mean_edge`` and ``pseudo_matte_mean_edge``, the mean of the matte and of its L2
    target M-hat (Sec. 4.2) on the edge band.  The two means agree where the matte has learned M-hat's expectation:
    an L2 loss toward a binary target whose edge it cannot predict leaves a soft edge."""
    depth = region_depth(gt["mask_face"], 2 * MATTE_EDGE + 1)
    edge, inner = (depth > 0) & (depth <= MATTE_EDGE), depth > 2 * MATTE_EDGE
    soft = matte < FACE_THRESHOLD

    def mean_on(values, where):  # NaN where no pixel is there
        return values[where].float().mean().item() if where.any() else float("nan")

    return {
        "matte_soft_edge": mean_on(soft, edge),
        "matte_soft_inner": mean_on(soft, inner),
        "matte_mean_edge": mean_on(matte, edge),
        "pseudo_matte_mean_edge": mean_on(gt["mask_pseudo"], edge),
    }


def uv_metrics(out: dict, gt: dict, region: torch.Tensor) -> dict:
    """The implicit model's two steps, scored apart on ``region`` (:func:`decomposed_region`): ``uv_error``, the
    distance of its UV map from the true one (UV units: the texture square is 1 wide), and, with UV-space normals,
    ``normal_at_true_uv_mean``, the angular error of its UV-space normals looked up at the true UV.  Normals
    right at the true UV but wrong at its own say the UV map failed; wrong at both, the UV-space normals did.
    ``pseudo_uv_error``: the same distance for the UV map that supervised it (E_UV's target, Sec. 4.2)."""
    from disent.losses import masked_mean
    from disent.models.implicit import sample_uv
    from disent.render import unit

    def distance(uv):  # [B,2,H,W] -> mean over the region of the per-pixel distance from the true uv
        return masked_mean((uv - gt["uv"].to(uv.dtype)).norm(dim=1, keepdim=True), region.to(uv.dtype)).item()

    m = {"uv_error": distance(out["uv"])}
    if "uv_pseudo" in gt:
        m["pseudo_uv_error"] = distance(gt["uv_pseudo"])
    if "normal_uv" in out:
        looked_up = unit(sample_uv(out["normal_uv"], gt["uv"].to(out["normal_uv"].dtype)))
        m["normal_at_true_uv_mean"] = normal_angular_error(looked_up, gt["normal"], region)["mean"]
    return m


def completed_light_metrics(out: dict, gt: dict, prior: torch.Tensor) -> dict:
    """``sh_error_completed``: the SH error of the network's light completed by ``prior`` (the mean train light,
    :func:`disent.eval.trivial.dataset_means`) along the SH directions its *own* normals and matte hide
    (:func:`~disent.eval.metrics.completed_sh`); ``pseudo_sh_error_completed``: L-hat's, completed along what the
    pseudo normals hide.  No truth enters the estimate: both are estimators, scored like ``sh_error``."""
    own = face_mask(out["matte"]) if "matte" in out else torch.ones_like(out["normal"][:, :1])
    m = {"sh_error_completed": sh_error(completed_sh(out["sh"], prior, sh_gram(out["normal"], own)), gt["sh"])}
    if {"sh_pseudo", "normal_pseudo", "mask_pseudo"} <= set(gt):
        pseudo = sh_gram(gt["normal_pseudo"], gt["mask_pseudo"])
        m["pseudo_sh_error_completed"] = sh_error(completed_sh(gt["sh_pseudo"], prior, pseudo), gt["sh"])
    return m


VAL_KEYS = (
    "recon_psnr",
    "recon_face_psnr",
    "normal_mean",
    "pseudo_normal_mean",
    "albedo_si_mse",
    "albedo_global_si_mse",
    "albedo_face_si_mse",
    "sh_error",
    "pseudo_sh_error",
    "light_shading_si_mse",
    "pseudo_light_shading_si_mse",
)


def validate(model, batch: dict) -> dict:
    """The periodic check on a fixed validation batch: recon PSNR (whole image and face), normal angular
    error of the network and of the pseudo-GT on the same pixels (degrees), albedo scale-invariant MSE
    and SH error (:mod:`disent.eval.evaluate`'s metrics, the ``VAL_KEYS`` the batch has truth for)."""
    out = predict(model, batch["image"])
    out = {k: out[k].float() for k in ("recon", "normal", "albedo", "sh") if k in out}
    if "matte" not in batch:  # real photos: no intrinsic ground truth, the reconstruction only
        return {"recon_psnr": reconstruction_metrics(out["recon"].clamp(0, 1), batch["image"])["psnr"]}
    m = metrics_from_outputs(out, batch)
    return {k: m[k] for k in VAL_KEYS if k in m}

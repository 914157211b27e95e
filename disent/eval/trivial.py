"""Trivial baselines: one constant estimate for every image, from the training split's ground truth.

A layer counts as learned only where the network beats its trivial baseline:

* normals: the dataset-mean normal map (per pixel, the normalised mean of the true normals over the
  face pixels of the training images; the frontal normal where no face ever covers the pixel);
* albedo: the dataset-mean albedo map (per pixel mean over face pixels), scored by the same
  scale-invariant MSEs as the network's albedo;
* shading: the mean light through the mean normal map (scale-invariant, like the network's shading), and the
  detailed albedo it gives, the image over that shading;
* albedo, a stronger floor where the data carry uv: the *template*, the mean train albedo in UV space (``albedo_uv``)
  placed on each test face through its true uv.  It knows where the face's features are and nothing of whose face it
  is; an albedo that beats the mean map but not the template has learned the face's placement, not its identity
  (``template_albedo_si_mse``, ``template_albedo_colour_si_mse``, ``template_albedo_global_si_mse``);
* uv, where the data carry it: the dataset-mean UV map (per pixel mean over face pixels), scored by the same
  distance from the true uv as the implicit model's UV map (``trivial_uv_error``);
* matte: the mean train face region (``mask_face``, the share of training faces whose skin covers each pixel),
  scored by the same IoU as the network's matte;
* light: the mean true SH light, scored by the same scale-aligned SH error; beside it, for context,
  ``trivial_lhat_sh_error``: the mean L-hat, the constant a network could learn from its supervision alone
  (L-hat's constant albedo carries skin tone and the face's dark features into the light, so its mean is
  biased where the true mean is not).

``trivial_metrics`` scores them with :func:`disent.eval.scoring.metrics_from_outputs`, the code that
scores the networks, and returns its keys prefixed with ``trivial_`` (``trivial_normal_mean``,
``trivial_albedo_si_mse``, ``trivial_albedo_global_si_mse``, ``trivial_sh_error``, ...).
"""

from __future__ import annotations

import torch

from disent.eval.metrics import scale_invariant_mse, sh_error
from disent.eval.scoring import metrics_from_outputs
from disent.regions import decomposed_region, face_mask
from disent.render import sh_shading

N_IMAGES = 1024  # training images the means are taken over (fewer if the split is smaller)
KEYS = (
    "normal_mean",
    "normal_median",
    "albedo_si_mse",
    "albedo_global_si_mse",
    "albedo_colour_si_mse",
    "albedo_face_si_mse",
    "albedo_coarse_si_mse",
    "albedo_fine_si_mse",
    "albedo_detailed_si_mse",
    "shading_si_mse",
    "shading_colour_si_mse",
    "sh_error",
    "sh_error_shown",
    "sh_error_hidden",
    "light_shading_si_mse",
    "light_contrast",
    "light_pattern_corr",
    "light_contrast_ratio",
    "light_log_error",
    "shading_contrast",
    "shading_pattern_corr",
    "shading_contrast_ratio",
    "shading_log_error",
    "matte_iou",
    "uv_error",
)


@torch.no_grad()
def dataset_means(dataset, n: int = N_IMAGES, batch_size: int = 256) -> dict:
    """``normal [3,H,W]``, ``albedo [3,H,W]``, ``sh [C,9]``: the constant estimates, from the first
    ``n`` items of ``dataset`` (which must carry ``normal``, ``albedo``, ``sh`` and ``matte``); ``sh_pseudo``, the
    template's ``albedo_uv [3,R,R]``, the face region's mean ``mask_face [1,H,W]`` and the mean UV map ``uv [2,H,W]``
    (over face pixels, like the albedo) where the items carry them."""
    from disent.eval.scoring import batches

    optional = ("sh_pseudo", "albedo_uv", "mask_face")
    sums = {"normal": 0.0, "albedo": 0.0, "uv": 0.0, "weight": 0.0, "sh": 0.0, **{k: 0.0 for k in optional}}
    count = 0
    for b in batches(dataset, batch_size, n):
        b = {k: v.cpu() if torch.is_tensor(v) else v for k, v in b.items()}  # summed on the CPU (data.device aside)
        face = face_mask(b["matte"].double())
        sums["normal"] = sums["normal"] + (b["normal"].double() * face).sum(0)
        sums["albedo"] = sums["albedo"] + (b["albedo"].double() * face).sum(0)
        if "uv" in b:
            sums["uv"] = sums["uv"] + (b["uv"].double() * face).sum(0)
        sums["weight"] = sums["weight"] + face.sum(0)
        sums["sh"] = sums["sh"] + b["sh"].double().sum(0)
        for k in optional:
            if k in b:
                sums[k] = sums[k] + b[k].double().sum(0)
        count += len(b["image"])
    if count == 0:
        raise ValueError("dataset_means: the data set is empty")
    covered = sums["weight"] > 0
    frontal = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)[:, None, None]
    normal = torch.where(covered, torch.nn.functional.normalize(sums["normal"], dim=0), frontal)
    mean_albedo = sums["albedo"].sum((1, 2)) / sums["weight"].sum().clamp_min(1)  # [C], where no face ever is
    albedo = torch.where(covered, sums["albedo"] / sums["weight"].clamp_min(1), mean_albedo[:, None, None])
    means = {"normal": normal.float(), "albedo": albedo.float(), "sh": (sums["sh"] / count).float(), "n": count}
    if torch.is_tensor(sums["uv"]):  # the texture's centre where no face ever is
        means["uv"] = torch.where(covered, sums["uv"] / sums["weight"].clamp_min(1), torch.tensor(0.5)).float()
    for k in optional:
        if torch.is_tensor(sums[k]):
            means[k] = (sums[k] / count).float()
    return means


def trivial_outputs(means: dict, batch: int) -> dict:
    """The constant estimates as a model's outputs for ``batch`` images, and the shading they make (Eq. 4); the
    mean face region as the matte and the mean UV map where ``means`` has them."""
    out = {k: means[k].expand(batch, *means[k].shape) for k in ("normal", "albedo", "sh", "uv") if k in means}
    if "mask_face" in means:
        out["matte"] = means["mask_face"].expand(batch, *means["mask_face"].shape)
    return {**out, "shading": sh_shading(out["normal"], out["sh"])}


TEMPLATE_KEYS = ("albedo_si_mse", "albedo_colour_si_mse", "albedo_global_si_mse")


def template_albedo(albedo_uv: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``[B,3,H,W]``: the UV-space albedo ``[3,R,R]`` placed on each face through its ``uv [B,2,H,W]`` in [0, 1]
    (bilinear, as :meth:`disent.lighting.texture.TextureModel.at_pixels` reads a texture)."""
    grid = (2 * uv.to(albedo_uv.dtype) - 1).permute(0, 2, 3, 1)
    return torch.nn.functional.grid_sample(
        albedo_uv.expand(len(uv), *albedo_uv.shape), grid, mode="bilinear", align_corners=True
    )


def trivial_metrics(means: dict, gt: dict) -> dict:
    """``trivial_<key>`` for each key of ``KEYS``: the constant estimates scored against ``gt``; with a template and
    the true uv, ``template_<key>`` for each key of ``TEMPLATE_KEYS``."""
    m = metrics_from_outputs(trivial_outputs(means, len(gt["image"])), gt)
    out = {f"trivial_{k}": m[k] for k in (*KEYS, "sh_error_coefficients") if k in m}  # what gt has truth for
    if "albedo_uv" in means and {"uv", "albedo"} <= set(gt):
        template, region = template_albedo(means["albedo_uv"], gt["uv"]), decomposed_region(gt)
        for key, kw in zip(TEMPLATE_KEYS, ({}, {"per_channel": False}, {"per_image": False})):
            out[f"template_{key}"] = scale_invariant_mse(template, gt["albedo"], region, **kw)
    if "sh_pseudo" in means:
        out["trivial_lhat_sh_error"] = sh_error(means["sh_pseudo"].expand_as(gt["sh"]), gt["sh"])
    return out


__all__ = ["dataset_means", "trivial_outputs", "trivial_metrics", "template_albedo", "N_IMAGES", "TEMPLATE_KEYS"]

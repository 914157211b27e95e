"""Evaluation metrics: batched torch in, python floats (or per-image tensors) out.

Masks are ``[B,1,H,W]`` (or ``[B,H,W]``); a pixel counts when its mask value is > 0.5.
Aggregates pool pixels or average images as each docstring says.

Scale conventions (intrinsic images are defined only up to scale, Grosse et al. 2009):

* albedo: :func:`scale_invariant_mse` rescales the prediction by the least-squares optimal
  scalar per image **and per channel** before the MSE;
* lighting: :func:`sh_error` rescales the predicted SH by the least-squares optimal scalar
  per image (one scalar for all 3 x 9 coefficients; ``per_channel=True`` uses one per channel,
  matching the albedo convention), then divides the squared error by the truth's squared norm;
  :func:`sh_error_shown_hidden` splits it between the SH directions a face's normals show and those
  they hide; :func:`completed_sh` fills what a face hides from a prior (the mean train light).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from disent.render import sh_shading

ANGLE_THRESHOLDS = (20.0, 25.0, 30.0)


def _mask(mask: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor:
    """Boolean mask ``[B,1,H,W]`` checked against ``like [B,C,H,W]`` (all ones when None)."""
    B, _, H, W = like.shape
    if mask is None:
        return torch.ones(B, 1, H, W, dtype=torch.bool, device=like.device)
    if mask.dim() == 3:
        mask = mask[:, None]
    if mask.shape != (B, 1, H, W):
        raise ValueError(f"mask must be [B,1,H,W] = {(B, 1, H, W)}, got {tuple(mask.shape)}")
    return mask > 0.5


def _check_pair(pred: torch.Tensor, target: torch.Tensor, channels: int | None = None) -> None:
    if pred.shape != target.shape or pred.dim() != 4:
        raise ValueError(f"pred and target must both be [B,C,H,W], got {tuple(pred.shape)} and {tuple(target.shape)}")
    if channels is not None and pred.shape[1] != channels:
        raise ValueError(f"expected {channels} channels, got {pred.shape[1]}")


def angular_error_deg(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel angle in degrees between normal maps ``[B,3,H,W]`` -> ``[B,H,W]``.

    Both maps are normalised (zero vectors stay zero and give 90 degrees); the dot is clamped to [-1, 1].
    """
    _check_pair(pred, target, 3)
    p = torch.nn.functional.normalize(pred.double(), dim=1, eps=1e-12)
    t = torch.nn.functional.normalize(target.double(), dim=1, eps=1e-12)
    cos = (p * t).sum(1).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.acos(cos)).to(pred.dtype)


def normal_angular_error(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> dict:
    """Angular error over the masked pixels of the whole batch (pixels pooled).

    Returns ``mean`` and ``median`` in degrees and ``under_20/25/30``, the share of pixels
    (in [0, 1]) whose error is below 20, 25, 30 degrees.
    """
    err = angular_error_deg(pred, target)
    m = _mask(mask, pred)[:, 0]
    if not m.any():
        raise ValueError("normal_angular_error: the mask selects no pixel")
    e = err[m].double()
    out = {"mean": e.mean().item(), "median": e.median().item()}
    for t in ANGLE_THRESHOLDS:
        out[f"under_{int(t)}"] = (e < t).double().mean().item()
    return out


FLAT_SHARE = 0.25  # a normal map whose spread is under this share of the truth's has collapsed to one flat normal


def normal_spread(normal: torch.Tensor, mask: torch.Tensor) -> float:
    """Mean angle (degrees) between each masked pixel's normal and its image's mean normal, over the masked pixels of
    the batch: how much a normal map varies across a face (a flat map scores 0; SynthFaces' true normals ~39)."""
    w = _mask(mask, normal)
    if not w.any():
        raise ValueError("normal_spread: the mask selects no pixel")
    n = torch.nn.functional.normalize(normal.double(), dim=1, eps=1e-12)
    mean = torch.nn.functional.normalize((n * w).sum((2, 3), keepdim=True), dim=1, eps=1e-12)
    angle = torch.rad2deg(torch.acos((n * mean).sum(1, keepdim=True).clamp(-1.0, 1.0)))
    return angle[w].mean().item()


def aligned_normal_error(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> dict:
    """The angular error left after the one orthogonal map Q of the normals' frame, shared by every masked pixel
    of the batch, that best takes ``pred`` onto ``target`` in least squares (orthogonal Procrustes: Q = U V^T from
    the SVD of sum t p^T over the pixels; least squares on the unit vectors, not the mean angle, so a map near the
    identity can leave the mean angle a hair above the plain error).  A rendering of SH order <= 2 cannot tell
    such a map of the normals from the same map of the light (the degree-2 polynomials in N are closed under it),
    so the image alone cannot pin the frame: without E_recon-N (Eq. 8) a network may learn the face's shape in a
    rotated or mirrored frame and still reconstruct the image, held only by E_recon-L (Eq. 9) on its light.

    Returns ``mean`` (degrees, pixels pooled), ``angle`` (degrees: the rotation of Q, or of -Q, a rotation too,
    where Q mirrors) and ``det`` (+1: a rotation; -1: a mirror)."""
    m = _mask(mask, pred)[:, 0]
    if not m.any():
        raise ValueError("aligned_normal_error: the mask selects no pixel")
    p = F.normalize(pred.double(), dim=1, eps=1e-12).permute(0, 2, 3, 1)[m]  # [P, 3]
    t = F.normalize(target.double(), dim=1, eps=1e-12).permute(0, 2, 3, 1)[m]
    U, _, Vh = torch.linalg.svd(t.T @ p)
    Q = U @ Vh  # argmax_Q sum t . Q p over orthogonal Q
    det = torch.linalg.det(Q).sign().item()
    proper = Q * det
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (proper.trace().item() - 1.0) / 2.0))))
    err = angular_error_deg(torch.einsum("ij,bjhw->bihw", Q, pred.double()), target.double())[m]
    return {"mean": err.mean().item(), "angle": angle, "det": det}


def normals_collapsed(metrics: dict) -> bool:
    """Whether an evaluation's normals collapsed flat: its ``normal_spread`` under :data:`FLAT_SHARE` of its
    ``true_normal_spread`` (False where either was not measured)."""
    spread, truth = metrics.get("normal_spread"), metrics.get("true_normal_spread")
    return spread is not None and truth is not None and spread < FLAT_SHARE * truth


def frame_map(metrics: dict) -> str:
    """The best map of the normals' frame an evaluation measured, in words: ``"a rotation by 58 deg"``."""
    kind = "rotation" if metrics["normal_aligned_det"] > 0 else "mirror"
    return f"a {kind} by {metrics['normal_aligned_angle']:.0f} deg"


def normals_failure(metrics: dict) -> str | None:
    """How an evaluation's normals failed, or None: ``"flat"`` (:func:`normals_collapsed`), ``"frame"`` (farther
    from the truth than the dataset-mean map, ``trivial_normal_mean``, but nearer than it once one rotation or
    mirror of the whole frame is forgiven, ``normal_aligned_mean``: the face's shape learned in another frame) or
    ``"astray"`` (farther than the mean map, not flat, and no frame map explains it, or none was measured)."""
    if normals_collapsed(metrics):
        return "flat"
    error, floor = metrics.get("normal_mean"), metrics.get("trivial_normal_mean")
    if error is None or floor is None or error <= floor:
        return None
    aligned = metrics.get("normal_aligned_mean")
    return "frame" if aligned is not None and aligned < floor else "astray"


def _win_size(H: int, W: int) -> int:
    w = min(7, H, W)
    w -= (w + 1) % 2  # odd
    if w < 3:
        raise ValueError(f"SSIM needs images of at least 3x3 pixels, got {H}x{W}")
    return w


def reconstruction_metrics(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> dict:
    """MSE, PSNR (dB) and SSIM of images in [0, 1] (scikit-image, ``data_range=1``), averaged over images.

    With a mask, MSE and PSNR use the masked pixels only and SSIM is its full map averaged
    over the mask.  A perfect reconstruction has PSNR ``inf``.
    """
    _check_pair(pred, target)
    m = _mask(mask, pred)
    if not m.flatten(1).any(1).all():
        raise ValueError("reconstruction_metrics: the mask selects no pixel in some image")
    P = pred.detach().double().cpu().numpy()
    T = target.detach().double().cpu().numpy()
    M = m[:, 0].cpu().numpy()
    win = _win_size(*P.shape[2:])
    mse, psnr, ssim = [], [], []
    for p, t, mk in zip(P, T, M):  # per image; scikit-image works on one image at a time
        pm, tm = p[:, mk], t[:, mk]
        e = float(np.mean((pm - tm) ** 2))
        mse.append(e)
        psnr.append(math.inf if e == 0 else float(peak_signal_noise_ratio(tm, pm, data_range=1.0)))
        _, smap = structural_similarity(t, p, data_range=1.0, channel_axis=0, win_size=win, full=True)
        ssim.append(float(smap.mean(0)[mk].mean()))
    return {"mse": float(np.mean(mse)), "psnr": float(np.mean(psnr)), "ssim": float(np.mean(ssim))}


def optimal_scale(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor, dims) -> torch.Tensor:
    """argmin_s sum w (s pred - target)^2 = sum w pred target / sum w pred^2 over ``dims`` (0 if pred is 0)."""
    num = (weight * pred * target).sum(dims, keepdim=True)
    den = (weight * pred * pred).sum(dims, keepdim=True)
    return torch.where(den > 0, num / den.clamp_min(1e-300), torch.zeros_like(num))


def _aligned_error(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, per_image: bool = True, per_channel: bool = True
):
    """``(s * pred - target, weight)`` in float64, ``s`` the least-squares scale per image (``per_image``) or over the
    batch, and per channel (``per_channel``) or shared by the channels; ``weight [B,1,H,W]`` the mask as 0/1."""
    _check_pair(pred, target)
    w = _mask(mask, pred).double()
    if not (w.flatten(1).sum(1) > 0).all():
        raise ValueError("scale_invariant_mse: the mask selects no pixel in some image")
    p, t = pred.detach().double(), target.detach().double()
    dims = (() if per_image else (0,)) + (() if per_channel else (1,)) + (2, 3)
    s = optimal_scale(p, t, w, dims)  # [B or 1, C or 1, 1, 1]
    return s * p - t, w


def _masked_mean_square(e: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Per image: the mean of ``e^2`` over the masked pixels and the channels, ``[B]``."""
    return (w * e**2).sum((1, 2, 3)) / (w.sum((1, 2, 3)) * e.shape[1])


def scale_invariant_mse(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor,
    reduction: str = "mean",
    per_image: bool = True,
    per_channel: bool = True,
):
    """Scale-invariant MSE of albedo (or shading) maps ``[B,C,H,W]`` over the mask.

    Each image and channel of ``pred`` is multiplied by its least-squares optimal scale
    before the MSE over masked pixels and channels (``per_image=False``: one scale per channel
    for the whole batch, so an albedo that leaves each face's colour to the light is not forgiven;
    ``per_channel=False``: one scale for the three channels, so an albedo that leaves the face's colour to the
    shading is not forgiven either).  ``reduction="none"`` returns ``[B]``, ``"mean"`` their mean as a float.
    """
    return _reduce(_masked_mean_square(*_aligned_error(pred, target, mask, per_image, per_channel)), reduction)


def pattern_corr(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, reduction: str = "mean"):
    """Pearson's correlation of ``pred`` with ``target`` ``[B,C,H,W]`` over each image's masked pixels, per
    channel, averaged over the channels: how well the map's spatial pattern follows the truth's whatever its scale,
    offset and contrast (which a scale-invariant MSE forgives only in part: a flatter map scores better there).
    ``reduction="none"`` returns ``[B]``."""
    _check_pair(pred, target)
    w = _mask(mask, pred).to(pred.dtype)
    n = w.sum((2, 3)).clamp_min(1)
    p = pred - (pred * w).sum((2, 3), keepdim=True) / n[..., None, None]
    t = target - (target * w).sum((2, 3), keepdim=True) / n[..., None, None]
    cov = (p * t * w).sum((2, 3))
    den = ((p**2 * w).sum((2, 3)) * (t**2 * w).sum((2, 3))).sqrt().clamp_min(1e-12)
    return _reduce((cov / den).mean(1), reduction)


def light_shading_si_mse(
    sh: torch.Tensor, reference_sh: torch.Tensor, normal: torch.Tensor, mask: torch.Tensor, reduction: str = "mean"
):
    """The light as the face shows it: ``sh``'s shading through ``normal`` against ``reference_sh``'s (Eq. 4),
    :func:`scale_invariant_mse` inside ``mask``; blind to the SH directions the face's normals cannot reveal."""
    n = normal.detach().double()
    return scale_invariant_mse(sh_shading(n, sh.double()), sh_shading(n, reference_sh.double()), mask, reduction)


def log_shading_agreement(shading: torch.Tensor, reference: torch.Tensor, mask: torch.Tensor, floor: float = 1e-3):
    """How a shading ``[B,C,H,W]`` follows a ``reference`` shading inside ``mask``, on their log shadings (clamped at
    ``floor``), each centred over the mask per image and channel: ``dict`` of ``[B, C]`` tensors, ``corr``, their
    correlation (the pattern: 1 where the shading falls where the reference's does), ``ratio``, the ratio of their
    standard deviations (the magnitude of the contrast: 1 as contrasty as the reference, 0 flat), ``slope``, the
    least-squares slope of the shading's on the reference's, ``corr * ratio``, and ``error``, their squared
    difference as a share of the reference's spread, ``1 - 2 corr ratio + ratio^2`` (0: the same up to scale; the
    error an albedo ``I / S`` inherits, in log). Blind to each image's and channel's scale. Below the ``slope`` of 1
    a shading leaves part of the reference's to the albedo, by a pattern that differs (``corr``) or a contrast that
    is smaller (``ratio``). Where the pattern is imperfect, the least ``error`` needs ``ratio = corr``, not 1: an
    estimate that is right on average is flatter than its truth."""
    w = mask.double().expand_as(shading[:, :1])

    def centred_log(s):
        s = s.double().clamp_min(floor).log()
        return s - (s * w).sum((2, 3), keepdim=True) / w.sum((2, 3), keepdim=True).clamp_min(1e-12)

    s, t = centred_log(shading), centred_log(reference)
    st, ss, tt = ((a * b * w).sum((2, 3)) for a, b in ((s, t), (s, s), (t, t)))
    tt, ss = tt.clamp_min(1e-12), ss.clamp_min(1e-12)
    error = ((s - t).pow(2) * w).sum((2, 3)) / tt
    return {"corr": st / (ss * tt).sqrt(), "ratio": (ss / tt).sqrt(), "slope": st / tt, "error": error}


def shading_contrast(
    sh: torch.Tensor, reference_sh: torch.Tensor, normal: torch.Tensor, mask: torch.Tensor, floor: float = 1e-3
) -> dict:
    """:func:`log_shading_agreement` of the shading of the light ``sh`` with that of ``reference_sh``, both through
    ``normal`` (Eq. 4) inside ``mask``: ``slope`` is how much of the reference's shading contrast the light shows (1:
    as contrasty, at any scale; 0: flat), ``corr`` and ``ratio`` part it into pattern and magnitude."""
    n = normal.detach().double()
    return log_shading_agreement(sh_shading(n, sh.double()), sh_shading(n, reference_sh.double()), mask, floor)


BAND_SIGMA = 2.0  # px at 64x64: the coarse band keeps what varies over more than a few pixels (shading-like)


def masked_blur(x: torch.Tensor, weight: torch.Tensor, sigma: float) -> torch.Tensor:
    """Normalised Gaussian blur of ``x [B,C,H,W]`` inside ``weight [B,1,H,W]``: ``G*(w x) / G*w`` (separable,
    zero outside the image), so pixels outside the mask do not leak in and a constant stays that constant."""
    r = max(1, math.ceil(3 * sigma))
    t = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    g = torch.exp(-(t**2) / (2 * sigma**2))
    g = g / g.sum()

    def conv(z):
        C = z.shape[1]
        z = F.conv2d(F.pad(z, (r, r, 0, 0)), g.view(1, 1, 1, -1).expand(C, 1, 1, -1), groups=C)
        return F.conv2d(F.pad(z, (0, 0, r, r)), g.view(1, 1, -1, 1).expand(C, 1, -1, 1), groups=C)

    return conv(x * weight) / conv(weight).clamp_min(1e-12)


def scale_invariant_mse_bands(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, sigma: float = BAND_SIGMA
) -> dict:
    """:func:`scale_invariant_mse`'s error split by scale: ``coarse`` the mean square of its masked Gaussian blur
    (``sigma`` px, :func:`masked_blur`), ``fine`` of what the blur leaves (the detail), each normalised as the
    total is, mean over images.  The total is coarse + fine + twice their inner product."""
    e, w = _aligned_error(pred, target, mask)
    coarse = masked_blur(e, w, sigma)
    return {
        "coarse": _masked_mean_square(coarse, w).mean().item(),
        "fine": _masked_mean_square(e - coarse, w).mean().item(),
    }


def sh_error(pred_sh: torch.Tensor, true_sh: torch.Tensor, per_channel: bool = False, reduction: str = "mean"):
    """Relative squared error of SH coefficients ``[B,C,9]`` after the least-squares scale alignment.

    Per image: ``||s pred - true||^2 / ||true||^2`` with ``s`` the optimal scale, one per image
    (default) or per image and channel (``per_channel=True``).  0 is perfect; 1 is what a
    prediction orthogonal to the truth (or zero) scores, so the number is free of the light's
    overall brightness.  ``reduction="none"`` returns ``[B]``, ``"mean"`` a float, ``"coefficients"``
    the mean's share of each of the 9 coefficients (DC, y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2), a list
    that sums to the mean.
    """
    if pred_sh.shape != true_sh.shape or pred_sh.dim() != 3 or pred_sh.shape[-1] != 9:
        raise ValueError(f"SH must both be [B,C,9], got {tuple(pred_sh.shape)} and {tuple(true_sh.shape)}")
    p, t = pred_sh.detach().double(), true_sh.detach().double()
    s = optimal_scale(p, t, torch.ones_like(p), (2,) if per_channel else (1, 2))
    share = ((s * p - t) ** 2).sum(1) / t.pow(2).sum((1, 2)).clamp_min(1e-300)[:, None]  # [B, 9]
    if reduction == "coefficients":
        return share.mean(0).tolist()
    return _reduce(share.sum(1), reduction)


def sh_gram(normal: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``[B,9,9]``: per image, ``G = mean over the mask of Y(n) Y(n)^T`` (Eq. 4's basis at ``normal [B,3,H,W]``):
    the shading energy ``L^T G L`` a light ``L`` makes over the face.  Its eigenvalues span orders of magnitude, as
    a face's normals cover part of the sphere."""
    from disent.render import sh_basis

    Y = sh_basis(normal.detach().double(), 1)  # [B, 9, H, W]
    w = (mask > 0.5).double()
    return torch.einsum("nkhw,nlhw->nkl", Y * w, Y) / w.sum((1, 2, 3)).clamp_min(1)[:, None, None]


def scale_in_shading(pred_sh: torch.Tensor, true_sh: torch.Tensor, gram: torch.Tensor) -> torch.Tensor:
    """``s pred_sh`` with ``s`` per image and channel where the scale can be seen, in shading:
    ``argmin_s (s p - t)^T G (s p - t)`` (``gram``: :func:`sh_gram`)."""
    p, t = pred_sh.detach().double(), true_sh.detach().double()
    s = torch.einsum("nck,nkl,ncl->nc", p, gram, t) / torch.einsum("nck,nkl,ncl->nc", p, gram, p).clamp_min(1e-300)
    return s[..., None] * p


def hidden_directions(gram: torch.Tensor, fraction: float = 0.01) -> tuple:
    """``(vectors [B,9,9], hidden [B,1,9])``: ``gram``'s eigenvectors (columns) and which are *hidden*, eigenvalue
    below ``fraction`` of the largest: SH directions whose shading over the face no image of it can pin down."""
    values, vectors = torch.linalg.eigh(gram)  # ascending, per image
    return vectors, (values < fraction * values[:, -1:])[:, None, :]


def shown_hidden_energy(x: torch.Tensor, gram: torch.Tensor, fraction: float = 0.01) -> tuple:
    """``(shown [B], hidden [B])``: the squared norm of SH vectors ``x [B,C,9]`` (summed over channels) split over
    ``gram``'s eigenvectors into the hidden directions (:func:`hidden_directions`) and the *shown* rest."""
    vectors, hidden = hidden_directions(gram, fraction)
    energy = torch.einsum("nck,nkj->ncj", x, vectors) ** 2
    return (energy * ~hidden).sum((1, 2)), (energy * hidden).sum((1, 2))


def completed_sh(sh: torch.Tensor, prior: torch.Tensor, gram: torch.Tensor, fraction: float = 0.01) -> torch.Tensor:
    """The light a face shows, completed by a prior where it hides: ``sh [B,C,9]`` along the directions ``gram``
    (:func:`sh_gram` at the estimator's *own* normals and mask) shows, ``prior [C,9]`` (or ``[B,C,9]``, e.g. the
    mean train light) along those it hides (:func:`hidden_directions`), the prior scaled per image and channel to
    ``sh`` over the shown directions.  An image says nothing of the hidden part, so an estimator that fills it from
    the prior models no more of the light than the face reveals."""
    s, g = sh.detach().double(), gram.double()
    vectors, hidden = hidden_directions(g, fraction)
    own = torch.einsum("nck,nkj->ncj", s, vectors)
    pri = torch.einsum("nck,nkj->ncj", prior.detach().double().expand_as(s), vectors)
    scale = (own * pri * ~hidden).sum(2, keepdim=True) / (pri.pow(2) * ~hidden).sum(2, keepdim=True).clamp_min(1e-300)
    return torch.einsum("ncj,nkj->nck", torch.where(hidden, scale * pri, own), vectors).to(sh.dtype)


def sh_error_shown_hidden(
    pred_sh: torch.Tensor, true_sh: torch.Tensor, normal: torch.Tensor, mask: torch.Tensor, fraction: float = 0.01
) -> dict:
    """The SH error split by what the face shows: ``{"shown", "hidden"}``, each a share of ``||true||^2``.

    ``pred_sh [B,C,9]`` is scaled per image and channel in shading (:func:`scale_in_shading`); its error
    ``e = s p - t`` splits over the face's SH directions (:func:`shown_hidden_energy` of :func:`sh_gram` at the
    true ``normal``) into the hidden and the shown part (``shown + hidden`` is ``||e||^2 / ||t||^2``)."""
    return sh_error_split(pred_sh, true_sh, sh_gram(normal, mask), fraction)


def sh_error_split(pred_sh: torch.Tensor, true_sh: torch.Tensor, gram: torch.Tensor, fraction: float = 0.01) -> dict:
    """:func:`sh_error_shown_hidden` with each face's ``gram [B,9,9]`` (:func:`sh_gram`) given."""
    t = true_sh.detach().double()
    shown, hidden = shown_hidden_energy(scale_in_shading(pred_sh, t, gram) - t, gram, fraction)
    norm = t.pow(2).sum((1, 2))
    return {"shown": (shown / norm).mean().item(), "hidden": (hidden / norm).mean().item()}


def mask_iou(pred: torch.Tensor, target: torch.Tensor, threshold: float = 0.5) -> float:
    """Intersection over union of two masks ``[B,1,H,W]``, each cut at ``threshold``, pooled over the batch (the
    intersections' sum over the unions' sum: a face is weighted by its size); 1 where both are empty."""
    _check_pair(pred, target, 1)
    p, t = pred > threshold, target > threshold
    union = (p | t).sum().item()
    return (p & t).sum().item() / union if union else 1.0


def region_depth(mask: torch.Tensor, max_depth: int) -> torch.Tensor:
    """Each pixel's depth inside ``mask [B,1,H,W]`` (cut at 0.5): 1 on the pixels that touch its outside
    (8-neighbours or the image border), 2 on the next ring, and so on up to ``max_depth``; 0 outside (chessboard
    distance, by repeated 3x3 erosion)."""
    inside = (mask > 0.5).to(torch.float32)
    depth = torch.zeros_like(inside)
    for _ in range(max_depth):
        depth += inside
        inside = -F.max_pool2d(-F.pad(inside, (1, 1, 1, 1)), 3, 1)  # outside the image counts as outside the region
    return depth


def _reduce(per_image: torch.Tensor, reduction: str):
    if reduction == "none":
        return per_image
    if reduction == "mean":
        return per_image.mean().item()
    raise ValueError(f"reduction must be 'mean' or 'none', got {reduction!r}")


__all__ = [
    "angular_error_deg",
    "normal_angular_error",
    "normal_spread",
    "normals_collapsed",
    "aligned_normal_error",
    "normals_failure",
    "frame_map",
    "FLAT_SHARE",
    "reconstruction_metrics",
    "scale_invariant_mse",
    "light_shading_si_mse",
    "mask_iou",
    "sh_error",
    "sh_error_shown_hidden",
    "sh_error_split",
    "sh_gram",
    "scale_in_shading",
    "shown_hidden_energy",
    "hidden_directions",
    "completed_sh",
    "optimal_scale",
    "ANGLE_THRESHOLDS",
]

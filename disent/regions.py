"""Where a face's layers are scored: the face mask of a soft matte, and the region the intrinsic layers are scored
on.  A leaf: the losses, the metrics and the studies all read it."""

from __future__ import annotations

import torch

FACE_THRESHOLD = 0.99  # matte above this is face without background mixing


def face_mask(matte: torch.Tensor, threshold: float = FACE_THRESHOLD) -> torch.Tensor:
    """Binary face mask ``[B,1,H,W]`` from a soft matte: antialiased border pixels mix in background."""
    return (matte > threshold).to(matte.dtype)


def decomposed_region(gt: dict) -> torch.Tensor:
    """Where the intrinsic layers are scored: the true face mask intersected with the pseudo mask M-hat.
    The model renders the face there; its matte is trained towards M-hat (Sec. 3.3), so hair, ears and
    neck belong to its background layer, and its albedo there is not an estimate of anything."""
    return face_mask(gt["matte"]) * (gt["mask_pseudo"] > 0.5)

"""Relighting and lighting transfer (Sec. 5.3).

* **Relight by code**: replace the target's ``Z_L`` (the SH light, ``[B,3,9]`` reshaped) with
  another image's, a named light of ``disent.data.LIGHT_BANK``, or distant lights given by
  direction and intensity, and decode.  Loses the details the bottleneck cannot carry.
* **Transfer with detailed albedo** (the paper's method): ``A_target = I_target / S_target``
  (Eq. 2 solved for the albedo, so it keeps every detail of the input),
  ``S_transfer = sh_shading(N_target, L_source)`` (Eq. 4), and
  ``I = composite(M_target, A_target * S_transfer, I_target)`` (Eq. 6): the face is relit, the
  target's own pixels stay outside the matte.
* **Naive ratio relighting** (the baseline): the whole image times ``S_transfer / S_target``,
  no matte, so background and hair are "relit" with whatever normals the network put there.

Where the target shading is small (``S < eps``: shadow, or the negative lobe of an SH fit) the
division is not trusted: the detailed albedo falls back to a given albedo (the network's own
estimate) and the ratio to 1, so neither can produce NaN or Inf.
"""

from __future__ import annotations

import torch

from disent.render import (
    SHADING_EPS,
    check_finite,
    composite,
    detailed_albedo,
    image_formation,
    sh_from_directions,
    sh_shading,
)


# ----------------------------------------------------------------------------- lights
def named_light(name: str) -> torch.Tensor:
    """A light of the light bank by name, ``[1,3,9]``."""
    from disent.data import LIGHT_BANK

    if name not in LIGHT_BANK:
        raise ValueError(f"unknown light {name!r}; the bank has {sorted(LIGHT_BANK)}")
    return torch.as_tensor(LIGHT_BANK[name], dtype=torch.float32).reshape(1, 3, 9)


def directional_light(direction, intensity=1.0, ambient=0.0) -> torch.Tensor:
    """One distant white light (``direction`` in the camera frame, +z towards the camera), ``[1,3,9]``.

    ``intensity`` and ``ambient`` are scalars or RGB triples.
    """
    d = torch.as_tensor(direction, dtype=torch.float32).reshape(1, 1, 3)
    if d.norm() == 0:
        raise ValueError("light direction must be non-zero")
    i = torch.as_tensor(intensity, dtype=torch.float32).expand(3).reshape(1, 1, 3)
    a = torch.as_tensor(ambient, dtype=torch.float32).expand(3).reshape(1, 3)
    return sh_from_directions(d, i, a)


def with_light(codes: dict, sh: torch.Tensor) -> dict:
    """Codes with ``Z_L`` replaced by the SH light ``sh`` (``[3,9]``, ``[1,3,9]`` or ``[B,3,9]``)."""
    if "L" not in codes:
        raise ValueError(
            f"these codes have no lighting code Z_L (got {sorted(codes)}); relighting needs "
            "the explicit or implicit model"
        )
    L = codes["L"]
    B = L.shape[0]
    sh = torch.as_tensor(sh, dtype=L.dtype, device=L.device).reshape(-1, 27)
    if sh.shape[0] not in (1, B):
        raise ValueError(f"need 1 or {B} lights, got {sh.shape[0]}")
    return {**codes, "L": sh.expand(B, 27).reshape(L.shape).clone()}


# ----------------------------------------------------------------------------- transfer
def transfer_lighting(
    image: torch.Tensor,
    normal: torch.Tensor,
    shading: torch.Tensor,
    matte: torch.Tensor,
    sh_source: torch.Tensor,
    albedo: torch.Tensor | None = None,
    eps: float = SHADING_EPS,
) -> torch.Tensor:
    """Lighting transfer with detailed albedo (Sec. 5.3): the target ``image`` under ``sh_source``.

    ``normal``, ``shading``, ``matte`` (and the fallback ``albedo``) are the target's intrinsic
    estimates; ``sh_source [B or 1, C, 9]`` the source light.
    """
    A = detailed_albedo(image, shading, albedo, eps)
    sh_source = sh_source.to(normal.dtype).expand(normal.shape[0], -1, -1)
    S_transfer = sh_shading(normal, sh_source)
    return composite(matte, image_formation(A, S_transfer), image)


def ratio_relight(
    image: torch.Tensor,
    normal: torch.Tensor,
    sh_target: torch.Tensor,
    sh_source: torch.Tensor,
    eps: float = SHADING_EPS,
) -> torch.Tensor:
    """The naive baseline: every pixel times ``S(N, L_source) / S(N, L_target)`` (1 where ``S_target < eps``)."""
    check_finite("image", image)
    B = normal.shape[0]
    S_t = sh_shading(normal, sh_target.to(normal.dtype).expand(B, -1, -1))
    S_s = sh_shading(normal, sh_source.to(normal.dtype).expand(B, -1, -1))
    ok = S_t >= eps
    ratio = torch.where(ok, S_s / torch.where(ok, S_t, torch.ones_like(S_t)), torch.ones_like(S_t))
    return image * ratio


# ----------------------------------------------------------------------------- with a model
@torch.no_grad()
def relight(
    model, image: torch.Tensor, sh_source: torch.Tensor, method: str = "transfer", eps: float = SHADING_EPS
) -> torch.Tensor:
    """``image`` relit under ``sh_source`` with a trained model's estimates.

    ``method``: ``"transfer"`` (detailed albedo), ``"ratio"`` (naive whole-image) or ``"decode"``
    (replace ``Z_L`` and decode).
    """
    out = model(image)
    if "sh" not in out:
        raise ValueError("relighting needs a model with a lighting code (explicit or implicit)")
    sh_source = torch.as_tensor(sh_source, dtype=image.dtype).reshape(-1, 3, 9)
    if method == "transfer":
        return transfer_lighting(image, out["normal"], out["shading"], out["matte"], sh_source, out["albedo"], eps)
    if method == "ratio":
        return ratio_relight(image, out["normal"], out["sh"], sh_source, eps)
    if method == "decode":
        return model.decode(with_light(out["codes"], sh_source))["recon"]
    raise ValueError(f"method must be 'transfer', 'ratio' or 'decode', got {method!r}")

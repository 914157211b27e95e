"""Tensors as pictures: one place for how a layer is shown and saved.

A map ``[C,H,W]`` (``C`` = 1, 2 or 3) is shown as an ``[H,W,3]`` array in [0,1]: a one-channel map (matte,
grey shading) is repeated over RGB, a UV map shows u red and v green, a normal map goes from [-1,1] to [0,1]
with its zero vectors (pixels no model claims) left black, and everything is clipped to [0,1].  Shading under
BWS has mean 0.75 and peaks above 1: :func:`over_max` divides it by each image's maximum before it is shown.

Photos are stored sRGB-encoded; the paper's image model (I = A * S, Eq. 2) and SynthFaces are linear in
radiance.  :func:`srgb_to_linear` decodes a photo's pixels before any model or fit sees them, and
:func:`linear_to_srgb` encodes linear pixels where they leave as a photo (files written for a user's photos,
renders handed to the landmark detector).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch


def display(x: torch.Tensor, kind: str = "rgb") -> torch.Tensor:
    """``[C,H,W]`` (or ``[B,C,H,W]``) -> the same with 3 channels in [0,1]; ``kind="normal"`` maps [-1,1] to [0,1],
    ``kind="srgb"`` encodes linear radiance as a photo is stored (:func:`linear_to_srgb`)."""
    x = x.detach().float().cpu()
    if kind == "srgb":
        x = linear_to_srgb(x.clamp(0, 1))
    if kind == "normal":
        x = torch.where(x.abs().sum(-3, keepdim=True) > 0, 0.5 * x + 0.5, torch.zeros_like(x))
    if x.shape[-3] == 1:
        x = x.expand(*x.shape[:-3], 3, *x.shape[-2:])
    elif x.shape[-3] == 2:  # a UV map: u red, v green
        x = torch.cat([x, torch.zeros_like(x[..., :1, :, :])], -3)
    return x[..., :3, :, :].clamp(0, 1)


def srgb_to_linear(x):
    """sRGB-encoded values in [0, 1] -> linear radiance (IEC 61966-2-1), for a tensor or an array."""
    lib = torch if torch.is_tensor(x) else np
    return lib.where(x <= 0.04045, x / 12.92, ((lib.clip(x, 0.04045, None) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x):
    """Linear radiance in [0, 1] -> sRGB-encoded values, the inverse of :func:`srgb_to_linear`."""
    lib = torch if torch.is_tensor(x) else np
    return lib.where(x <= 0.0031308, 12.92 * x, 1.055 * lib.clip(x, 0.0031308, None) ** (1 / 2.4) - 0.055)


def to_array(x: torch.Tensor, kind: str = "rgb") -> np.ndarray:
    """``[C,H,W]`` -> ``[H,W,3]`` float array in [0,1], for matplotlib's ``imshow``."""
    return display(x, kind).permute(1, 2, 0).numpy()


def to_uint8(x: torch.Tensor | np.ndarray, kind: str = "rgb") -> np.ndarray:
    """``[C,H,W]`` tensor (or an ``[H,W,3]`` array in [0,1]) -> ``[H,W,3]`` uint8, rounded."""
    arr = to_array(x, kind) if torch.is_tensor(x) else np.clip(x, 0, 1)
    return (arr * 255).round().astype(np.uint8)


def save_image(x: torch.Tensor | np.ndarray, path, kind: str = "rgb") -> None:
    """Write a map (or an ``[H,W,3]`` uint8 / [0,1] array) as a PNG, creating its folder."""
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(x if isinstance(x, np.ndarray) and x.dtype == np.uint8 else to_uint8(x, kind)).save(path)


def over_max(shading: torch.Tensor) -> torch.Tensor:
    """Shading ``[(B,)C,H,W]`` divided by each image's maximum, for display."""
    return shading / shading.amax((-3, -2, -1), keepdim=True).clamp_min(1e-6)


FACE_LAYERS = ("albedo", "normal", "shading")  # the layers the rendered face is made of (Eqs. 2-4)


def on_matte(out: dict, key: str, threshold: float = 0.5) -> torch.Tensor:
    """``out[key]``; a face layer (:data:`FACE_LAYERS`) black where the model's own matte is at or under
    ``threshold``, where the composite (Eq. 6) shows the background instead. Other layers, and models without a
    matte, as they are."""
    x = out[key]
    return x * (out["matte"] > threshold) if key in FACE_LAYERS and "matte" in out else x


def strip(images: list[torch.Tensor], pad: int = 2, kind: str = "rgb") -> torch.Tensor:
    """Maps ``[3,H,W]`` side by side with a white gap of ``pad`` pixels, each shown as ``kind`` (:func:`display`)."""
    gap = torch.ones(3, images[0].shape[1], pad)
    return torch.cat([t for im in images for t in (display(im, kind), gap)][:-1], 2)


def sample_grid(batch: dict, out: dict, columns, n: int = 8) -> np.ndarray:
    """uint8 ``[n*H, k*W, 3]``: one row per image, one column per name in ``columns`` that the model has
    (``image`` from the batch, the rest from its output)."""
    cols = [
        display((batch if name == "image" else out)[name][:n], "normal" if name == "normal" else "rgb")
        for name in columns
        if name == "image" or out.get(name) is not None
    ]
    grid = torch.cat([torch.cat(list(c), 1) for c in cols], 2)  # [3, n*H, k*W]
    return to_uint8(grid.permute(1, 2, 0).numpy())


def pyplot():
    """matplotlib's pyplot on the Agg backend (files only, no screen): every figure of the suite is drawn so."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path, **kwargs) -> None:
    """Save ``fig`` as a PNG without the timestamp and version matplotlib writes (a rebuild gives the same bytes
    for the same pixels), and close it."""
    fig.savefig(path, metadata={"Software": None}, **kwargs)
    pyplot().close(fig)


def wrapped(text: str, width: int) -> str:
    """``text`` in lines of at most ``width`` characters where it can, broken only after a space, ``_``, ``-`` or
    ``.`` (a run folder's or a setting's name stays whole between those)."""
    lines = [""]
    for piece in re.split(r"(?<=[ _.\-])", text):
        if lines[-1] and len(lines[-1].rstrip()) + len(piece.rstrip()) > width:
            lines.append("")
        lines[-1] += piece
    return "\n".join(line.rstrip() for line in lines)


def image_grid(
    sets: list[tuple[str, torch.Tensor]],
    path: Path,
    title: str | None = None,
    columns: bool = False,
    scale: float = 1.2,
    dpi: int = 110,
) -> None:
    """Named ``[N,C,H,W]`` image sets as a grid: one row per set with its name on the left, or (``columns``) one
    column per set with its name on top, the paper's figure layout; a set named ``normal...`` is shown as normals.
    ``title`` is wrapped to the figure's width; ``scale``: inches per image."""
    plt = pyplot()
    n, k = sets[0][1].shape[0], len(sets)
    shape, size = ((n, k), (scale * k, scale * n + 0.4)) if columns else ((k, n), (scale * n + 1, scale * k))
    fig, axes = plt.subplots(*shape, figsize=size, squeeze=False)
    for s, (name, images) in enumerate(sets):
        for i in range(n):
            ax = axes[i, s] if columns else axes[s, i]
            ax.imshow(to_array(images[i], "normal" if name.startswith("normal") else "rgb"), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                (ax.set_title if columns else ax.set_ylabel)(name, fontsize=7)
    if title:
        fig.suptitle(wrapped(title, int(size[0] * 15)), fontsize=8)  # about 15 characters an inch at 8 pt
    fig.tight_layout(pad=0.2 if columns else 1.08)
    save_figure(fig, path, dpi=dpi)

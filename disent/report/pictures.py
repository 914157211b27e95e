"""Pictures from models: the runs' or shipped models, a test batch, image grids."""

from __future__ import annotations

import re
from pathlib import Path

import torch

from disent.images import to_array
from disent.report.document import pyplot, save_figure


def image_grid(rows: list[tuple[str, torch.Tensor]], path: Path, title: str) -> None:
    """One row per named ``[N,C,H,W]`` tensor, N columns; the title wrapped to the figure's width."""
    plt = pyplot()
    n = rows[0][1].shape[0]
    width = 1.2 * n + 1  # inches
    fig, axes = plt.subplots(len(rows), n, figsize=(width, 1.2 * len(rows)), squeeze=False)
    for i, (name, t) in enumerate(rows):
        for j in range(n):
            ax = axes[i, j]
            ax.imshow(to_array(t[j], "normal" if name.startswith("normal") else "rgb"), interpolation="nearest")
            ax.set_xticks([]), ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle(wrapped(title, int(width * 15)), fontsize=8)  # about 15 characters an inch at 8 pt
    fig.tight_layout()
    save_figure(fig, path, dpi=110)


def test_batch(n: int, resolution: int = 64):
    from disent.data import SynthFaces
    from disent.eval.scoring import batches

    return next(iter(batches(SynthFaces(split="test", resolution=resolution, seed=0), n, n)))


def wrapped(text: str, width: int) -> str:
    """``text`` in lines of at most ``width`` characters where it can, broken only after a space, ``_``, ``-`` or
    ``.`` (a run folder's or a setting's name stays whole between those)."""
    lines = [""]
    for piece in re.split(r"(?<=[ _.\-])", text):
        if lines[-1] and len(lines[-1].rstrip()) + len(piece.rstrip()) > width:
            lines.append("")
        lines[-1] += piece
    return "\n".join(line.rstrip() for line in lines)

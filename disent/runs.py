"""What a training run writes into its folder (Hydra's ``outputs/<date>/<time>/``).

``git.txt`` (revision and dirty files), ``metrics.jsonl`` (one JSON record per line),
``checkpoints/last.pt`` (written atomically: a temp file, then ``os.replace``),
``samples/*.png`` (grids: input, recon, albedo, normal, shading, matte) and ``eval.json``.
Readers of finished runs are in :mod:`disent.eval.runs`.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path

import numpy as np
import torch

SAMPLE_COLUMNS = ("image", "recon", "albedo", "normal", "shading", "matte")


def write_git_revision(run_dir: Path) -> None:
    """``git.txt``: ``git rev-parse HEAD`` and ``git status --porcelain`` of the source tree."""
    src = Path(__file__).resolve().parent

    def git(*args):
        try:
            return subprocess.run(["git", *args], cwd=src, capture_output=True, text=True, timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return ""

    rev = git("rev-parse", "HEAD") or "unknown (not a git checkout)"
    dirty = git("status", "--porcelain", "--untracked-files=no")
    text = f"revision: {rev}\n" + (f"uncommitted changes:\n{dirty}\n" if dirty else "clean\n")
    (run_dir / "git.txt").write_text(text)


class MetricsLog:
    """Append-only ``metrics.jsonl``; each record is flushed at once, so a killed run keeps its log."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def write(self, record: dict) -> None:
        clean = {k: (float(v) if isinstance(v, (float, np.floating)) or torch.is_tensor(v) else v)
                 for k, v in record.items()}
        clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in clean.items()}
        with self.path.open("a") as f:
            f.write(json.dumps(clean) + "\n")

    def truncate_after(self, step: int) -> None:
        """Drop records past ``step`` and earlier evaluations (a resumed run rewrites them exactly)."""
        if self.path.exists():
            recs = [json.loads(l) for l in self.path.read_text().splitlines() if l.strip()]
            keep = [json.dumps(r) for r in recs if r.get("step", 0) <= step and "eval" not in r]
            atomic_write(self.path, lambda f: f.write("".join(l + "\n" for l in keep).encode()))


def atomic_write(path, write) -> None:
    """Write ``path`` through ``write(binary_file)`` into a temp file beside it, then rename it into place:
    a crash mid-write leaves the previous file intact (per-process temp name: workers may race)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
    with tmp.open("wb") as f:
        write(f)
    os.replace(tmp, path)


def save_checkpoint(path: Path, state: dict) -> None:
    """Atomic ``torch.save``: a crash mid-write leaves the previous checkpoint intact."""
    atomic_write(path, lambda f: torch.save(state, f))


def load_checkpoint(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=False)


def rng_state() -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None}


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    if state.get("cuda") is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _tile(x: torch.Tensor) -> torch.Tensor:
    """``[B,C,H,W]`` -> 3-channel ``[B,3,H,W]`` in [0,1] for display."""
    x = x.detach().float().cpu()
    return x.expand(-1, 3, -1, -1).clamp(0, 1) if x.shape[1] == 1 else x[:, :3].clamp(0, 1)


def sample_grid(batch: dict, out: dict, n: int = 8) -> np.ndarray:
    """uint8 ``[n*H, k*W, 3]``: one row per image; columns those of SAMPLE_COLUMNS the model has."""
    cols = []
    for name in SAMPLE_COLUMNS:
        x = batch["image"] if name == "image" else out.get(name)
        if x is None:
            continue
        x = x[:n]
        if name == "normal":
            x = x * 0.5 + 0.5  # [-1,1] -> [0,1]
        cols.append(_tile(x))
    grid = torch.cat([torch.cat(list(c), 1) for c in cols], 2)  # [3, n*H, k*W]
    return (grid.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)


def save_samples(path: Path, batch: dict, out: dict, n: int = 8) -> None:
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sample_grid(batch, out, n)).save(path)

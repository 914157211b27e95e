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
import shutil
import subprocess
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

SAMPLE_COLUMNS = ("image", "recon", "albedo", "normal", "shading", "matte")

# ${pid:} in conf/config.yaml's hydra.run.dir / hydra.sweep.dir: two runs started in the same second
# get different folders
OmegaConf.register_new_resolver("pid", os.getpid, replace=True, use_cache=True)  # cached: jobs in worker processes reuse it


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


def previous_checkpoint(path: Path) -> Path:
    """Where :func:`save_checkpoint` keeps the checkpoint it replaced (``last.pt`` -> ``prev.pt``)."""
    path = Path(path)
    return path.with_name("prev.pt") if path.name == "last.pt" else path.with_name(path.stem + ".prev" + path.suffix)


def save_checkpoint(path: Path, state: dict) -> None:
    """Atomic ``torch.save``, keeping the checkpoint it replaces as :func:`previous_checkpoint`: a crash
    mid-write leaves the previous file intact, and a file damaged later still leaves one good copy."""
    path = Path(path)
    if path.exists():  # last.pt stays in place throughout; prev.pt becomes a second name for it
        prev = previous_checkpoint(path)
        tmp = prev.with_name(f"{prev.name}.tmp{os.getpid()}")
        tmp.unlink(missing_ok=True)
        try:
            os.link(path, tmp)
        except OSError:  # a file system without hard links
            shutil.copyfile(path, tmp)
        os.replace(tmp, prev)

    def write(f):
        torch.save(state, f)
        f.flush()
        os.fsync(f.fileno())

    atomic_write(path, write)


class CheckpointError(RuntimeError):
    """A checkpoint file that cannot be read, named with what to do."""


def load_checkpoint(path: Path, fallback: bool = False) -> dict:
    """``torch.load`` on the CPU.  A damaged file raises :class:`CheckpointError` naming it; with
    ``fallback`` the previous checkpoint (:func:`previous_checkpoint`) is loaded instead, the damaged file
    is set aside as ``*.damaged`` (so that the next save cannot rotate it in), and ``loaded_from`` says so."""
    path = Path(path)
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except FileNotFoundError:
        raise CheckpointError(f"no checkpoint at {path}") from None
    except Exception as err:  # truncated zip, not a torch file, ...
        why = f"{type(err).__name__}: {str(err).split('. ')[0]}"
        prev = previous_checkpoint(path)
        if fallback and prev.exists():
            state = load_checkpoint(prev)
            os.replace(path, path.with_name(path.name + ".damaged"))
            print(f"warning: {path} cannot be read ({why}); set aside as {path.name}.damaged, continuing from "
                  f"the previous checkpoint {prev} (step {state.get('step', '?')})")
            return {**state, "loaded_from": str(prev)}
        hint = f"; the previous checkpoint is {prev}" if prev.exists() else ""
        raise CheckpointError(f"the checkpoint {path} cannot be read ({why}){hint}") from None


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


class RunFolderBusy(RuntimeError):
    """Another live process holds the run folder."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def lock_holder(run_dir) -> int | None:
    """PID of the live process holding ``run_dir`` (its ``.lock``), or None."""
    try:
        pid = int((Path(run_dir) / ".lock").read_text().strip() or 0)
    except (OSError, ValueError):
        return None
    return pid if pid and pid != os.getpid() and _alive(pid) else None


class RunLock:
    """``run_dir/.lock`` holds the PID of the one process writing the folder.

    Taken with ``O_EXCL``; a lock left by a dead process is taken over; a live holder makes
    :meth:`acquire` raise :class:`RunFolderBusy`, before anything in the folder is written."""

    def __init__(self, run_dir: Path):
        self.path = Path(run_dir) / ".lock"

    def acquire(self) -> "RunLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                holder = lock_holder(self.path.parent)
                if holder is not None:
                    raise RunFolderBusy(f"the run folder {self.path.parent} is in use by process {holder}; "
                                        "give this run its own folder (hydra.run.dir=...)") from None
                self.path.unlink(missing_ok=True)  # stale: its process is gone
                continue
            with os.fdopen(fd, "w") as f:
                f.write(str(os.getpid()))
            return self
        raise RunFolderBusy(f"could not take {self.path}: another process keeps creating it")

    def release(self) -> None:
        try:
            if int(self.path.read_text().strip() or 0) == os.getpid():
                self.path.unlink()
        except (OSError, ValueError):
            pass

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()

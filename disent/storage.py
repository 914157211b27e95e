"""What a run writes into its folder and reads back, below the training loop: atomic writes, checkpoints and their
RNG state, the folder's lock, the metrics log (``metrics.jsonl`` and TensorBoard events), the git revision and the
machine a run trained on, and the JSON and YAML readers that never raise.

Written: ``git.txt`` (revision and dirty files), ``machine.json``, ``metrics.jsonl`` (one JSON record per line),
``checkpoints/last.pt`` (written atomically: a temp file, then ``os.replace``; the one before it kept as
``prev.pt``), ``samples/*.png`` (grids: input, recon, albedo, normal, shading, matte).  A running job holds
``.lock`` (:class:`RunLock`).  Finding, reading and labelling finished runs is :mod:`disent.runs`.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np
import torch
import yaml
from omegaconf import OmegaConf

SAMPLE_COLUMNS = ("image", "recon", "albedo", "normal", "shading", "matte")

# ${pid:} in conf/config.yaml's hydra.run.dir / hydra.sweep.dir: two runs started in the same second
# get different folders
OmegaConf.register_new_resolver(
    "pid", os.getpid, replace=True, use_cache=True
)  # cached: jobs in worker processes reuse it


def _git(*args) -> str:
    """``git ARGS`` in the source tree's folder, its output stripped; "" where git or the checkout is missing."""
    try:
        src = Path(__file__).resolve().parent
        return subprocess.run(["git", *args], cwd=src, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def head_revision() -> str | None:
    """``git rev-parse HEAD`` of the source tree, None outside a git checkout."""
    return _git("rev-parse", "HEAD") or None


GIT_LINE, NO_REVISION = "revision: ", "unknown (not a git checkout)"  # git.txt's first line: GIT_LINE + revision


def git_revision() -> str:
    """:func:`head_revision` and ``git status --porcelain`` of the source tree, as ``git.txt`` holds them."""
    rev = head_revision() or NO_REVISION
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return f"{GIT_LINE}{rev}\n" + (f"uncommitted changes:\n{dirty}\n" if dirty else "clean\n")


def write_git_revision(run_dir: Path) -> None:
    """``git.txt``: :func:`git_revision`."""
    (run_dir / "git.txt").write_text(git_revision())


def cpu_name() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info(device="cpu", threads=None) -> dict:
    """What a number was measured on: system, processor, CPU count, torch, numpy and scipy builds, device (with the
    GPU's name)."""
    import platform

    import numpy
    import scipy
    import torch

    info = {
        "system": platform.platform(),
        "processor": cpu_name(),
        "cpus": os.cpu_count(),
        "torch": torch.__version__,
        "numpy": numpy.__version__,
        "scipy": scipy.__version__,
        "device": str(device),
        "threads": threads,
    }
    if str(device).startswith("cuda") and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(torch.device(str(device)))
    return info


def machine_text(info: dict | None) -> str:
    """One line of :func:`machine_info` for a caption."""
    if not info:
        return "not recorded"
    where = info.get("gpu") or f"{info.get('processor')}, {info.get('cpus')} CPUs"
    return f"{where}, torch {info.get('torch')}, device {info.get('device')}, {info.get('threads')} thread(s)"


class MetricsLog:
    """Append-only ``metrics.jsonl``; each record is flushed at once, so a killed run keeps its log.  With
    ``events`` (a folder) each record also goes to TensorBoard event files there (:class:`TensorBoardLog`), so that
    ``tensorboard --logdir outputs`` shows runs as they train; ``metrics.jsonl`` stays the record the report reads."""

    def __init__(self, path: Path, events: Path | None = None):
        self.path = Path(path)
        self.events = TensorBoardLog(events) if events is not None else None

    def write(self, record: dict) -> None:
        clean = {
            k: (float(v) if isinstance(v, (float, np.floating)) or torch.is_tensor(v) else v) for k, v in record.items()
        }
        clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in clean.items()}
        with self.path.open("a") as f:
            f.write(json.dumps(clean) + "\n")
        if self.events is not None:
            self.events.write(clean)

    def truncate_after(self, step: int) -> None:
        """Drop records past ``step`` and earlier evaluations (a resumed run rewrites them exactly); the event files
        drop theirs past ``step`` too."""
        if self.path.exists():
            recs = [json.loads(l) for l in self.path.read_text().splitlines() if l.strip()]
            keep = [json.dumps(r) for r in recs if r.get("step", 0) <= step and "eval" not in r]
            atomic_write(self.path, lambda f: f.write("".join(l + "\n" for l in keep).encode()))
        if self.events is not None:
            self.events.purge_step = step + 1  # the steps after the checkpoint are trained again

    def close(self) -> None:
        if self.events is not None:
            self.events.close()


class TensorBoardLog:
    """The training log as TensorBoard scalars (``torch.utils.tensorboard``): each loss term under ``loss/``, the
    speed and learning rate, each validation metric under ``val/`` with its trivial baseline (``trivial/``) and the
    pseudo-GT's (``pseudo/``) drawn on one chart beside it, and the final test metrics under ``eval/``.  The writer
    opens at the first record (a resumed run purges the steps it trains again)."""

    SKIP = ("step", "epoch", "wall", "minutes", "n", "seconds")

    def __init__(self, folder: Path):
        self.folder, self.writer, self.purge_step, self.charted = Path(folder), None, None, False

    def scalars(self, prefix: str, values: dict, step: int) -> None:
        for k, v in values.items():
            if k not in self.SKIP and isinstance(v, (int, float)) and not isinstance(v, bool):
                self.writer.add_scalar(f"{prefix}/{k}", v, step)

    def write(self, record: dict) -> None:
        if self.writer is None:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.folder), purge_step=self.purge_step, flush_secs=10)
            self.purge_step = None
        step = int(record.get("step", 0))
        if isinstance(record.get("val"), dict):
            val = record["val"]
            mine = {k: v for k, v in val.items() if not k.startswith(("trivial_", "pseudo_"))}
            self.scalars("val", mine, step)
            for kind in ("trivial", "pseudo"):
                self.scalars(kind, {k[len(kind) + 1 :]: v for k, v in val.items() if k.startswith(kind + "_")}, step)
            if not self.charted:  # one chart per metric: the network beside its baselines
                charts = [k for k in mine if k not in self.SKIP]
                lines = {k: ["Multiline", [f"val/{k}", f"trivial/{k}", f"pseudo/{k}"]] for k in charts}
                self.writer.add_custom_scalars({"validation beside the trivial baselines": lines})
                self.charted = True
        elif isinstance(record.get("eval"), dict):
            self.scalars("eval", record["eval"], step)
        else:
            losses = {k: v for k, v in record.items() if k not in ("lr", "images_per_s")}
            self.scalars("loss", losses, step)
            self.scalars("train", {k: record[k] for k in ("lr", "images_per_s") if k in record}, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def atomic_write(path, write) -> None:
    """Write ``path`` through ``write(binary_file)`` into a temp file beside it, then rename it into place:
    a crash mid-write leaves the previous file intact (a temp name per process and thread: processes and the
    prefetch threads may write the same file at once; the last rename wins)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp{os.getpid()}-{threading.get_ident()}")
    with tmp.open("wb") as f:
        write(f)
    os.replace(tmp, path)


def previous_checkpoint(path: Path) -> Path:
    """Where :func:`save_checkpoint` keeps the checkpoint it replaced (``last.pt`` -> ``prev.pt``)."""
    path = Path(path)
    return path.with_name("prev.pt") if path.name == "last.pt" else path.with_name(path.stem + ".prev" + path.suffix)


def nonfinite_tensors(*modules) -> list[str]:
    """Names of the parameters and buffers of ``modules`` (None skipped) holding a NaN or Inf; one device sync."""
    named = [
        (f"{i}.{k}", v)
        for i, m in enumerate(modules)
        if m is not None
        for k, v in m.state_dict().items()
        if v.is_floating_point()
    ]
    finite = torch.stack([v.isfinite().all() for _, v in named]).tolist() if named else []
    return [k for (k, _), ok in zip(named, finite) if not ok]


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
            print(
                f"warning: {path} cannot be read ({why}); set aside as {path.name}.damaged, continuing from "
                f"the previous checkpoint {prev} (step {state.get('step', '?')})"
            )
            return {**state, "loaded_from": str(prev)}
        hint = f"; the previous checkpoint is {prev}" if prev.exists() else ""
        raise CheckpointError(f"the checkpoint {path} cannot be read ({why}){hint}") from None


def rng_state() -> dict:
    return {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
    }


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    if state.get("cuda") is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_samples(path: Path, batch: dict, out: dict, n: int = 8) -> None:
    """A grid, one row per image; columns those of SAMPLE_COLUMNS the model has."""
    from disent.images import sample_grid, save_image

    save_image(sample_grid(batch, out, SAMPLE_COLUMNS, n), path)


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
                    raise RunFolderBusy(
                        f"the run folder {self.path.parent} is in use by process {holder}; "
                        "give this run its own folder (hydra.run.dir=...)"
                    ) from None
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


def load_yaml(path: Path):
    """The YAML at ``path``, None where it is missing or unreadable."""
    try:
        return yaml.safe_load(path.read_text()) if path.is_file() else None
    except (OSError, yaml.YAMLError):
        return None


def load_json(path):
    """The JSON at ``path``, None where it is missing or unreadable."""
    path = Path(path)
    try:
        return json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        return None


def dotted(d, key: str, default=None):
    """``d["a"]["b"]`` for ``key`` ``"a.b"`` of nested dicts (a resolved config), ``default`` where a part is
    missing."""
    for part in key.split("."):
        if not isinstance(d, dict) or part not in d:
            return default
        d = d[part]
    return d


def read_jsonl(path: Path) -> list[dict]:
    """Records of a JSON-lines file; unreadable lines (a run killed mid-write) are skipped."""
    rows = []
    if Path(path).is_file():
        for line in Path(path).read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
    return rows


def tool_folder(tool: str, out=None) -> Path:
    """The folder a tool writes into: ``out`` when given, else ``outputs/<tool>/<date>/<time>-<pid>/``.  It holds
    ``.tool`` (the tool's name, for :func:`publish`), ``command.txt`` (the command line) and ``git.txt``."""
    import sys
    import time

    if not tool.isidentifier():
        raise ValueError(f"tool name {tool!r}: letters, digits and underscores only")
    folder = Path(out) if out else Path("outputs") / tool / f"{time.strftime('%Y-%m-%d/%H-%M-%S')}-{os.getpid()}"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / ".tool").write_text(tool + "\n")
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)  # python -m NAME: the module's name
    prog = f"python -m {spec.name.removesuffix('.__main__')}" if spec else f"python {sys.argv[0]}"
    (folder / "command.txt").write_text(" ".join([prog, *sys.argv[1:]]) + "\n")
    write_git_revision(folder)
    return folder

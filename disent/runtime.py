"""Runtime tuning, in one place: how the machine is used (CPU threads, memory, the device a table lives on, compiled
kernels), never what is computed.

- :func:`tune_malloc`: glibc keeps freed activations for reuse (``train.malloc_tuning``, the benchmarks).
- :class:`Prefetcher`: training batches rendered ahead in background threads (``train.prefetch``, ``_workers``).
- :class:`single_thread`: one torch thread inside (SynthFaces generation is written for one core).
- :func:`single_core`: one torch thread and one OpenBLAS thread (the lighting experiments).
- :func:`used_here`: a batch rendered on another thread's CUDA stream claimed by this one's (``train.together``).
- :func:`compile_networks`: torch.compile of the model and D in place (``train.compile``, ``bench --compile``).
- :func:`per_device`: a cached tensor builder (SynthFaces' mesh, masks, banks) copied once to the device it is
  asked on, where batches are rendered on the training device (``data.device``).
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import ContextDecorator, contextmanager

import torch


def tune_malloc() -> bool:
    """Keep freed memory in glibc's heap instead of returning it to the kernel (process-wide).

    glibc serves blocks above its mmap threshold (at most 32 MB, one ``[64,32,64,64]``
    float32 activation) with fresh ``mmap`` pages, so every large activation page-faults
    on first touch.  With mmap off and no trimming they are reused.  No-op off glibc.
    Used by training (``train.malloc_tuning``) and by ``python -m disent.bench``.
    """
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4  # <malloc.h>
        return bool(libc.mallopt(M_MMAP_MAX, 0) and libc.mallopt(M_TRIM_THRESHOLD, 2**31 - 1))
    except (OSError, AttributeError):
        return False


class Prefetcher:
    """``make_batch(step)`` for ``steps`` in order, computed up to ``depth`` steps ahead by ``workers``
    background threads while the training step runs (torch ops release the GIL).  ``get(step)``
    returns the batch of ``step`` and checks that the steps are consumed in the order given, so
    prefetching never changes which images a step sees, whatever the worker count.  ``depth=0``:
    ``make_batch`` in the caller.  An exception in a worker is raised again by ``get``.  One worker
    suits the 2-core machine; a GPU step outruns one rendering core, so ``device=cuda`` wants several.
    """

    def __init__(self, make_batch, steps, depth: int = 2, workers: int = 1):
        self.make_batch, self.depth = make_batch, depth
        self.steps = iter(steps)
        self.pending: deque = deque()  # (step, future), in step order
        if depth > 0:
            # torch initialises a thread's OpenMP count lazily from the last set_num_threads of ANY
            # thread; initialise this one now, so the workers' set_num_threads(1) leaves it alone
            torch.get_num_threads()
            workers = max(1, int(workers))
            self.pool = ThreadPoolExecutor(workers, "prefetch", initializer=torch.set_num_threads, initargs=(1,))
            for _ in range(max(depth, workers)):  # rendering on one core per worker
                self._submit()

    def _submit(self) -> None:
        step = next(self.steps, None)
        if step is not None:
            self.pending.append((step, self.pool.submit(self.make_batch, step)))

    def get(self, step: int) -> dict:
        if self.depth == 0:
            got = next(self.steps)
            batch = self.make_batch(got)
        else:
            got, future = self.pending.popleft()
            self._submit()
            batch = future.result()
        if got != step:
            raise RuntimeError(f"prefetcher out of order: asked for step {step}, has step {got}")
        return batch

    def close(self) -> None:
        if self.depth > 0:
            self.pool.shutdown(wait=True, cancel_futures=True)


class single_thread(ContextDecorator):
    """Run torch on one thread inside (generation is written for one core: on a shared
    machine, intra-op threads only add synchronisation to these small tensor ops)."""

    def __enter__(self):
        self.n = torch.get_num_threads()
        if self.n != 1:
            torch.set_num_threads(1)

    def __exit__(self, *exc):
        if self.n != 1:
            torch.set_num_threads(self.n)


_SETTERS = (
    "openblas_set_num_threads",
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
)
_GETTERS = tuple(s.replace("set", "get") for s in _SETTERS)


def _openblas() -> list:
    """``(get, set)`` of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    import numpy  # noqa: F401  (load their BLAS libraries)
    import scipy.linalg  # noqa: F401

    try:
        paths = {line.split()[-1] for line in open("/proc/self/maps") if "openblas" in line.lower()}
    except OSError:  # not Linux: leave the BLAS alone
        return []
    found = []
    for path in sorted(paths):
        lib = ctypes.CDLL(path)
        for get, set_ in zip(_GETTERS, _SETTERS):
            if hasattr(lib, set_) and hasattr(lib, get):
                found.append((getattr(lib, get), getattr(lib, set_)))
                break
    return found


@contextmanager
def single_core():
    """Run the block with one torch thread (:class:`single_thread`) and one OpenBLAS thread; restore both
    after.  numpy's OpenBLAS starts one thread per core on its own; on a shared machine those threads spin
    against other work and make small matrix products many times slower, and ``torch.set_num_threads``
    does not reach them, so this sets OpenBLAS's count through its C API."""
    blas = _openblas()
    before = [get() for get, _ in blas]
    for _, set_ in blas:
        set_(1)
    try:
        with single_thread():
            yield
    finally:
        for (_, set_), n in zip(blas, before):
            set_(n)


def moved(value, device):
    """``value`` with every tensor in it on ``device``: a tensor, or tuples, lists, dicts and dataclasses of them, each
    copied (a dataclass's cache dict too, so the copy shares nothing with the original)."""
    if torch.is_tensor(value):
        return value.to(device)
    if isinstance(value, (tuple, list)):
        return type(value)(moved(v, device) for v in value)
    if isinstance(value, dict):
        return {k: moved(v, device) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.replace(
            value, **{f.name: moved(getattr(value, f.name), device) for f in dataclasses.fields(value) if f.init}
        )
    return value


def per_device(build):
    """Decorate a cached builder of tensors (``lru_cache``'d, no tensor arguments): on the CPU it is ``build``; under
    ``with torch.device(d)`` (SynthFaces rendering on the training device) ``build`` runs on the CPU, where its
    seeded generators live, and its result is copied to ``d`` once and kept."""
    copies = {}

    @functools.wraps(build)
    def on_default_device(*args):
        device = torch.get_default_device()
        if device.type == "cpu":
            return build(*args)
        key = (str(device), args)
        if key not in copies:
            with torch.device("cpu"):
                copies[key] = moved(build(*args), device)
        return copies[key]

    return on_default_device


def compile_networks(*networks) -> None:
    """``torch.compile`` each of ``networks`` (None skipped) in place, so checkpoints keep their keys.  A training step
    backpropagates D's loss with the graph kept for the generator's (``retain_graph``), which compiled backward
    passes allow only without donated buffers, so those are off."""
    import torch._functorch.config as functorch_config

    functorch_config.donated_buffer = False
    for net in networks:
        if net is not None:
            net.compile()


def used_here(batch: dict) -> dict:
    """``batch`` with its GPU tensors marked as used by this thread's CUDA stream (``record_stream``): a batch
    rendered on another thread's stream (``data.device=cuda``) is then not handed back to the allocator while a run
    on its own stream (``train.together``) still reads it.  Nothing on the CPU."""
    for v in batch.values():
        if torch.is_tensor(v) and v.is_cuda:
            v.record_stream(torch.cuda.current_stream(v.device))
    return batch

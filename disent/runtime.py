"""Runtime tuning, in one place: how the CPU is used, never what is computed.

- :func:`tune_malloc`: glibc keeps freed activations for reuse (``train.malloc_tuning``, the benchmarks).
- :class:`Prefetcher`: training batches rendered ahead in a background thread (``train.prefetch``).
- :class:`single_thread`: one torch thread inside (SynthFaces generation is written for one core).
- :func:`single_core`: one torch thread and one OpenBLAS thread (the lighting experiments).
"""

from __future__ import annotations

import ctypes
import queue
import threading
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
    """``make_batch(step)`` for ``steps`` in order, computed up to ``depth`` steps ahead in a
    background thread while the training step runs (torch ops release the GIL).  ``get(step)``
    returns the batch of ``step`` and checks that the steps are consumed in the order given, so
    prefetching never changes which images a step sees.  ``depth=0``: ``make_batch`` in the caller.
    An exception in the thread is raised again by ``get``.
    """

    def __init__(self, make_batch, steps, depth: int = 2):
        self.make_batch, self.depth = make_batch, depth
        self.steps = iter(steps)
        if depth > 0:
            # torch initialises a thread's OpenMP count lazily from the last set_num_threads of ANY
            # thread; initialise this one now, so the worker's set_num_threads(1) leaves it alone
            torch.get_num_threads()
            self.queue: queue.Queue = queue.Queue(maxsize=depth)
            self.stopped = threading.Event()
            self.thread = threading.Thread(target=self._work, name="prefetch", daemon=True)
            self.thread.start()

    def _work(self) -> None:
        torch.set_num_threads(1)  # rendering on one core; the training thread keeps its own count
        try:
            for step in self.steps:
                item = (step, self.make_batch(step))
                while not self.stopped.is_set():
                    try:
                        self.queue.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        pass
                if self.stopped.is_set():
                    return
        except BaseException as e:  # handed to the training thread
            self.queue.put((None, e))

    def get(self, step: int) -> dict:
        if self.depth == 0:
            got = next(self.steps)
            batch = self.make_batch(got)
        else:
            got, batch = self.queue.get()
            if got is None:
                raise batch
        if got != step:
            raise RuntimeError(f"prefetcher out of order: asked for step {step}, has step {got}")
        return batch

    def close(self) -> None:
        if self.depth > 0:
            self.stopped.set()
            while self.thread.is_alive():
                try:
                    self.queue.get(timeout=0.1)
                except queue.Empty:
                    pass
            self.thread.join()


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

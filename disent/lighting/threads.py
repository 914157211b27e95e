"""One core for the lighting experiments: torch's threads and the BLAS threads numpy and scipy use.

numpy's OpenBLAS starts one thread per core on its own; on a shared machine those threads
spin against other work and make small matrix products many times slower.  ``torch.set_num_threads``
does not reach them, so :func:`single_core` also sets OpenBLAS's count through its C API.
"""
from __future__ import annotations

import ctypes
from contextlib import contextmanager

_SETTERS = ("openblas_set_num_threads", "scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
            "openblas_set_num_threads64_")
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
    """Run the block with one torch thread (:class:`disent.data.face_model.single_thread`) and one
    OpenBLAS thread; restore both after."""
    from disent.data.face_model import single_thread

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


__all__ = ["single_core"]

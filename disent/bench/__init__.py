"""The benchmarks: ``python -m disent.bench [SUBCOMMAND ...]`` (:mod:`disent.bench.__main__`).

This module holds what every benchmark shares (timing, the matmul peak, the JSON they write); the
subcommands live beside it: :mod:`~disent.bench.models` (models, profile, time_to_accuracy),
:mod:`~disent.bench.data` (SynthFaces generation), :mod:`~disent.bench.lighting` (L-hat and the posterior)
and, in ``__main__``, the matmul peak and the shading layer.

Every subcommand prints a table and merges its figures into ``bench.json`` (``bench-cuda.json`` with
``--device cuda``) in the tool folder ``outputs/bench/<date>/<time>-<pid>/`` (or ``--out FILE``);
``python -m disent.report --publish FOLDER`` merges its sections into ``reports/bench*.json``, which the
report reads, so that GPU figures sit beside the CPU ones.  Benchmarks print figures; no test asserts a time.
The machine is shared and noisy, so each figure is the median of several rounds.
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path
from typing import Callable, Sequence

import torch

from disent.storage import machine_info as runs_machine_info

BENCH_JSON = Path("bench.json")  # in the bench tool folder; published to reports/bench.json
DEVICE = "cpu"  # set by --device


def bench_json(device: str) -> Path:
    """The file a run on ``device`` writes: ``bench.json`` on the CPU, ``bench-cuda.json`` on any GPU
    (``cuda:N`` included), so the two never overwrite each other when published to ``reports/``."""
    kind = torch.device(device).type
    return BENCH_JSON if kind == "cpu" else BENCH_JSON.with_name(f"bench-{kind}.json")


def timed_rounds(fns: Sequence[Callable[[], object]], rounds: int = 5, warmup: int = 1) -> list[list[float]]:
    """Wall seconds of each of ``fns`` in every round: within a round the functions run in turn,
    so on a shared machine they see the load of the same moments.  ``warmup`` untimed rounds first."""
    times = [[] for _ in fns]
    for r in range(warmup + rounds):
        for fn, out in zip(fns, times):
            t0 = time.perf_counter()
            fn()
            if r >= warmup:
                out.append(time.perf_counter() - t0)
    return times


def median_time(fn: Callable[[], object], rounds: int = 5, warmup: int = 1) -> float:
    """Median wall time in seconds of ``fn()`` over ``rounds`` after ``warmup`` calls."""
    return statistics.median(timed_rounds([fn], rounds, warmup)[0])


def device_sync(device: str) -> Callable[[], None]:
    """Waits for the device's queued work (a GPU's kernels run asynchronously); nothing on the CPU."""
    return torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)


def matmul(n: int = 2048, device: str = "cpu") -> Callable[[], None]:
    """One fp32 ``n x n`` matmul (``2 n^3`` FLOPs), synchronised: the peak's yardstick."""
    a = torch.randn(n, n, device=device)
    b = torch.randn(n, n, device=device)
    sync = device_sync(device)

    def mm():
        a @ b
        sync()

    return mm


def measure_peak_gflops(n: int = 2048, rounds: int = 5, device: str = "cpu") -> float:
    """This machine's fp32 matmul peak in GFLOP/s at the current thread count."""
    return 2 * n**3 / median_time(matmul(n, device), rounds) / 1e9


def machine_info() -> dict:
    """:func:`disent.storage.machine_info` under the benchmark file's keys (the GPU's name inside ``device``)."""
    info = runs_machine_info(DEVICE, torch.get_num_threads())
    return {
        "torch": info["torch"],
        "threads": info["threads"],
        "device": DEVICE if "gpu" not in info else f"{DEVICE} ({info['gpu']})",
        "cpu": info["processor"],
        "cpu_count": info["cpus"],
    }


def save(section: str, figures: dict, path: Path = BENCH_JSON) -> None:
    """Merge ``figures`` under ``section`` into the benchmark JSON (atomic write).

    A ``"top"`` entry of ``figures`` is merged into the top level instead (e.g. ``peak_gflops``).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.exists() else {}
    machine = machine_info()
    if any(data.get(k) != machine[k] for k in ("cpu", "device")):  # load_average_1min names this machine's sections
        data.pop("load_average_1min", None)
    data.update(machine)
    figures = dict(figures)
    data.update(figures.pop("top", {}))
    data[section] = figures
    # the 1-minute load average as the section is written (the benchmark's own threads count in it): more than
    # the thread count means other work shared the cores
    data.setdefault("load_average_1min", {})[section] = round(os.getloadavg()[0], 2)
    from disent.storage import atomic_write

    atomic_write(path, lambda f: f.write(json.dumps(data, indent=2, sort_keys=True).encode()))


def print_table(title: str, rows: dict) -> None:
    print(f"\n{title}")
    width = max(len(k) for k in rows)
    for k, v in rows.items():
        print(f"  {k:<{width}}  {v:,.4g}" if isinstance(v, (int, float)) else f"  {k:<{width}}  {v}")

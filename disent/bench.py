"""One benchmark entry point: ``python -m disent.bench [SUBCOMMAND ...]``.

Every subcommand prints a table and merges its figures into ``reports/bench.json``, or
``reports/bench-cuda.json`` with ``--device cuda``, so that GPU figures sit beside the CPU ones
(the report reads every ``reports/bench*.json``).  Benchmarks print figures; no test asserts a time.
The machine is shared and noisy, so each figure is the median of several rounds.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Callable, Sequence

import torch

BENCH_JSON = Path("reports/bench.json")
DEVICE = "cpu"  # set by --device


def bench_json(device: str) -> Path:
    """Where a run on ``device`` writes: ``reports/bench.json`` on the CPU, ``reports/bench-cuda.json``
    on any GPU (``cuda:N`` included), so the two never overwrite each other."""
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


def matmul(n: int = 2048, device: str = "cpu") -> Callable[[], None]:
    """One fp32 ``n x n`` matmul (``2 n^3`` FLOPs), synchronised: the peak's yardstick."""
    a = torch.randn(n, n, device=device)
    b = torch.randn(n, n, device=device)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)

    def mm():
        a @ b
        sync()

    return mm


def measure_peak_gflops(n: int = 2048, rounds: int = 5, device: str = "cpu") -> float:
    """This machine's fp32 matmul peak in GFLOP/s at the current thread count."""
    return 2 * n**3 / median_time(matmul(n, device), rounds) / 1e9


def machine_info() -> dict:
    return {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "device": DEVICE if DEVICE == "cpu" else f"{DEVICE} ({torch.cuda.get_device_name(DEVICE)})",
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
    }


def save(section: str, figures: dict, path: Path = BENCH_JSON) -> None:
    """Merge ``figures`` under ``section`` into the benchmark JSON (atomic write).

    A ``"top"`` entry of ``figures`` is merged into the top level instead (e.g. ``peak_gflops``).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    data = json.loads(path.read_text()) if path.exists() else {}
    data.update(machine_info())
    figures = dict(figures)
    data.update(figures.pop("top", {}))
    data[section] = figures
    from disent.runs import atomic_write

    atomic_write(path, lambda f: f.write(json.dumps(data, indent=2, sort_keys=True).encode()))


def print_table(title: str, rows: dict) -> None:
    print(f"\n{title}")
    width = max(len(k) for k in rows)
    for k, v in rows.items():
        print(f"  {k:<{width}}  {v:,.4g}" if isinstance(v, (int, float)) else f"  {k:<{width}}  {v}")


# ----------------------------------------------------------------------------- subcommands
def bench_render(args) -> dict:
    """Shading layer: forward / backward pixels/s, analytic backward vs plain autograd."""
    from disent.render import sh_shading, sh_shading_reference

    B, H = args.batch, args.size
    normal = torch.nn.functional.normalize(torch.randn(B, 3, H, H), dim=1).requires_grad_()
    sh = torch.randn(B, 3, 9).requires_grad_()
    pixels = B * H * H
    fwd = median_time(lambda: sh_shading(normal, sh), args.rounds)

    def fwd_bwd(fn):
        return lambda: fn(normal, sh).sum().backward()

    custom = median_time(fwd_bwd(sh_shading), args.rounds)
    plain = median_time(fwd_bwd(sh_shading_reference), args.rounds)
    out = {
        "batch": B, "resolution": H,
        "forward_pixels_s": pixels / fwd,
        "forward_backward_pixels_s": pixels / custom,
        "backward_pixels_s": pixels / max(custom - fwd, 1e-9),
        "autograd_forward_backward_pixels_s": pixels / plain,
        "custom_vs_autograd_speedup": plain / custom,
    }
    print_table(f"shading layer, batch {B} at {H}x{H}, {torch.get_num_threads()} threads", out)
    return out


def bench_peak(args) -> dict:
    out = {"peak_gflops": measure_peak_gflops(args.peak_n, rounds=args.rounds, device=args.device)}
    print_table("fp32 matmul peak", out)
    return {**out, "top": out}


SUBCOMMANDS: dict[str, Callable] = {"peak": bench_peak, "render": bench_render}


def register(name: str, fn: Callable) -> None:
    """Let a module add a subcommand (``fn(args) -> dict``)."""
    SUBCOMMANDS[name] = fn


def _load_optional_subcommands() -> None:
    """Import modules that register benchmark subcommands, where present."""
    import importlib

    for mod in ("disent.data.bench", "disent.models.bench", "disent.lighting"):
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name != mod and not mod.startswith(str(e.name)):
                raise


def main(argv=None) -> None:
    _load_optional_subcommands()
    if __name__ == "__main__":  # run as a script, modules registered into the importable disent.bench
        import disent.bench

        SUBCOMMANDS.update(disent.bench.SUBCOMMANDS)
    p = argparse.ArgumentParser(prog="python -m disent.bench", description=__doc__)
    p.add_argument("which", nargs="*", default=[], help=f"subcommands (default: all): {', '.join(SUBCOMMANDS)}")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: the count with the highest matmul peak)")
    p.add_argument("--rounds", type=int, default=5, help="timed rounds; the median is reported")
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--out", type=Path, default=None, help="default: reports/bench.json, reports/bench-cuda.json on a GPU")
    p.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    p.add_argument("--amp", action="store_true", help="bfloat16 mixed precision (the shading layer stays float32)")
    p.add_argument("--bf16", dest="bf16", action="store_true", default=None,
                   help="measure bfloat16 autocast figures beside the float32 ones (default: on a GPU or a CPU "
                        "with native bf16; where bf16 is emulated it is ~15x slower and takes minutes)")
    p.add_argument("--no-bf16", dest="bf16", action="store_false", help="skip the bfloat16 figures")
    p.add_argument("--no-channels-last", action="store_true", help="NCHW instead of NHWC activations")
    p.add_argument("--models", nargs="*", default=None, help="models to benchmark (default: all)")
    p.add_argument("--norm", choices=("none", "batch", "group"), default=None,
                   help="the models' normalisation layers instead of conf/model's (to time what they cost)")
    p.add_argument("--run", default=None, help="run folder for time_to_accuracy (default: newest under outputs/)")
    p.add_argument("--peak-n", type=int, default=2048, help="side of the square matmul that measures the peak")
    p.add_argument("--train-batch", type=int, default=64, help="batch of the models' training steps")
    p.add_argument("--infer-batches", type=int, nargs="+", default=[1, 64, 256], help="inference batches (64 is the headline)")
    p.add_argument("--no-malloc-tuning", action="store_true", help="leave glibc's malloc as it is (see tune_malloc)")
    args = p.parse_args(argv)
    if args.threads is not None and args.threads < 1:
        p.error(f"--threads {args.threads}: must be a whole number >= 1 (default: the count with the highest matmul peak)")
    args.out = args.out or bench_json(args.device)
    from disent.train import tune_malloc  # the same setting as training (train.malloc_tuning)

    args.malloc_tuned = False if args.no_malloc_tuning else tune_malloc()
    global DEVICE
    DEVICE = args.device
    if args.norm:
        from disent.models import bench as model_bench

        model_bench.LAYER_OVERRIDES["norm"] = args.norm
    if args.threads:
        torch.set_num_threads(args.threads)
    else:  # the fastest thread count, by the matmul peak (on a shared machine fewer threads can win)
        by_threads = {}
        for t in range(1, (os.cpu_count() or 1) + 1):
            torch.set_num_threads(t)
            by_threads[t] = measure_peak_gflops(1024, rounds=3, device=args.device)
        torch.set_num_threads(max(by_threads, key=by_threads.get))
        print(f"threads: {torch.get_num_threads()} (matmul GFLOP/s by thread count: "
              + ", ".join(f"{t}: {g:.0f}" for t, g in by_threads.items()) + ")")
    for name in args.which or list(SUBCOMMANDS):
        if name not in SUBCOMMANDS:
            p.error(f"unknown benchmark {name!r}; choose from {', '.join(SUBCOMMANDS)}")
        save(name, SUBCOMMANDS[name](args), args.out)
    print(f"\nwritten to {args.out}")


if __name__ == "__main__":
    main()

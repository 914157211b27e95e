"""``python -m disent.bench [SUBCOMMAND ...]``: every subcommand prints a table and merges its figures into
the benchmark JSON (see :mod:`disent.bench`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Callable

import torch

import disent.bench as bench
from disent.bench import bench_json, data, lighting, measure_peak_gflops, median_time, models, print_table, save
from disent.bench.stack import bench_stack
from disent.runtime import tune_malloc  # the same setting as training (train.malloc_tuning)
from disent.storage import tool_folder


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
        "batch": B,
        "resolution": H,
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


SUBCOMMANDS: dict[str, Callable] = {
    "peak": bench_peak,
    "render": bench_render,
    "data": data.bench_data,
    "models": models.bench_models,
    "stack": bench_stack,
    "norm_cost": models.bench_norm_cost,
    "profile": models.bench_profile,
    "time_to_accuracy": models.bench_time_to_accuracy,
    "lighting": lighting.bench_lighting,
}


def fastest_threads(device: str) -> None:
    """Set torch's thread count to the one with the highest 1024-square matmul rate, and print the rates."""
    by_threads = {}
    for t in range(1, (os.cpu_count() or 1) + 1):
        torch.set_num_threads(t)
        by_threads[t] = measure_peak_gflops(1024, rounds=3, device=device)
    torch.set_num_threads(max(by_threads, key=by_threads.get))
    print(
        f"threads: {torch.get_num_threads()} (matmul GFLOP/s by thread count: "
        + ", ".join(f"{t}: {g:.0f}" for t, g in by_threads.items())
        + ")"
    )


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m disent.bench", description=bench.__doc__)
    p.add_argument("which", nargs="*", default=[], help=f"subcommands (default: all): {', '.join(SUBCOMMANDS)}")
    p.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: the count with the highest matmul peak)"
    )
    p.add_argument("--rounds", type=int, default=5, help="timed rounds; the median is reported")
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--size", type=int, default=64)
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the JSON to merge into, in a folder that becomes the tool folder (default: bench.json, "
        "bench-cuda.json on a GPU, in a new tool folder outputs/bench/<date>/<time>-<pid>/)",
    )
    p.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    p.add_argument("--amp", action="store_true", help="bfloat16 mixed precision (the shading layer stays float32)")
    p.add_argument("--compile", action="store_true", help="training steps timed with torch.compile (train.compile)")
    p.add_argument(
        "--bf16",
        dest="bf16",
        action="store_true",
        default=None,
        help="measure bfloat16 autocast figures beside the float32 ones (default: on a GPU or a CPU "
        "with native bf16; where bf16 is emulated it is ~15x slower and takes minutes)",
    )
    p.add_argument("--no-bf16", dest="bf16", action="store_false", help="skip the bfloat16 figures")
    p.add_argument("--no-channels-last", action="store_true", help="NCHW instead of NHWC activations")
    p.add_argument("--models", nargs="*", default=None, help="models to benchmark (default: all)")
    p.add_argument(
        "--no-kernels",
        action="store_true",
        help="the plain PyTorch layers instead of the CPU speed kernels (model.kernels=false: what the kernels buy)",
    )
    p.add_argument(
        "--norm",
        choices=("none", "batch", "group"),
        default=None,
        help="the models' normalisation layers instead of conf/model's (to time what they cost)",
    )
    p.add_argument("--run", default=None, help="run folder for time_to_accuracy (default: newest under outputs/)")
    p.add_argument("--peak-n", type=int, default=2048, help="side of the square matmul that measures the peak")
    p.add_argument("--train-batch", type=int, default=64, help="batch of the models' training steps")
    p.add_argument("--runs", type=int, default=3, help="runs stacked by the stack benchmark (train.stack)")
    p.add_argument(
        "--infer-batches", type=int, nargs="+", default=[1, 64, 256], help="inference batches (64 is the headline)"
    )
    p.add_argument("--no-malloc-tuning", action="store_true", help="leave glibc's malloc as it is (see tune_malloc)")
    return p


def main(argv=None) -> None:
    p = parser()
    args = p.parse_args(argv)
    if args.threads is not None and args.threads < 1:
        p.error(
            f"--threads {args.threads}: must be a whole number >= 1 (default: the count with the highest matmul peak)"
        )
    if args.out and args.out.resolve().parent == Path.cwd().resolve():
        p.error(f"--out {args.out}: give a file inside a folder of its own (the folder becomes the tool folder)")
    args.out = tool_folder("bench", args.out and args.out.parent) / (
        args.out.name if args.out else bench_json(args.device)
    )
    args.malloc_tuned = False if args.no_malloc_tuning else tune_malloc()
    bench.DEVICE = args.device
    if args.norm:
        models.LAYER_OVERRIDES["norm"] = args.norm
    if args.no_kernels:
        models.LAYER_OVERRIDES["kernels"] = False
    if args.threads:
        torch.set_num_threads(args.threads)
    else:  # the fastest thread count, by the matmul peak (on a shared machine fewer threads can win)
        fastest_threads(args.device)
    for name in args.which or list(SUBCOMMANDS):
        if name not in SUBCOMMANDS:
            p.error(f"unknown benchmark {name!r}; choose from {', '.join(SUBCOMMANDS)}")
        save(name, SUBCOMMANDS[name](args), args.out)
    print(f"\nwritten to {args.out}; publish: python -m disent.report --publish {args.out.parent}")


if __name__ == "__main__":
    main()

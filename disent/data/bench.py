"""``python -m disent.bench data``: SynthFaces generation speed, images/s on one core.

Times ``SynthFaces.get_batch`` on fresh indices (nothing cached): every layer of the
sample, the true face and the coarse 3DMM-like fit rasterized together, and the pseudo
ground truth with its L-hat, at one torch thread.  The median over rounds is reported per
wall-clock second and per CPU second of this process; on a shared machine the second is
the one-core figure (the first also counts time the core spent on other work).  The
``_without_pseudo`` figures time the same scenes without the pseudo ground truth (median
CPU seconds).  The dataset's target is 1,000 images per CPU second at 64x64.
"""
from __future__ import annotations

import time

import torch

from disent.bench import print_table, register


def _median(xs: list[float]) -> float:
    return sorted(xs)[len(xs) // 2]


def bench_data(args) -> dict:
    from disent.data import SynthFaces
    from disent.data.synth import render_scenes

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    out = {"threads": 1}
    try:
        for res in sorted({64, 128} | {args.size}):
            ds = SynthFaces("train", resolution=res, seed=0)
            B = min(args.batch, 256)
            ds.get_batch(range(B))  # builds the fixed tables (layers, atlas, model)
            wall, cpu, bare, start = [], [], [], B
            for _ in range(args.rounds):
                idx = range(start, start + B)
                start += B
                t0, c0 = time.perf_counter(), time.process_time()
                ds.get_batch(idx)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
                p = ds.params(idx)
                c0 = time.process_time()
                render_scenes(p, res, pseudo=False)
                bare.append(time.process_time() - c0)
            out[f"images_per_s_{res}"] = B / _median(wall)
            out[f"images_per_cpu_s_{res}"] = B / _median(cpu)
            out[f"images_per_cpu_s_{res}_without_pseudo"] = B / _median(bare)
        out["batch"] = B
    finally:
        torch.set_num_threads(threads)
    print_table("SynthFaces generation (one thread, fresh indices, all layers + pseudo-GT)", out)
    return out


register("data", bench_data)

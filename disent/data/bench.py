"""``python -m disent.bench data``: SynthFaces generation speed, images/s on one core.

Times ``SynthFaces.get_batch`` on fresh indices (nothing cached), with the pseudo ground
truth, at one torch thread; the median over rounds is reported, both per wall-clock
second and per CPU second of this process (on a shared machine the second is the
one-core figure, the first also counts time the core spent on other work).
"""
from __future__ import annotations

import time

import torch

from disent.bench import print_table, register


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
            wall, cpu, start = [], [], B
            for _ in range(args.rounds):
                idx = range(start, start + B)
                start += B
                t0, c0 = time.perf_counter(), time.process_time()
                ds.get_batch(idx)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            out[f"images_per_s_{res}"] = B / sorted(wall)[len(wall) // 2]
            out[f"images_per_cpu_s_{res}"] = B / sorted(cpu)[len(cpu) // 2]
            p = ds.params(range(B))
            t0 = time.perf_counter()
            render_scenes(p, res, pseudo=False)
            out[f"images_per_s_{res}_without_pseudo"] = B / (time.perf_counter() - t0)
        out["batch"] = B
    finally:
        torch.set_num_threads(threads)
    print_table("SynthFaces generation (one thread, fresh indices, all layers + pseudo-GT)", out)
    return out


register("data", bench_data)

"""``python -m disent.bench data``: SynthFaces generation speed, images/s on one core.

Times ``SynthFaces.get_batch`` on fresh indices (nothing cached): every layer of the
sample, the true face and the coarse 3DMM-like fit rasterized together, and the pseudo
ground truth with its L-hat, at one torch thread.  The median over rounds is reported per
wall-clock second and per CPU second of this process; on a shared machine the second is
the one-core figure (the first also counts time the core spent on other work).  The
``_without_pseudo`` figures time the same scenes without the pseudo ground truth (median
CPU seconds).  The dataset's target is 1,000 images per CPU second at 64x64.  ``--device cuda``: the same batches
rendered on the GPU (``data.device``), timed to the end of their GPU work.
"""

from __future__ import annotations

import statistics
import time

from disent.bench import device_sync, print_table


def generation_rates(ds, n: int, rounds: int) -> tuple[float, float]:
    """``ds.get_batch`` (one torch thread, as SynthFaces renders) on ``rounds`` fresh blocks of ``n``
    indices, after one block that builds the generator's fixed tables: medians of (images per wall
    second, images per CPU second of this process).  Also the loader figure of ``disent.bench models``."""
    sync = device_sync(str(ds.device))
    ds.get_batch(range(n))
    sync()
    wall, cpu = [], []
    for start in range(n, n * (rounds + 1), n):
        t0, c0 = time.perf_counter(), time.process_time()
        ds.get_batch(range(start, start + n))
        sync()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return n / statistics.median_high(wall), n / statistics.median_high(cpu)


def bench_data(args) -> dict:
    from disent.data import SynthFaces
    from disent.data.synth.scenes import render_scenes
    from disent.runtime import single_thread

    out = {"threads": 1, "device": str(args.device)}
    with single_thread():
        for res in sorted({64, 128} | {args.size}):
            ds = SynthFaces("train", resolution=res, seed=0, device=args.device)
            B = min(args.batch, 256)
            out[f"images_per_s_{res}"], out[f"images_per_cpu_s_{res}"] = generation_rates(ds, B, args.rounds)
            bare = []
            for start in range(B, B * (args.rounds + 1), B):  # the same scenes without the pseudo ground truth
                if ds.device.type != "cpu":
                    break  # a CPU figure (the renderer's share of a CPU second)
                p = ds.params(range(start, start + B))
                c0 = time.process_time()
                render_scenes(p, res, pseudo=False)
                bare.append(time.process_time() - c0)
            if bare:
                out[f"images_per_cpu_s_{res}_without_pseudo"] = B / statistics.median_high(bare)
        out["batch"] = B
    print_table("SynthFaces generation (one thread, fresh indices, all layers + pseudo-GT)", out)
    return out

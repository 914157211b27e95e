"""``python -m disent.bench stack``: several runs' training steps stacked (``train.stack``) against the same steps
one run after another.

``--runs`` explicit models with D, each on its own batch of ``--train-batch`` SynthFaces images (the EBGAN margin
above every energy, so each step does its whole work), stepped once each in turn (``sequential``) and as one stacked
step (:class:`disent.stack.Stack`: one ``vmap`` of the model, its losses and D for all).  Images/s across the runs,
each rate timed beside the matmul peak and stated as a fraction of it; ``stacked_over_sequential`` is the speed-up.
On a GPU, where a small model's step is a few thousand small kernels, stacking is what fills the card.
"""

from __future__ import annotations

from types import SimpleNamespace

import torch
from omegaconf import OmegaConf

from disent.bench import device_sync, print_table
from disent.bench.models import CONF, FULL_WORK_MARGIN, Trainer, add_fractions, beside_peak, count_flops, synth_batch


def bench_stack(args) -> dict:
    from disent.stack import Stack

    device, sync, n = args.device, device_sync(args.device), args.train_batch
    channels_last, runs = not args.no_channels_last, max(2, getattr(args, "runs", 3))
    batches = [synth_batch(n, args.size, device, channels_last, start=k * n) for k in range(runs)]
    trainers = [Trainer("explicit", b, True, device, channels_last, args.amp, FULL_WORK_MARGIN) for b in batches]
    cfg_train = OmegaConf.load(CONF / "train" / "default.yaml")
    stack = Stack([SimpleNamespace(cfg=SimpleNamespace(train=cfg_train), **vars_of(tr)) for tr in trainers])
    batch = {k: torch.stack([b[k] for b in batches]) for k in batches[0]}
    cfg_loss = trainers[0].cfg

    def sequential():
        for tr in trainers:
            tr.step()
        sync()

    def stacked():
        losses = stack.step(batch, cfg_loss, 0)
        if "nonfinite" in losses:
            raise FloatingPointError(f"benchmark step gave non-finite {losses['nonfinite']}")
        sync()

    flops = count_flops(trainers[0].step) / n
    out = {"runs": runs, "batch": n, "flops_per_image": flops}
    for key, fn in (("sequential", sequential), ("stacked", stacked)):
        fn()  # warm-up (allocator, optimiser state)
        out[f"{key}_flops_per_image"] = flops
        out[f"{key}_img_s"], out[f"{key}_peak_gflops"] = beside_peak(args, device, fn, runs * n, args.rounds)
    add_fractions(out, out["stacked_peak_gflops"])
    out["stacked_over_sequential"] = out["stacked_img_s"] / out["sequential_img_s"]
    print_table(f"{runs} explicit runs' training steps with D, stacked against one after another ({device})", out)
    return out


def vars_of(trainer: Trainer) -> dict:
    """The networks and optimisers of a benchmark trainer, as a run's training state holds them."""
    return {"model": trainer.model, "disc": trainer.disc, "opt_g": trainer.opt_g, "opt_d": trainer.opt_d}

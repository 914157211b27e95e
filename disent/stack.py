"""Runs of one setting trained as one stacked model: ``train.together=true train.stack=true`` in a sweep over seeds.

The runs' networks keep their own weights, stacked along a leading run axis (``torch.func.stack_module_state``),
and one ``torch.func.vmap`` of the paper's model, its losses and EBGAN's D computes every run's step at once: on a
GPU each of the step's few thousand small kernels then does the work of all the runs.  Each run draws its own
batch in its own seeded order, and the optimiser's update is elementwise, so a run's numbers are the ones it trains
to alone, to float rounding (``tests/test_train.py``).  Each run keeps its own folder, log, validation records,
checkpoints and ``eval.json``: before any of them is written the run's slice is copied back into its own networks
and optimisers (:meth:`Stack.unstack_into`), which are then what the single-run code reads.

Stacking needs the runs to differ only in their seed (and warm start) and to stand at the same step; where they do
not, :func:`disent.together.train_queued` trains them side by side instead.  A non-finite loss in one run stops the
whole stack, as it stops a run alone.
"""

from __future__ import annotations

import copy
import dataclasses
import time

import torch
from omegaconf import OmegaConf
from torch.func import functional_call, stack_module_state, vmap

from disent import losses as L
from disent.config import loss_setting
from disent.data import to_device
from disent.models.discriminator import energy_of
from disent.models.networks import Decoder
from disent.optim import autocast, learning_rate, loss_weights, make_optimizer, set_learning_rate
from disent.runtime import Prefetcher
from disent.train import (
    NonFiniteLoss,
    after_step,
    batch_maker,
    checkpoint,
    due,
    finite_flags,
    last_good,
    stop_reason,
    update,
)

UNSTACKED = ("seed", "init", "resume")  # the settings stacked runs may differ in


def why_not_stacked(states: list) -> str | None:
    """Why the runs ``states`` (set up by :func:`disent.train.set_up`) cannot train stacked; None where they can."""
    if len(states) < 2:
        return "a single run"
    plain = [OmegaConf.to_container(s.cfg, resolve=True) for s in states]
    for p in plain:
        for key in UNSTACKED:
            p.pop(key, None)
    if any(p != plain[0] for p in plain[1:]):
        return "their settings differ beyond the seed"
    if len({s.step for s in states}) > 1:
        return "they stand at different steps: " + ", ".join(f"{s.run_dir.name} at {s.step}" for s in states)
    return None


def functional_copy(net: torch.nn.Module) -> torch.nn.Module:
    """A weightless copy of ``net`` (on the meta device) to call with stacked weights: the plain layers (the CPU
    speed kernels' autograd functions do not batch) and the unpooling that batches."""
    base = copy.deepcopy(net).to("meta")
    for m in base.modules():
        if dataclasses.is_dataclass(getattr(m, "layers", None)):
            m.layers = dataclasses.replace(m.layers, kernels=False)
        if isinstance(m, Decoder):
            m.unpool_by_scatter = True
    return base


class Stack:
    """The runs' model and D stacked, with one optimiser each over the stacked weights (the runs' own state
    stacked in, for runs resumed from checkpoints)."""

    def __init__(self, states: list):
        self.states, t = states, states[0].cfg.train
        self.model = functional_copy(states[0].model)
        self.params, self.buffers = stack_module_state([s.model for s in states])
        self.opt_g = stacked_optimizer([s.opt_g for s in states], list(self.params.values()), t)
        self.disc = self.disc_params = self.disc_buffers = self.opt_d = None
        if states[0].disc is not None:
            self.disc = functional_copy(states[0].disc)
            self.disc_params, self.disc_buffers = stack_module_state([s.disc for s in states])
            self.opt_d = stacked_optimizer([s.opt_d for s in states], list(self.disc_params.values()), t)

    def losses(self, batch: dict, cfg_loss, step: int) -> dict:
        """Every run's loss terms (each ``[N]``), as :func:`disent.train.train_step` computes one run's."""
        weights = loss_weights(cfg_loss, step)
        settings = {k: loss_setting(cfg_loss, k) for k in L.GENERATOR_SETTINGS}
        has_d = self.disc is not None

        def one(params, buffers, disc_params, disc_buffers, b):
            def energy(x):
                return energy_of(functional_call(self.disc, (disc_params, disc_buffers), (x,)), x)

            out = functional_call(self.model, (params, buffers), (b["image"],))
            fake = energy(out["recon"]) if has_d else None
            losses = L.generator_losses(out, b, weights, fake, cfg_loss.bws_c, **settings)
            if has_d:
                real = energy(b["image"])
                losses["D"] = L.discriminator_loss(real, fake, cfg_loss.margin, prune=False)
                losses["D_real"] = real.mean().detach()
            return losses

        d = (self.disc_params, self.disc_buffers) if has_d else ({}, {})
        return vmap(one, randomness="error")(self.params, self.buffers, *d, batch)

    def step(self, batch: dict, cfg_loss, step: int) -> dict:
        """One update of every run; ``nonfinite``: ``(run index, term)`` where a term is not finite (then no update)."""
        losses = self.losses(batch, cfg_loss, step)
        bad = [(i, k) for k, row in zip(losses, finite_flags(losses)) for i, ok in enumerate(row) if not ok]
        if bad:
            return {"nonfinite": bad, **losses}
        loss_d = losses["D"].sum() if self.disc is not None else None
        update(self.opt_g, self.opt_d, losses["total"].sum(), loss_d)  # the runs' sums: each run's own gradient
        return losses

    def unstack_into(self) -> None:
        """Each run's slice of the stacked weights and optimiser state copied into its own networks and optimisers."""
        with torch.no_grad():
            for i, s in enumerate(self.states):
                for net, params, buffers in (
                    (s.model, self.params, self.buffers),
                    (s.disc, self.disc_params, self.disc_buffers),
                ):
                    stacked = params | buffers if net is not None else {}
                    for name, v in (*net.named_parameters(), *net.named_buffers()) if net is not None else ():
                        v.copy_(stacked[name][i])
                s.opt_g.load_state_dict(run_slice(self.opt_g.state_dict(), i))
                if s.opt_d is not None:
                    s.opt_d.load_state_dict(run_slice(self.opt_d.state_dict(), i))


def stacked_optimizer(opts: list, params: list, cfg_train) -> torch.optim.Optimizer:
    """An optimiser over the stacked ``params`` holding the runs' optimisers' state stacked (empty before a step)."""
    opt = make_optimizer(params, cfg_train)
    states = [o.state_dict() for o in opts]
    if states[0]["state"]:
        stacked = {
            j: {k: torch.stack([st["state"][j][k] for st in states]) if v.dim() else v for k, v in per.items()}
            for j, per in states[0]["state"].items()
        }
        opt.load_state_dict({"state": stacked, "param_groups": states[0]["param_groups"]})
    return opt


def run_slice(state: dict, i: int) -> dict:
    """Run ``i``'s optimiser state from a stacked optimiser's: each stacked tensor's ``i``-th slice."""
    return {
        "state": {j: {k: v[i] if v.dim() else v for k, v in per.items()} for j, per in state["state"].items()},
        "param_groups": state["param_groups"],
    }


def train_stacked(states: list) -> list[tuple[str, dict | None]]:
    """The runs ``states`` from their common step to their end, stacked; per run, why it stopped and its last batch
    (for :func:`disent.train.finish`)."""
    s0, t = states[0], states[0].cfg.train
    stack = Stack(states)
    prefetch = [
        Prefetcher(batch_maker(s), range(s.step, s.total_steps), t.get("prefetch", 0), t.get("prefetch_workers", 1))
        for s in states
    ]
    stopped, batches = "steps", [None] * len(states)
    try:
        while s0.step < s0.total_steps:
            if (stopped := stop_reason(s0)) != "steps":
                stack.unstack_into()
                for s in states:
                    checkpoint(s)
                break
            epoch, lr = s0.step // s0.steps_per_epoch, learning_rate(t, s0.step, s0.steps_per_epoch, s0.total_steps)
            set_learning_rate(lr, stack.opt_g, stack.opt_d)
            t0 = time.perf_counter()
            batches = [to_device(p.get(s.step), s.device, t.channels_last) for p, s in zip(prefetch, states)]
            batch = {k: torch.stack([b[k] for b in batches]) for k in batches[0]}
            with autocast(s0.device, t.get("amp", False)):
                losses = stack.step(batch, s0.cfg.loss, s0.step)
            if "nonfinite" in losses:
                i, term = losses["nonfinite"][0]
                s = states[i]
                raise NonFiniteLoss(
                    f"loss term {term!r} is not finite at step {s.step} in {s.run_dir} (epoch {epoch}), which trained "
                    f"stacked with {len(states) - 1} other run(s); all stopped. {last_good(s)}"
                )
            dt = time.perf_counter() - t0
            for s in states:
                s.wall += dt
                s.step += 1
            if any(now["val"] or now["sample"] or now["checkpoint"] for now in map(due, states)):
                stack.unstack_into()  # what the single-run code reads: each run's own networks and optimisers
            for i, (s, b) in enumerate(zip(states, batches)):
                after_step(s, epoch, lr, len(b["image"]) / dt, {k: v[i] for k, v in losses.items()}, b)
    finally:
        for p in prefetch:
            p.close()
        for s in states:
            s.log.close()
    stack.unstack_into()
    return [(stopped, b) for b in batches]

"""Training loop: read top to bottom.  ``run(cfg, run_dir)`` trains, checkpoints, evaluates.

One step (Sec. 4.2): the model renders I_o; the EBGAN discriminator D scores it; the generator
minimises sum_k w_k E_k (disent/losses.py) and D its margin loss, both from the same forward
pass (optimiser and lr schedule: conf/train/default.yaml).  The data order of epoch e is a permutation seeded by
(seed, e), so a run resumed from ``checkpoints/last.pt`` replays exactly the steps it missed.
Batches are rendered ``train.prefetch`` steps ahead in background threads (``Prefetcher``), in
that same order; every ``train.val_every`` steps a fixed validation subset is scored (``validate``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tqdm import tqdm

from disent import losses as L
from disent.config import (
    ConfigError,
    check_config,
    config_differences,
    idle_settings,
    loss_setting,
    truth_readers,
)
from disent.data import get_batch, make_dataset, step_indices, to_device
from disent.eval.evaluate import evaluate, print_eval, trivial_baselines
from disent.eval.scoring import validate
from disent.eval.trivial import trivial_metrics
from disent.lighting.targets import target_fit, with_fitted_lhat
from disent.models import build_model
from disent.optim import (
    autocast,
    build_discriminator,
    learning_rate,
    loss_weights,
    make_optimizer,
    set_learning_rate,
    warm_start,
)
from disent.runtime import Prefetcher, compile_networks, tune_malloc, used_here
from disent.storage import (
    MetricsLog,
    RunLock,
    load_checkpoint,
    machine_info,
    nonfinite_tensors,
    rng_state,
    save_checkpoint,
    save_samples,
    set_rng_state,
    write_git_revision,
)

TRAIN_KEYS = ("image", "normal_pseudo", "mask_pseudo", "sh_pseudo", "uv_pseudo", "normal_uv_pseudo")


def train_keys(cfg_loss) -> tuple:
    """The batch keys a training step reads: the pseudo-GT, and the true layers where a setting reads them
    (:func:`truth_readers`)."""
    return TRAIN_KEYS + (L.TRUTH_KEYS if truth_readers(cfg_loss) else ())


class NonFiniteLoss(FloatingPointError):
    """A loss term or, after an update, a weight became NaN or Inf; the run stops and keeps its last good
    checkpoint (only finite weights are ever saved)."""


def train_step(model, disc, opt_g, opt_d, batch, cfg_loss, step: int = 0) -> dict:
    """One simultaneous generator/discriminator update at ``step``; returns every term (detached floats later)."""
    weights = loss_weights(cfg_loss, step)
    out = model(batch["image"])
    energy_fake = disc.energy(out["recon"]) if disc is not None else None
    settings = {k: loss_setting(cfg_loss, k) for k in L.GENERATOR_SETTINGS}
    losses = L.generator_losses(out, batch, weights, energy_fake, cfg_loss.bws_c, **settings)
    if disc is not None:
        energy_real = disc.energy(batch["image"])
        losses["D"] = L.discriminator_loss(energy_real, energy_fake, cfg_loss.margin)
        losses["D_real"] = energy_real.mean().detach()
    bad = [k for k, ok in zip(losses, finite_flags(losses)) if not ok]
    if bad:
        named = [k for k in bad if k != "total"] or bad
        return {"nonfinite": named, **losses}
    update(opt_g, opt_d, losses["total"], losses.get("D"))
    return losses


def finite_flags(losses: dict) -> list:
    """Whether each term of ``losses`` is finite (a row of runs per term for stacked runs); one device sync."""
    return torch.stack([v.detach().float() for v in losses.values()]).isfinite().tolist()


def update(opt_g, opt_d, total, loss_d=None) -> None:
    """One simultaneous update: D's gradient first (``loss_d``, where there is a D), the graph kept for the
    generator's (``total``); each loss flows only into the weights its own optimiser steps."""
    opt_g.zero_grad(set_to_none=True)
    if opt_d is not None:
        opt_d.zero_grad(set_to_none=True)
        loss_d.backward(inputs=[p for g in opt_d.param_groups for p in g["params"]], retain_graph=True)
    total.backward(inputs=[p for g in opt_g.param_groups for p in g["params"]])
    opt_g.step()
    if opt_d is not None:
        opt_d.step()


def run(cfg, run_dir) -> dict:
    """Train and evaluate in ``run_dir``, which this process holds (``run_dir/.lock``) while it runs."""
    check_config(cfg)
    lock = RunLock(run_dir).acquire()
    try:
        return train_and_evaluate(cfg, Path(run_dir))
    finally:
        lock.release()


@dataclass
class Training:
    """What a run's set-up hands the loop: the data and its budget, the networks and optimisers, where the run
    stands (``step``, ``wall``: training seconds), the log, and the fixed validation batch with its trivial
    baselines beside it."""

    cfg: object
    run_dir: Path
    device: torch.device
    data: object
    steps_per_epoch: int
    total_steps: int
    model: torch.nn.Module
    disc: torch.nn.Module | None
    opt_g: torch.optim.Optimizer
    opt_d: torch.optim.Optimizer | None
    log: MetricsLog
    trivial: dict | None
    val_batch: dict | None = None
    val_trivial: dict = field(default_factory=dict)
    step: int = 0
    wall: float = 0.0
    last_saved: int = 0

    @property
    def ckpt_path(self) -> Path:
        return self.run_dir / "checkpoints" / "last.pt"


def train_and_evaluate(cfg, run_dir: Path) -> dict:
    """Set up (data, networks, resume), train, then evaluate the final model into ``eval.json``."""
    s = set_up(cfg, run_dir)
    stopped, batch = train_loop(s)
    return finish(s, stopped, batch)


def set_up(cfg, run_dir: Path) -> Training:
    """Threads and seed, the run's revision and machine, the training data and its step budget, the validation
    batch, the trivial baselines, the networks and optimisers, and the state of a run resumed in its folder (or the
    weights it warm-starts from)."""
    t = cfg.train
    if t.threads:
        torch.set_num_threads(t.threads)
    if t.get("malloc_tuning", True):
        tune_malloc()
    torch.manual_seed(cfg.seed)
    device = torch.device(cfg.device)
    fmt = torch.channels_last if t.channels_last else torch.contiguous_format
    write_git_revision(run_dir)
    (run_dir / "machine.json").write_text(json.dumps(machine_info(device, t.threads), indent=1))
    log = MetricsLog(run_dir / "metrics.jsonl", run_dir / "tensorboard" if t.get("tensorboard", True) else None)

    data = make_dataset(cfg.data, "train", cfg.data.get("train_size"))
    steps_per_epoch = len(data) // t.batch_size
    if steps_per_epoch == 0:
        raise ConfigError(
            f"train.batch_size={t.batch_size} exceeds the {len(data)} training images (data.train_size"
            + ("; a small photo folder: data.split_by=all" if cfg.data.get("name") == "folder" else "")
            + ")"
        )
    total_steps = steps_per_epoch * t.epochs if t.max_steps is None else min(t.max_steps, steps_per_epoch * t.epochs)
    val_every, val_size = t.get("val_every", 0), t.get("val_size", 64)
    val_batch = None
    if val_every and val_every <= total_steps:  # rendered once, before the prefetch thread starts using the data code
        val_data = make_dataset(cfg.data, "val", val_size)
        keys = (*TRAIN_KEYS, "normal", "matte", "albedo", "sh")
        val_batch = to_device(get_batch(val_data, range(min(val_size, len(val_data))), keys), device, t.channels_last)
    trivial = trivial_baselines(data)  # constant estimates, scored beside the network in val records and eval.json
    val_trivial = {}
    if val_batch is not None and trivial is not None and "matte" in val_batch:
        val_trivial = trivial_metrics(trivial, {k: v.cpu() for k, v in val_batch.items()})

    model = build_model(cfg.model).to(device, memory_format=fmt)
    disc = build_discriminator(model).to(device, memory_format=fmt) if cfg.loss.weights.adv else None
    if t.get("compile", False):
        compile_networks(model, disc)
    s = Training(
        *(cfg, run_dir, device, data, steps_per_epoch, total_steps, model, disc, make_optimizer(model, t)),
        *(make_optimizer(disc, t) if disc is not None else None, log, trivial, val_batch, val_trivial),
    )
    resume = Path(cfg.resume) if cfg.resume else (s.ckpt_path if s.ckpt_path.exists() else None)
    if resume is not None:
        resume_from(s, resume)
    elif cfg.get("init"):
        warm_start(model, cfg)
    s.last_saved = s.step
    return s


def resume_from(s: Training, resume: Path) -> None:
    """Load a checkpoint (``resume``: a run folder or a checkpoint file) into ``s``: weights, optimisers, step,
    training seconds and RNG state; the log drops what it wrote after that step.  A checkpoint of other settings
    stops the run (``resume_force=true`` overrides)."""
    cfg = s.cfg
    ck = load_checkpoint(resume / "checkpoints" / "last.pt" if resume.is_dir() else resume, fallback=True)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    diffs = config_differences(ck.get("cfg"), resolved, ignore=idle_settings(resolved))
    if diffs and not cfg.get("resume_force", False):
        raise ConfigError(
            f"{resume} was trained with other settings ({'; '.join(diffs[:6])}"
            f"{' ...' if len(diffs) > 6 else ''}); start in a new folder, or pass resume_force=true"
        )
    s.model.load_state_dict(ck["model"])
    s.opt_g.load_state_dict(ck["opt_g"])
    if s.disc is not None:
        s.disc.load_state_dict(ck["disc"])
        s.opt_d.load_state_dict(ck["opt_d"])
    s.step, s.wall = ck["step"], ck["wall"]
    set_rng_state(ck["rng"])
    s.log.truncate_after(s.step)
    print(f"resumed from {ck.get('loaded_from', resume)} at step {s.step}")


def last_good(s: Training) -> str:
    """Where a stopped run can continue from."""
    if s.ckpt_path.exists():
        return (
            f"Last good checkpoint: {s.ckpt_path} (step {s.last_saved}); to continue from it, start again in "
            f"{s.run_dir} (hydra.run.dir=...) with a smaller train.lr"
        )
    return f"No checkpoint was written yet; start again with a smaller train.lr (now {s.cfg.train.lr})"


def checkpoint(s: Training) -> None:
    """``checkpoints/last.pt`` (atomically, :func:`disent.storage.save_checkpoint`); weights that became
    non-finite are never saved as good."""
    bad = nonfinite_tensors(s.model, s.disc)
    if bad:  # the losses were finite, the update was not: never save such weights as good
        raise NonFiniteLoss(
            f"weights became non-finite by step {s.step} ({', '.join(bad[:4])}"
            f"{' ...' if len(bad) > 4 else ''}: 0 = model, 1 = D); stopped, not saved. {last_good(s)}"
        )
    state = {"model": s.model.state_dict(), "opt_g": s.opt_g.state_dict()}
    state |= {"disc": s.disc.state_dict() if s.disc is not None else None}
    state |= {"opt_d": s.opt_d.state_dict() if s.opt_d is not None else None}
    state |= {"step": s.step, "epoch": s.step / s.steps_per_epoch, "wall": s.wall, "rng": rng_state()}
    save_checkpoint(s.ckpt_path, state | {"cfg": OmegaConf.to_container(s.cfg, resolve=True)})


def batch_maker(s: Training):
    """``step -> batch`` where the data renders (``data.device``; the prefetch threads run it): the step's seeded
    slice of its epoch's order, with E_recon-L's target fitted where the setting fits it (once per training image)."""
    cfg, t = s.cfg, s.cfg.train
    keys = train_keys(cfg.loss)
    target, fit = loss_setting(cfg.loss, "recon_L_target"), target_fit(cfg.loss)  # where the trainer fits it
    fitted_lights = {}  # data index -> its fitted E_recon-L target

    def make_batch(step):
        idx = step_indices(cfg.seed, step, s.steps_per_epoch, t.batch_size, len(s.data))
        batch = get_batch(s.data, idx, keys)
        if fit:
            batch = with_fitted_lhat(batch, idx, fitted_lights, target, fit)
        batch = to_device(batch, batch["image"].device, t.channels_last)  # where it was rendered (data.device)
        if batch["image"].is_cuda:  # rendered on this thread's stream: done before the step's stream reads it
            torch.cuda.current_stream().synchronize()
        return batch

    return make_batch


def stop_reason(s: Training) -> str:
    """Why the loop stops before its last step (``time_limit``, ``stop_step``), or ``steps``."""
    t = s.cfg.train
    if t.time_limit_min and s.wall > 60 * t.time_limit_min:  # budget spent: keep what we have, evaluate
        return "time_limit"
    if t.get("stop_step") and s.step >= t.stop_step:  # a replayed time-guard stop: the schedule is unchanged
        return "stop_step"
    return "steps"


def train_loop(s: Training) -> tuple[str, dict | None]:
    """The steps from where the run stands to ``total_steps`` (or its time guard): each on a prefetched batch at
    the scheduled learning rate, logged every ``train.log_every`` steps, validated every ``train.val_every``,
    checkpointed every ``train.checkpoint_every`` and at each epoch's end.  Returns why it stopped and its last
    batch."""
    t = s.cfg.train
    prefetch = Prefetcher(
        batch_maker(s), range(s.step, s.total_steps), t.get("prefetch", 0), t.get("prefetch_workers", 1)
    )
    bar = tqdm(total=s.total_steps, initial=s.step, disable=not t.progress, unit="step", dynamic_ncols=True)
    stopped, batch = "steps", None
    try:
        while s.step < s.total_steps:
            if (stopped := stop_reason(s)) != "steps":
                checkpoint(s)
                break
            epoch = s.step // s.steps_per_epoch
            lr = learning_rate(t, s.step, s.steps_per_epoch, s.total_steps)
            set_learning_rate(lr, s.opt_g, s.opt_d)
            t0 = time.perf_counter()
            batch = used_here(to_device(prefetch.get(s.step), s.device, t.channels_last))
            with autocast(s.device, t.get("amp", False)):  # the shading layer stays float32
                losses = train_step(s.model, s.disc, s.opt_g, s.opt_d, batch, s.cfg.loss, s.step)
            if "nonfinite" in losses:
                raise NonFiniteLoss(
                    f"loss term {', '.join(repr(k) for k in losses['nonfinite'])} is not finite at step {s.step} "
                    f"(epoch {epoch}); stopped. {last_good(s)}"
                )
            dt = time.perf_counter() - t0
            s.wall += dt
            s.step += 1
            ips = len(batch["image"]) / dt
            bar.update(1)
            if t.progress:  # .item() waits for the step's GPU work: not with the bar off (device=cuda runs)
                bar.set_postfix(loss=f"{losses['total'].item():.4f}", img_s=f"{ips:.0f}", epoch=epoch)
            after_step(s, epoch, lr, ips, losses, batch)
    finally:
        prefetch.close()
        bar.close()
        s.log.close()
    return stopped, batch


def due(s: Training) -> dict:
    """What follows step ``s.step`` (just taken): its log record, the validation record, a sample grid, a checkpoint."""
    t, step = s.cfg.train, s.step
    return {
        "log": step % t.log_every == 0 or step == s.total_steps,
        "val": s.val_batch is not None and step % t.get("val_every", 0) == 0,
        "sample": bool(t.sample_every) and step % t.sample_every == 0,
        "checkpoint": step % t.checkpoint_every == 0 or step % s.steps_per_epoch == 0 or step == s.total_steps,
    }


def after_step(s: Training, epoch: int, lr: float, ips: float, losses: dict, batch: dict) -> None:
    """What follows a step, each when due (:func:`due`)."""
    step, now = s.step, due(s)
    if now["log"]:
        record = {"step": step, "epoch": epoch, "wall": s.wall, "lr": lr, "images_per_s": ips}
        s.log.write(record | {k: v.item() for k, v in losses.items()})
    if now["val"]:  # wall: training seconds only
        t1 = time.perf_counter()
        val = validate(s.model, s.val_batch)
        n, seconds = len(s.val_batch["image"]), time.perf_counter() - t1
        val = {**val, **s.val_trivial, "n": n, "seconds": seconds}
        s.log.write({"step": step, "epoch": epoch, "wall": s.wall, "minutes": s.wall / 60, "val": val})
    if now["sample"]:
        save_samples(s.run_dir / "samples" / f"step{step:06d}.png", batch, s.model(batch["image"]))
    if now["checkpoint"]:
        checkpoint(s)
        s.last_saved = step


def finish(s: Training, stopped: str, batch: dict | None) -> dict:
    """The final sample grid, the test metrics beside the trivial baselines (``eval.json``, the log's last record)
    and the run's summary printed."""
    t = s.cfg.train
    s.model.eval()
    if batch is None:  # no step ran in this process (a resumed run that was already done)
        keys = train_keys(s.cfg.loss)
        batch = to_device(get_batch(s.data, range(min(8, len(s.data))), keys), s.device, t.channels_last)
    with torch.no_grad():
        save_samples(s.run_dir / "samples" / "final.png", batch, s.model(batch["image"]))
    metrics = {
        **evaluate(s.model, s.cfg, t.eval_size, s.trivial),
        "steps": s.step,
        "stopped_by": stopped,
        "train_seconds": s.wall,
    }
    s.log.write({"step": s.step, "epoch": s.step / s.steps_per_epoch, "wall": s.wall, "eval": metrics})
    s.log.close()
    (s.run_dir / "eval.json").write_text(json.dumps(metrics, indent=2))
    print_eval(metrics, s.run_dir)
    return metrics

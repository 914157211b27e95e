"""The training recipe's moving parts: the optimisers (``train.optimizer``), the learning-rate schedule
(``train.schedule`` after ``train.warmup_steps``), the loss weights by step (``loss.early_weights``), the EBGAN
discriminator built to match its generator, and the weights a run starts from (``init``: a warm start)."""

from __future__ import annotations

import math

import torch

from disent.config import OPTIMIZERS, SCHEDULES, check_init, loss_setting
from disent.models import Discriminator, checkpoint_path
from disent.models.shipped import load_weights
from disent.storage import load_checkpoint


def learning_rate(t, step: int, steps_per_epoch: int, total_steps: int) -> float:
    """``train.lr`` after a linear warm-up of ``train.warmup_steps``, then ``train.schedule``: ``epoch_decay``
    (the release: x ``train.lr_decay`` per epoch) or ``cosine`` (half a cosine from lr to 0 over the run's steps)."""
    schedule = t.get("schedule", "epoch_decay")
    if schedule not in SCHEDULES:
        raise ValueError(f"train.schedule={schedule!r}; choose from {', '.join(SCHEDULES)}")
    warm = min(1.0, (step + 1) / max(t.warmup_steps, 1))
    if schedule == "cosine":
        return t.lr * warm * 0.5 * (1 + math.cos(math.pi * step / max(total_steps, 1)))
    return t.lr * warm * t.lr_decay ** (step // steps_per_epoch)


def make_optimizer(module, cfg_train) -> torch.optim.Optimizer:
    """``train.optimizer`` (rmsprop as in the release, or adam) over ``module``'s parameters (or a list of
    tensors: stacked models' weights, :mod:`disent.stack`) at ``train.lr``."""
    name = cfg_train.get("optimizer", "rmsprop")
    if name not in OPTIMIZERS:
        raise ValueError(f"train.optimizer={name!r}; choose from {', '.join(OPTIMIZERS)}")
    params = module.parameters() if isinstance(module, torch.nn.Module) else module
    return OPTIMIZERS[name](params, lr=cfg_train.lr)


def build_discriminator(model) -> Discriminator:
    """The EBGAN discriminator, with the generator's layer choices (normalisation, input centring)."""
    return Discriminator(model.resolution, layers=model.layers)


def set_learning_rate(lr: float, *optimizers) -> None:
    """``lr`` in every parameter group of ``optimizers`` (None skipped): the step's scheduled rate."""
    for opt in optimizers:
        for g in opt.param_groups if opt is not None else []:
            g["lr"] = lr


def autocast(device, enabled: bool):
    """bfloat16 mixed precision, as ``train.amp`` (no loss scaling needed); the shading layer stays float32."""
    return torch.autocast(torch.device(device).type, dtype=torch.bfloat16, enabled=enabled)


def loss_weights(cfg_loss, step: int) -> dict:
    """``loss.weights`` at ``step``: ``loss.early_weights`` in place of theirs for the first ``loss.early_steps``."""
    weights = dict(cfg_loss.weights)
    if step < loss_setting(cfg_loss, "early_steps"):
        weights.update(loss_setting(cfg_loss, "early_weights") or {})
    return weights


def warm_start(model, cfg) -> None:
    """Load the model weights of ``cfg.init`` (a run folder, checkpoint or shipped name) into ``model``; its model
    settings must be ``cfg.model``'s (:func:`disent.config.check_init`)."""
    path = checkpoint_path(cfg.init)
    ck = load_checkpoint(path)
    check_init(cfg, ck.get("cfg"))
    load_weights(model, ck["model"], path)  # a shipped model's half precision is cast back on loading
    print(f"warm start from {path}")

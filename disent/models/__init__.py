"""The three models of the paper and the EBGAN discriminator.

``build_model(cfg_model)`` builds ``baseline``, ``explicit`` or ``implicit`` from the Hydra
``model`` group.  ``model(image)`` returns a dict with ``recon [B,3,H,W]`` and ``codes``; the
explicit and implicit models add ``foreground, background, matte, albedo, shading, normal, sh``,
and the implicit one ``uv, normal_uv, albedo_uv``.  ``codes`` holds the latent codes by paper
name (``bg, m, L, Ne, Ae`` / ``bg, m, L, UV, Ni, Ai`` / ``z``) and, for the rendering models,
the encoder's pooling ``switches`` that the background and matte decoders unpool with.
``model.decode(codes)`` re-renders edited codes.
"""

from __future__ import annotations

from pathlib import Path

import torch

from disent.models.baseline import Baseline
from disent.models.discriminator import Discriminator
from disent.models.explicit import Explicit
from disent.models.implicit import Implicit

MODELS = {"baseline": Baseline, "explicit": Explicit, "implicit": Implicit}


def build_model(cfg_model) -> torch.nn.Module:
    """``cfg_model``: mapping with ``name`` and that model's constructor arguments."""
    kwargs = dict(cfg_model)
    name = kwargs.pop("name")
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; choose from {', '.join(MODELS)}")
    return MODELS[name](**kwargs)


def checkpoint_path(path) -> Path:
    """The checkpoint of a run folder (its ``checkpoints/last.pt``), a checkpoint file, or a shipped name."""
    from disent.models.shipped import shipped_path

    path = Path(path)
    if not path.exists():
        return shipped_path(str(path))
    ckpt_path = path / "checkpoints" / "last.pt" if path.is_dir() else path
    if not ckpt_path.exists():
        raise FileNotFoundError(f"no checkpoint at {ckpt_path}")
    return ckpt_path


def load_run(path):
    """``(model, cfg)`` from a run folder (its ``checkpoints/last.pt``), a checkpoint file, or the name of a
    shipped model (``explicit``, ``implicit``, ``baseline``: :mod:`disent.models.shipped`).

    The model is in eval mode, with ``trained_steps`` the step its weights were saved at (None where the
    checkpoint does not say) and ``shipped`` whether ``path`` named a shipped model; ``cfg`` is the run's
    resolved OmegaConf config.  An unknown name lists the shipped ones; a checkpoint that does not fit this
    code's architecture names the mismatch, and one that cannot be read names the file
    (:func:`disent.storage.load_checkpoint`).
    """
    from omegaconf import OmegaConf

    from disent.models.shipped import load_weights, manifest
    from disent.storage import load_checkpoint

    ckpt_path = checkpoint_path(path)
    ckpt = load_checkpoint(ckpt_path)
    cfg = OmegaConf.create(ckpt["cfg"])
    model = build_model(cfg.model)
    load_weights(model, ckpt["model"], ckpt_path)
    model.shipped = not Path(path).exists()  # a shipped model's name (disent/weights/), its steps in the manifest
    model.trained_steps = ckpt.get("step", manifest()[str(path)]["steps"] if model.shipped else None)
    return model.eval(), cfg


__all__ = [
    "build_model",
    "load_run",
    "checkpoint_path",
    "MODELS",
    "Baseline",
    "Explicit",
    "Implicit",
    "Discriminator",
]

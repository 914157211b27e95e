"""Trained weights shipped inside the package, so that every tool works on a trained model from a fresh install.

``disent/weights/<name>.pt`` holds a float16 state dict and the run's resolved config;
``disent/weights/manifest.json`` holds, per name: the file's size and SHA-256, the run's config, git
revision, test metrics (its ``eval.json``), training steps and seconds, the machine it trained on, and
``check``: metrics of the shipped (float16) weights on the first ``CHECK_IMAGES`` test images, which
``tests/test_shipped.py`` recomputes.

    python -m disent.models.shipped RUN_DIR NAME     # ship a finished run as NAME (disent.ship)
    python -m disent.models.shipped NAME --add-metrics   # score it with this version's metrics, add what it lacks
    load_run("explicit")                             # disent.models.load_run takes a shipped name

This module only reads them (a leaf of the core); shipping and rescoring are :mod:`disent.ship`.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

WEIGHTS = Path(__file__).resolve().parents[1] / "weights"
CHECK_IMAGES = 64
CHECK_KEYS = ("recon_psnr", "normal_mean", "albedo_si_mse", "sh_error")


def manifest(folder: Path = WEIGHTS) -> dict:
    path = Path(folder) / "manifest.json"
    return json.loads(path.read_text()) if path.exists() else {}


def shipped_names(folder: Path = WEIGHTS) -> list[str]:
    return sorted(manifest(folder))


def shipped_path(name: str, folder: Path = WEIGHTS) -> Path:
    """The checkpoint file of shipped model ``name``; an error listing the shipped names if there is none."""
    entry = manifest(folder).get(name)
    if entry is None:
        raise FileNotFoundError(
            f"{name!r} is neither a run folder, a checkpoint file nor a shipped model; "
            f"shipped models: {', '.join(shipped_names(folder)) or 'none'}"
        )
    return Path(folder) / entry["file"]


def load_weights(model: torch.nn.Module, state: dict, source) -> None:
    """``model.load_state_dict(state)`` that names what does not match instead of a raw traceback."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = [
        f"{k}: checkpoint {tuple(state[k].shape)} vs model {tuple(v.shape)}"
        for k, v in own.items()
        if k in state and tuple(state[k].shape) != tuple(v.shape)
    ]
    if missing or unexpected or shapes:
        parts = (
            [f"missing in the checkpoint: {', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}"]
            if missing
            else []
        )
        parts += (
            [f"not in the model: {', '.join(unexpected[:6])}{' ...' if len(unexpected) > 6 else ''}"]
            if unexpected
            else []
        )
        parts += [f"shape mismatch: {'; '.join(shapes[:4])}"] if shapes else []
        raise ValueError(
            f"the checkpoint {source} does not match the model its config builds with this code "
            f"({'; '.join(parts)}); it was written by another version of disent"
        )
    model.load_state_dict(state)


if __name__ == "__main__":  # python -m disent.models.shipped: the tool that ships weights is disent.ship
    from disent.ship import main

    main()

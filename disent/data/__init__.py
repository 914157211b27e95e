"""Data: the embedded synthetic faces and real photos, each with the same keys where they exist.

- :mod:`disent.data.synth`: SynthFaces, rendered here with full ground truth and pseudo ground truth
  (``scenes`` the generator, ``face_model`` its mesh, ``raster`` the rasterizer, ``sheet`` a contact sheet).
- :mod:`disent.data.photos`: a folder of real photos (``folder``) with pseudo ground truth from landmarks and
  the project's face model (``pseudo_gt``), and the study of the bundled photos (``study``).

``make_dataset(cfg_data, split, size)`` makes the data set a ``conf/data`` node names; :func:`get_batch` stacks
items of any of them.
"""

from __future__ import annotations

import torch
from omegaconf import OmegaConf

from disent.data.attributes import ATTRIBUTES
from disent.data.synth import ATTR_PRIOR, EFFECTS, LIGHT_BANK, LIGHT_NAMES, SPLITS, SynthFaces

DATASETS = ("synth", "folder")  # conf/data/<name>.yaml


def make_dataset(cfg_data, split: str, size: int | None = None, device=None):
    """The data set named by ``data.name``: SynthFaces (``synth``) or a folder of photos (``folder``).  SynthFaces
    renders on ``device``, by default ``data.device`` (training's batches; evaluation asks for the CPU)."""
    if cfg_data.name == "synth":
        effects = OmegaConf.to_container(cfg_data.effects) if cfg_data.get("effects") else None
        device = device or cfg_data.get("device", "cpu")
        return SynthFaces(split, cfg_data.resolution, cfg_data.seed, size, effects, device=device)
    if cfg_data.name == "folder":
        from disent.data.photos.folder import build as build_folder

        return build_folder(cfg_data, split, size)
    raise ValueError(f"data.name={cfg_data.name!r}; choose from {', '.join(DATASETS)}")


def collate(items: list[dict]) -> dict:
    """Items stacked into a batch: their tensors, and nested dicts of numbers (``attrs``) key by key."""
    out = {}
    for k, v in items[0].items():
        if isinstance(v, dict):
            out[k] = {a: torch.stack([torch.as_tensor(it[k][a]) for it in items]) for a in v}
        elif torch.is_tensor(v):
            out[k] = torch.stack([it[k] for it in items])
    return out


def get_batch(dataset, indices, keys=None, chunk: int = 256, **overrides) -> dict:
    """The items ``indices`` of ``dataset`` as one batch (only ``keys``, when given).

    A data set with a vectorized ``get_batch`` (SynthFaces) renders them together, ``chunk`` at a time, with
    generator ``overrides`` (``pose=``, ``sh=`` shared ``[3,9]`` or per item ``[B,3,9]``, ...); one with only
    ``sample(index, **overrides)`` renders them one by one; any other stacks its items.
    """
    indices = [int(i) for i in indices]
    if hasattr(dataset, "get_batch"):
        parts = [dataset.get_batch(indices[i : i + chunk], **overrides) for i in range(0, len(indices), chunk)]
        batch = (
            parts[0]
            if len(parts) == 1
            else {
                k: (
                    {a: torch.cat([p[k][a] for p in parts]) for a in v}
                    if isinstance(v, dict)
                    else torch.cat([p[k] for p in parts])
                )
                for k, v in parts[0].items()
            }
        )
    elif overrides and hasattr(dataset, "sample"):
        sh = overrides.pop("sh", None)
        per_item = sh is not None and sh.dim() == 3
        batch = collate(
            [
                dataset.sample(i, **overrides, **({} if sh is None else {"sh": sh[j] if per_item else sh}))
                for j, i in enumerate(indices)
            ]
        )
    elif overrides:
        raise ValueError(f"{type(dataset).__name__} cannot re-render its items with {', '.join(overrides)}")
    else:
        batch = collate([dataset[i] for i in indices])
    return batch if keys is None else {k: batch[k] for k in keys if k in batch}


def epoch_order(seed: int, epoch: int, n: int) -> torch.Tensor:
    """The training order of epoch ``epoch``: a permutation of the ``n`` images seeded by (seed, epoch), so a
    resumed run replays exactly the steps it missed."""
    return torch.randperm(n, generator=torch.Generator().manual_seed(seed * 100_003 + epoch))


def step_indices(seed: int, step: int, steps_per_epoch: int, batch_size: int, n: int) -> torch.Tensor:
    """The data indices of training step ``step`` (0-based): its slice of its epoch's permutation."""
    epoch, i = divmod(step, steps_per_epoch)
    return epoch_order(seed, epoch, n)[i * batch_size : (i + 1) * batch_size]


def to_device(batch: dict, device, channels_last: bool) -> dict:
    """A batch's tensors on ``device``; images (4-D) in channels-last memory order where asked."""
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    return {k: (v.to(device).contiguous(memory_format=fmt) if v.dim() == 4 else v.to(device)) for k, v in batch.items()}


__all__ = [
    "ATTRIBUTES",
    "ATTR_PRIOR",
    "EFFECTS",
    "LIGHT_BANK",
    "LIGHT_NAMES",
    "SPLITS",
    "SynthFaces",
    "make_dataset",
    "collate",
    "get_batch",
    "epoch_order",
    "step_indices",
    "to_device",
]

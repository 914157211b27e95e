"""SynthFaces: the embedded synthetic face dataset, with full and pseudo ground truth.

    from disent.data import SynthFaces
    ds = SynthFaces("train", resolution=64, seed=0)
    item = ds[0]                          # dict of float32 tensors, channels first
    batch = ds.get_batch(range(64))       # the same items, rendered as one vectorized batch
    relit = ds.sample(0, sh=LIGHT_BANK["flash_az-45"])   # item 0 under another light

Splits (default sizes, settable with ``size``):

* ``train`` 20,000 / ``val`` 1,000 / ``test`` 1,000: 4 (train) or 2 (val/test) images per
  identity, identities disjoint across splits; attributes drawn from ``ATTR_PRIOR``.
* ``lightbank``: every identity (50) x pose (3: yaw -30, 0, +30) x light of ``LIGHT_BANK``
  (24), the Multi-PIE protocol; index = (identity * 3 + pose) * 24 + light.
* ``pool_<attr>`` (``pool_smiling``, ``pool_beard``, ``pool_eyeglasses``, ``pool_senior``):
  4,000 images, one identity each, even indices positive and odd negative for ``<attr>``.

An item is a pure function of (seed, split, index); DataLoader batches are rendered
together through ``__getitems__``, and sequential ``__getitem__`` is served from a small
cache of rendered chunks.
"""

from __future__ import annotations

from collections import OrderedDict
from contextlib import nullcontext

import torch
from torch.utils.data import Dataset

from disent.runtime import moved, single_thread

from .scenes import (
    ATTR_PRIOR,
    ATTRIBUTES,
    EFFECTS,
    LIGHT_BANK,
    LIGHT_NAMES,
    attribute_labels,
    render_scenes,
    scene_params,
)

SPLITS = {"train": 20_000, "val": 1_000, "test": 1_000, "lightbank": None, **{f"pool_{a}": 4_000 for a in ATTRIBUTES}}
LIGHTBANK_IDENTITIES = 50
LIGHTBANK_POSES = ((-30.0, 0.0, 0.0), (0.0, 0.0, 0.0), (30.0, 0.0, 0.0))
IMAGES_PER_IDENTITY = {"train": 4, "val": 2, "test": 2}
_SPLIT_CODE = {name: k + 1 for k, name in enumerate(SPLITS)}
_ID_OFFSET = 10**8  # identity ids of split k start at k * _ID_OFFSET: disjoint across splits
RESOLUTIONS = (64, 128)
CHUNK = 64


class SynthFaces(Dataset):
    """Synthetic faces with ground-truth normal, albedo, SH light, matte, UV and pseudo-GT.

    Args:
        split: ``train``, ``val``, ``test``, ``lightbank`` or ``pool_<attr>``.
        resolution: 64 (the paper's) or 128.
        seed: fixes every number of the dataset.
        size: number of items (default per split, see the module docstring).
        effects: optional ``{name: severity in [0,1]}`` over ``specular``,
            ``cast_shadow``, ``noise``, ``occluder`` (default: none, the paper's image model).
        cache_chunks: rendered chunks of ``CHUNK`` items kept for ``__getitem__``.
        device: where batches are rendered (``cpu``, ``cuda``, ...).  The scene parameters are drawn on the CPU
            either way, so the seeded faces are the same; a batch rendered on a GPU equals the CPU's to float
            rounding (``tests/test_data.py`` states the tolerance).
    """

    def __init__(
        self,
        split: str = "train",
        resolution: int = 64,
        seed: int = 0,
        size: int | None = None,
        effects: dict | None = None,
        cache_chunks: int = 4,
        device: str | torch.device = "cpu",
    ):
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; choose from {', '.join(SPLITS)}")
        if resolution not in RESOLUTIONS:
            raise ValueError(f"resolution must be one of {RESOLUTIONS}, got {resolution}")
        if effects:
            unknown = set(effects) - set(EFFECTS)
            if unknown:
                raise ValueError(f"unknown effects {sorted(unknown)}; choose from {EFFECTS}")
        self.split, self.resolution, self.seed = split, resolution, int(seed)
        self.effects = dict(effects or {})
        full = len(LIGHT_NAMES) * LIGHTBANK_IDENTITIES * len(LIGHTBANK_POSES) if split == "lightbank" else SPLITS[split]
        self.size = full if size is None else int(size)
        if self.size <= 0:
            raise ValueError(f"size must be positive, got {size}")
        self._cache: OrderedDict[int, dict] = OrderedDict()
        self._cache_chunks = cache_chunks
        self.device = torch.device(device)

    def __len__(self) -> int:
        return self.size

    # --------------------------------------------------------------------- parameters
    def _check(self, indices) -> torch.Tensor:
        idx = torch.as_tensor(list(indices) if not torch.is_tensor(indices) else indices, dtype=torch.long).flatten()
        if idx.numel() == 0:
            raise ValueError("no indices")
        if (idx < 0).any() or (idx >= self.size).any():
            raise IndexError(f"indices must lie in [0, {self.size}) for split {self.split!r}")
        return idx

    def params(self, indices, **overrides) -> dict:
        """Generator parameters of ``indices`` (see :func:`disent.data.synth.scenes.scene_params`),
        with any of ``sh``, ``pose``, ``scale``, ``shift``, an attribute strength
        (``smiling=0.8``...) or ``light`` (a ``LIGHT_BANK`` name) replaced."""
        idx = self._check(indices)
        code = _SPLIT_CODE[self.split]
        key = (code << 40) | idx
        labels = None
        if self.split == "lightbank":
            per_id = len(LIGHTBANK_POSES) * len(LIGHT_NAMES)
            identity = code * _ID_OFFSET + idx // per_id
            key = (code << 40) | (idx // len(LIGHT_NAMES))  # background, expression: fixed across lights
        elif self.split.startswith("pool_"):
            identity = code * _ID_OFFSET + idx
            labels = {self.split[5:]: (idx % 2 == 0)}
        else:
            identity = code * _ID_OFFSET + idx // IMAGES_PER_IDENTITY[self.split]
        with single_thread():
            p = scene_params(key, identity, self.seed, labels)
        if self.split == "lightbank":
            light = idx % len(LIGHT_NAMES)
            pose = torch.tensor(LIGHTBANK_POSES)[(idx // len(LIGHT_NAMES)) % len(LIGHTBANK_POSES)]
            self._set_light(p, light)
            delta = pose - p["pose"]
            p["pose"], p["pseudo_pose"] = pose, p["pseudo_pose"] + delta
        return _override(p, **overrides)

    @staticmethod
    def _set_light(p: dict, light_id: torch.Tensor) -> None:
        from .scenes import _BANK_SH

        p["sh"] = _BANK_SH[light_id]
        p["light_id"] = light_id.long()

    # --------------------------------------------------------------------- rendering
    def get_batch(self, indices, effects: dict | None = None, **overrides) -> dict:
        """Render ``indices`` as one vectorized batch: the collated dict of items."""
        p = self.params(indices, **overrides)
        eff = self.effects if effects is None else effects
        on_device = nullcontext()
        if self.device.type != "cpu":  # drawn on the CPU, rendered where the model trains (every tensor made there)
            p, on_device = moved(p, self.device), torch.device(self.device)
        with single_thread(), on_device:
            out = render_scenes(p, self.resolution, effects=eff)
        out = {k: v.float().contiguous() for k, v in out.items()}
        out["attrs"] = {}
        for a, label in attribute_labels(p).items():
            out["attrs"][a] = label.float()
            out["attrs"][f"{a}_strength"] = p[a].float()
        out["identity"] = p["identity"].long()
        out["light_id"] = p["light_id"].long()
        out["pose"] = p["pose"].float()
        return out

    def sample(self, index: int, effects: dict | None = None, **overrides) -> dict:
        """Item ``index`` with generator parameters replaced (ground truth under controlled changes):
        ``sh=[3,9]``, ``pose=(yaw, pitch, roll)``, ``light=<LIGHT_BANK name>``, attribute
        strengths (``smiling=1.0``, ``beard=0.0``...), ``scale``, ``shift``, ``effects={...}``."""
        return _unbatch(self.get_batch([index], effects=effects, **overrides), 0)

    def __getitem__(self, index: int) -> dict:
        index = int(index)
        if not 0 <= index < self.size:
            raise IndexError(f"index {index} out of range for split {self.split!r} of size {self.size}")
        c = index // CHUNK
        if c not in self._cache:
            self._cache[c] = self.get_batch(range(c * CHUNK, min((c + 1) * CHUNK, self.size)))
            while len(self._cache) > self._cache_chunks:
                self._cache.popitem(last=False)
        self._cache.move_to_end(c)
        return _unbatch(self._cache[c], index - c * CHUNK)

    def __getitems__(self, indices: list) -> list:
        """DataLoader's batched fetch: one vectorized render for the whole batch."""
        batch = self.get_batch(indices)
        return [_unbatch(batch, k) for k in range(len(indices))]

    def __repr__(self) -> str:
        return (
            f"SynthFaces(split={self.split!r}, resolution={self.resolution}, seed={self.seed}, "
            f"size={self.size}, effects={self.effects or None}"
            + (f", device={str(self.device)!r})" if self.device.type != "cpu" else ")")
        )


def _override(p: dict, **overrides) -> dict:
    N = p["alpha"].shape[0]
    for k, v in overrides.items():
        if k == "sh":
            v = torch.as_tensor(v, dtype=torch.float32)
            if v.shape[-2:] != (3, 9):
                raise ValueError(f"sh must be [3,9] or [N,3,9], got {tuple(v.shape)}")
            p["sh"] = v.expand(N, 3, 9).clone()
            p["light_id"] = torch.full((N,), -1, dtype=torch.long)
        elif k == "light":
            if v not in LIGHT_BANK:
                raise ValueError(f"unknown light {v!r}; see LIGHT_BANK")
            SynthFaces._set_light(p, torch.full((N,), LIGHT_NAMES.index(v)))
        elif k == "pose":
            v = torch.as_tensor(v, dtype=torch.float32).expand(N, 3)
            p["pseudo_pose"] = p["pseudo_pose"] + (v - p["pose"])
            p["pose"] = v.clone()
        elif k in ("scale", "shift"):
            v = torch.as_tensor(v, dtype=torch.float32).expand_as(p[k])
            p[f"pseudo_{k}"] = p[f"pseudo_{k}"] * (v / p[k]) if k == "scale" else p[f"pseudo_{k}"] + (v - p[k])
            p[k] = v.clone()
        elif k in ATTRIBUTES:
            v = torch.as_tensor(v, dtype=torch.float32).expand(N).clone()
            if ((v < 0) | (v > 1)).any():
                raise ValueError(f"{k} strength must be in [0, 1]")
            p[k] = v
            if k == "smiling":  # the expression follows the smile; the mouth opens for a real smile
                fit_error = p["pseudo_expression"] - p["expression"]
                p["expression"] = torch.stack([v, torch.where(v >= 0.5, 0.7 * v, torch.zeros_like(v))], 1)
                p["pseudo_expression"] = (p["expression"] + fit_error).clamp(0, 1)
        else:
            raise ValueError(
                f"cannot override {k!r}; choose from sh, light, pose, scale, shift, {', '.join(ATTRIBUTES)}"
            )
    return p


def _unbatch(batch: dict, k: int) -> dict:
    return {n: ({a: t[k] for a, t in v.items()} if isinstance(v, dict) else v[k]) for n, v in batch.items()}


__all__ = ["SynthFaces", "LIGHT_BANK", "LIGHT_NAMES", "SPLITS", "ATTRIBUTES", "ATTR_PRIOR", "EFFECTS", "RESOLUTIONS"]

"""A texture model for the albedo that L-hat's constant-albedo assumption leaves out.

The paper's L-hat treats the albedo as constant.  Real albedo has texture (eyes, brows, lips,
hair, beard), and an i.i.d. noise model explains that structured misfit with extra SH terms,
so a constant-albedo order choice picks order 2 almost always.  A 3DMM fit comes with a
texture model (a mean and principal components in UV space); the pseudo ground truth gives
UV coordinates, so the pipeline has one too.  Here it is the PCA of SynthFaces *train*
albedos in UV space (no val/test image enters it), mapped into the image through ``uv``:

    albedo(p) = T_0(uv_p) + sum_j beta_j T_j(uv_p),   beta_j ~ N(0, lambda_j)   (PCA prior)
    I_c(p)   = albedo_c(p) * S(n_p, L_c) + e          (Eq. 2; the albedo's scale goes into L_c)

For a given lighting model the fit alternates least squares in L (albedo fixed) and ridge
least squares in beta (light fixed); :func:`disent.lighting.order.select_order` scores every
lighting candidate with its own fitted texture.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from disent.runs import atomic_write


@dataclass
class TextureModel:
    """Albedo texture in UV space: ``mean [3,R,R]``, ``components [J,3,R,R]`` (unit norm), ``variance [J]``."""

    mean: np.ndarray
    components: np.ndarray
    variance: np.ndarray

    @property
    def n_components(self) -> int:
        return len(self.variance)

    def truncate(self, n_components: int) -> "TextureModel":
        return TextureModel(self.mean, self.components[:n_components], self.variance[:n_components])

    def at_pixels(self, uv, index: np.ndarray) -> np.ndarray:
        """``[1 + J, P, 3]``: the mean and the components at the pixels ``index`` (flat, as in
        :class:`~disent.lighting.posterior.LightingData`) of a ``uv [2,H,W]`` map in [0, 1]."""
        uv = torch.as_tensor(uv).double()
        if uv.dim() != 3 or uv.shape[0] != 2:
            raise ValueError(f"need uv [2,H,W], got {tuple(uv.shape)}")
        maps = torch.from_numpy(np.concatenate([self.mean[None], self.components])).double()
        grid = (2 * uv - 1).permute(1, 2, 0)[None].expand(len(maps), -1, -1, -1)
        out = F.grid_sample(maps, grid, mode="bilinear", align_corners=True)  # [1+J, 3, H, W]
        return out.flatten(2)[:, :, torch.as_tensor(index)].permute(0, 2, 1).numpy().copy()


def _cache_path(resolution: int, n_images: int, seed: int) -> Path:
    """Keyed by the arguments and a fingerprint of the generator (the bytes of one rendered
    train albedo), so a changed SynthFaces never reuses a stale model."""
    from disent.data import SynthFaces

    probe = SynthFaces("train", resolution, seed).get_batch(range(1))["albedo_uv"].numpy().tobytes()
    root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "disent" / "lighting"
    return root / f"texture_{resolution}_{n_images}_{seed}_{hashlib.sha1(probe).hexdigest()[:12]}.npz"


@lru_cache(maxsize=4)
def texture_model(resolution: int = 64, n_components: int = 20, n_images: int = 512, seed: int = 0) -> TextureModel:
    """PCA of ``n_images`` SynthFaces train albedos in UV space (cached on disk: a pure function
    of the arguments and the generator)."""
    path = _cache_path(resolution, n_images, seed)
    if path.exists():
        with np.load(path) as z:
            full = TextureModel(z["mean"], z["components"], z["variance"])
    else:
        from disent.data import SynthFaces

        ds = SynthFaces("train", resolution, seed)
        albedo = torch.cat(
            [
                ds.get_batch(range(s, min(s + 128, n_images)))["albedo_uv"].double().flatten(1)
                for s in range(0, n_images, 128)
            ]
        )
        mean = albedo.mean(0)
        _, sv, v = torch.linalg.svd(albedo - mean, full_matrices=False)
        keep = min(64, len(sv))
        shape = (3, resolution, resolution)
        full = TextureModel(
            mean.reshape(shape).numpy(),
            v[:keep].reshape(keep, *shape).numpy(),
            (sv[:keep] ** 2 / (n_images - 1)).numpy(),
        )
        atomic_write(path, lambda f: np.savez(f, mean=full.mean, components=full.components, variance=full.variance))
    if n_components > full.n_components:
        raise ValueError(f"texture model has {full.n_components} components, asked for {n_components}")
    return full.truncate(n_components)


def texture_for(data, uv, n_components: int = 20) -> tuple:
    """``(pixels [1+J, P, C], variance [J])``: the texture model at the pixels of ``data``
    (:class:`~disent.lighting.posterior.LightingData`) through the ``uv [2,H,W]`` map, the
    ``texture`` argument of :func:`disent.lighting.order.select_order`."""
    model = texture_model(uv.shape[-1], n_components)
    return model.at_pixels(uv, data.index), model.variance


__all__ = ["TextureModel", "texture_model", "texture_for"]

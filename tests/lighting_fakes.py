"""Scenes and lights shared by the lighting tests."""

import numpy as np
import pytest
import torch

from disent.lighting.posterior import (
    prepare,
)
from disent.lighting.texture import TextureModel
from disent.render import sh_from_directions, sh_shading
from disent.runtime import single_core


@pytest.fixture(autouse=True)
def one_core():
    """numpy's BLAS threads spin against other work on a shared machine: one core, as the code targets."""
    with single_core():
        yield


def ellipsoid(H=32, W=32, a=0.8, b=1.0):
    """Normals of the camera-facing half of an ellipsoid and its mask (a face-like shape)."""
    y, x = torch.meshgrid(
        torch.linspace(1, -1, H, dtype=torch.float64), torch.linspace(-1, 1, W, dtype=torch.float64), indexing="ij"
    )
    r2 = (x / a) ** 2 + (y / b) ** 2
    mask = (r2 < 0.95).double()
    n = torch.stack([x / a**2, y / b**2, torch.sqrt((1 - r2).clamp_min(0))], 0)
    return torch.nn.functional.normalize(n, dim=0) * mask, mask[None]


def directional_light(direction, colour=(0.8, 0.7, 0.6), ambient=0.2):
    d = torch.tensor([direction], dtype=torch.float64)
    colour = torch.tensor([colour], dtype=torch.float64)
    return sh_from_directions(d, colour, ambient=ambient * colour[0])  # [3, 9]


def render(normal, sh, noise, seed=0):
    image = sh_shading(normal[None], sh[None])[0]
    g = torch.Generator().manual_seed(seed)
    return image + noise * torch.randn(image.shape, generator=g, dtype=torch.float64)


def textured_albedo(H, W, seed=0):
    g = torch.Generator().manual_seed(seed)
    return 0.3 + 0.6 * torch.rand(3, H, W, generator=g, dtype=torch.float64)


def feature_texture(R=32):
    """A texture model of dark features in UV space: hair (top band), beard (bottom band), eyes, lips."""
    t = torch.linspace(0, 1, R, dtype=torch.float64)
    v, u = torch.meshgrid(t, t, indexing="ij")
    blob = lambda cu, cv, r: torch.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * r * r))
    maps = torch.stack(
        [
            torch.sigmoid((0.3 - v) / 0.04),
            torch.sigmoid((v - 0.75) / 0.04),
            blob(0.33, 0.42, 0.05) + blob(0.67, 0.42, 0.05),
            blob(0.5, 0.7, 0.05),
        ]
    )
    comps = maps[:, None] * torch.tensor([1.0, 0.9, 0.8], dtype=torch.float64)[:, None, None]
    norms = comps.flatten(1).norm(dim=1)
    comps = comps / norms[:, None, None, None]
    return TextureModel(np.full((3, R, R), 0.7), comps.numpy(), 0.2 * norms.numpy() ** 2 / R**2)


def textured_scene(W_true, seed=0, H=32):
    """``(data, uv)``: an ellipsoid under an order-2 light whose albedo is :func:`feature_texture` seen through
    ``uv`` mapped by the affine ``W_true`` (what a misregistered pseudo uv would leave), with ``uv`` itself."""
    from disent.lighting.texture import affine

    normal, mask = ellipsoid(H, H)
    y, x = torch.meshgrid(
        torch.linspace(0, 1, H, dtype=torch.float64), torch.linspace(0, 1, H, dtype=torch.float64), indexing="ij"
    )
    uv = torch.stack([x, y])
    model = feature_texture()
    beta = -np.sqrt(model.variance) * 2.0
    albedo = torch.nn.functional.grid_sample(
        torch.from_numpy(model.mean + np.einsum("j,jchw->chw", beta, model.components))[None],
        (2 * affine(uv, W_true) - 1).permute(1, 2, 0)[None],
        align_corners=True,
    )[0]
    sh = directional_light([0.4, 0.3, 1.0])
    data = prepare(albedo * render(normal, sh, 0.0) + render(normal, 0 * sh, 0.005, seed), normal, mask)
    return data, uv, model

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

The pseudo ground truth's uv is itself misregistered: its eyes and brows land a few pixels off
(2.4 px rms at 64 px on SynthFaces train, 0.8 px of it left after the best affine map per face).
:func:`register` corrects it by the affine map that best registers the texture model to the
image, under a prior measured on train scenes, before any lighting model is scored.
"""

from __future__ import annotations

import hashlib
import os
import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from disent.storage import atomic_write


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

    @property
    def maps(self) -> np.ndarray:
        """``[1 + J, 3, R, R]``: the mean, then the components."""
        return np.concatenate([self.mean[None], self.components])

    def at_pixels(self, uv, index: np.ndarray, maps: np.ndarray | None = None) -> np.ndarray:
        """``[1 + J, P, 3]``: the mean and the components (or any ``maps [M, 3, R, R]``: ``[M, P, 3]``) at the
        pixels ``index`` (flat, as in :class:`~disent.lighting.posterior.LightingData`) of a ``uv [2,H,W]`` map
        in [0, 1]."""
        uv = torch.as_tensor(uv).double()
        if uv.dim() != 3 or uv.shape[0] != 2:
            raise ValueError(f"need uv [2,H,W], got {tuple(uv.shape)}")
        maps = torch.from_numpy(self.maps if maps is None else maps).double()
        grid = (2 * uv - 1).permute(1, 2, 0)[None].expand(len(maps), -1, -1, -1)
        out = F.grid_sample(maps, grid, mode="bilinear", align_corners=True)  # [M, 3, H, W]
        return out.flatten(2)[:, :, torch.as_tensor(index)].permute(0, 2, 1).numpy().copy()

    def blurred(self, sigma: float) -> "TextureModel":
        """Every map blurred by a Gaussian of std ``sigma`` in uv units (the coarse levels of :func:`register`)."""
        from scipy.ndimage import gaussian_filter

        R = self.mean.shape[-1]
        maps = gaussian_filter(self.maps, (0, 0, sigma * (R - 1), sigma * (R - 1)), mode="nearest")
        return TextureModel(maps[0], maps[1:], self.variance)


def _cache_path(resolution: int, n_images: int, seed: int) -> Path:
    """Keyed by the arguments and a fingerprint of the generator (the bytes of one rendered
    train albedo), so a changed SynthFaces never reuses a stale model."""
    from disent.data import SynthFaces

    probe = SynthFaces("train", resolution, seed).get_batch(range(1))["albedo_uv"].numpy().tobytes()
    root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "disent" / "lighting"
    return root / f"texture_{resolution}_{n_images}_{seed}_{hashlib.sha1(probe).hexdigest()[:12]}.npz"


_BUILDING = threading.Lock()  # the prefetch threads ask for the model at once: one builds it, the others load it


@lru_cache(maxsize=4)
def texture_model(resolution: int = 64, n_components: int = 20, n_images: int = 512, seed: int = 0) -> TextureModel:
    """PCA of ``n_images`` SynthFaces train albedos in UV space (cached on disk: a pure function
    of the arguments and the generator)."""
    with _BUILDING:
        full = _full_texture_model(resolution, n_images, seed)
    if n_components > full.n_components:
        raise ValueError(f"texture model has {full.n_components} components, asked for {n_components}")
    return full.truncate(n_components)


def _full_texture_model(resolution: int, n_images: int, seed: int) -> TextureModel:
    """Every kept component of :func:`texture_model`, read from its disk cache or built and written there."""
    path = _cache_path(resolution, n_images, seed)
    if path.exists():
        with np.load(path) as z:
            return TextureModel(z["mean"], z["components"], z["variance"])
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
    return full


def texture_for(data, uv, n_components: int = 20) -> tuple:
    """``(pixels [1+J, P, C], variance [J])``: the texture model at the pixels of ``data``
    (:class:`~disent.lighting.posterior.LightingData`) through the ``uv [2,H,W]`` map, the
    ``texture`` argument of :func:`disent.lighting.order.select_order`."""
    model = texture_model(uv.shape[-1], n_components)
    return model.at_pixels(uv, data.index), model.variance


def texture_light(
    image, normal, mask, uv, n_components: int = 20, rounds: int = 10, prior_scale: float = 2.0, model=None
) -> torch.Tensor:
    """``[B, C, 9]``: L-hat with the texture model's albedo in place of its constant, for a batch at once (float64):
    the order-2 RGB light and the texture coefficients fitted by the alternating least squares of
    :func:`disent.lighting.order.score` (Gaussian noise, ``rounds`` rounds from the mean texture), on the pixels
    with ``mask [B,1,H,W] > 0.5``, the texture ``model`` (None: :func:`texture_model` at the image's resolution and
    ``n_components``) read through ``uv [B,2,H,W]``.  Each light step is that function's ridge fit
    (``N(0, prior_scale^2)`` coefficients, the noise at its maximum likelihood, two Gauss-Newton steps from least
    squares); each texture step its ridge fit of the coefficients under their PCA prior (``tests/test_lighting.py``
    holds the two to the same light).  Masked pixels are packed first, so the cost follows the face, not the image:
    ~8 ms an image at 64x64 on one CPU thread."""
    from disent.render import sh_basis

    B, C, H, W = image.shape
    model = model or texture_model(uv.shape[-1], n_components)
    maps = torch.from_numpy(model.maps).double()  # [M, C, R, R]: the mean, then the components
    M = len(maps)
    inside = mask.reshape(B, H * W) > 0.5
    counts = inside.sum(1)
    order = torch.sort((~inside).to(torch.uint8), stable=True, dim=1)[1]  # each image's masked pixels first
    at = order[:, : int(counts.max())]
    m = (torch.arange(at.shape[1]) < counts[:, None]).double()[:, None]  # [B, 1, P]: 0 on the padding

    def packed(x):  # [B, K, H, W] -> [B, K, P] at the masked pixels, 0 on the padding
        return x.double().reshape(B, x.shape[1], H * W).gather(2, at[:, None].expand(-1, x.shape[1], -1)) * m

    grid = (2 * packed(uv) - 1).permute(0, 2, 1)[:, None]  # [B, 1, P, 2]
    tex = F.grid_sample(maps.reshape(1, M * C, *maps.shape[-2:]).expand(B, -1, -1, -1), grid, align_corners=True)
    tex = tex.view(B, M, C, -1) * m[:, None]  # [B, M, C, P]
    y, basis = packed(image), sh_basis(packed(normal), 1) * m  # [B, C, P], [B, 9, P]
    n = counts.double() * C  # values per image
    eye = torch.eye(9, dtype=torch.float64)

    def noise(L, A):  # the noise variance at its maximum likelihood, [B]
        return (y - (L[..., None, :] @ A)[..., 0, :]).pow(2).sum((1, 2)) / n

    def light(albedo):  # albedo [B, C, P] -> (L [B, C, 9], noise variance [B])
        A = albedo[:, :, None] * basis[:, None]  # [B, C, 9, P]
        AtA, Aty = A @ A.transpose(-1, -2), (A @ y[..., None])[..., 0]
        L = torch.linalg.lstsq(AtA, Aty[..., None], driver="gelsd" if AtA.device.type == "cpu" else None)[0][..., 0]
        for _ in range(2):  # order._fit's two Gauss-Newton steps: the ridge fit at the last light's noise
            L = torch.linalg.solve(AtA + (noise(L, A) / prior_scale**2)[:, None, None, None] * eye, Aty)
        return L, noise(L, A)

    variance = torch.from_numpy(model.variance).double()
    beta = torch.zeros(B, M - 1, dtype=torch.float64)
    for step in range(rounds + 1):  # the light at the texture's coefficients, then the coefficients at the light
        albedo = (tex[:, 0] + torch.einsum("bj,bjcp->bcp", beta, tex[:, 1:])).clamp_min(1e-3) * m
        L, v = light(albedo)
        if step == rounds:
            return L
        shading = L @ basis  # [B, C, P]
        X = (tex[:, 1:] * shading[:, None]).reshape(B, M - 1, -1)  # [B, J, C*P]
        H_beta = X @ X.transpose(1, 2) + torch.diag_embed(v[:, None] / variance)  # ridge in units of the noise
        beta = torch.linalg.solve(H_beta, X @ (y - tex[:, 0] * shading).reshape(B, -1, 1))[..., 0]


# uv' = [u, v, 1] W: an affine correction of the pseudo uv (W [3, 2], the identity is no correction)
AFFINE_IDENTITY = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])


def affine(uv, W: np.ndarray) -> torch.Tensor:
    """``uv [2,H,W]`` mapped by ``[u, v, 1] W``."""
    uv = torch.as_tensor(uv).double()
    x = torch.cat([uv, torch.ones_like(uv[:1])]).flatten(1).T  # [H*W, 3]
    return (x @ torch.from_numpy(W)).T.reshape(uv.shape)


@lru_cache(maxsize=4)
def registration_prior(
    resolution: int = 64, n_images: int = 64, seed: int = 0, network: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std ``[3, 2]`` of ``W - I`` over SynthFaces train scenes, where ``W`` is the least-squares affine
    map of each scene's pseudo uv onto its true uv (over the pixels in both the matte and the pseudo mask): the
    prior of :func:`register`. With ``network`` (a shipped model with a uv layer), the same of that model's uv and
    matte of each scene's image (:func:`network_maps`) in place of the pseudo ones."""
    from disent.data import SynthFaces

    batch = SynthFaces("train", resolution, seed).get_batch(range(n_images))
    estimates, masks = batch["uv_pseudo"], batch["mask_pseudo"]  # the uv to correct, and the pixels it covers
    if network:
        maps = [network_maps(network, image) for image in batch["image"]]
        estimates, masks = (torch.stack([m[k] for m in maps]) for k in ("uv_net", "matte_net"))
    Ws = []
    for estimate, uv, matte, mask in zip(estimates, batch["uv"], batch["matte"], masks):
        inside = (matte[0] > 0.5) & (mask[0] > 0.5)
        x = torch.cat([estimate[:, inside], torch.ones_like(estimate[:1, inside])]).double().T
        Ws.append(torch.linalg.lstsq(x, uv[:, inside].double().T).solution.numpy() - AFFINE_IDENTITY)
    return np.mean(Ws, 0), np.std(Ws, 0)


def register(
    data,
    uv,
    model: TextureModel | None = None,
    prior: tuple | None = None,
    iterations: int = 3,
    order: int = 2,
    blur=(0.04, 0.02, 0.01, 0.0),
) -> torch.Tensor:
    """The pseudo ``uv [2,H,W]`` corrected by the affine map ``W`` that best registers the texture ``model``
    (default: :func:`texture_model`'s 20 components) to the image of ``data``: the MAP of ``W - I`` under
    ``prior = (mean, std)`` (``[3, 2]`` each; default :func:`registration_prior`), by Gauss-Newton alternated
    with the light and texture fit of the largest lighting model (order ``order``, RGB), which every candidate
    then shares; coarse to fine over the maps blurred by each of ``blur`` (uv units), ``iterations`` steps each."""
    R = uv.shape[-1]
    model = texture_model(R) if model is None else model
    mean, std = (p.reshape(-1) for p in (registration_prior(R) if prior is None else prior))
    x = torch.cat([torch.as_tensor(uv).double(), torch.ones(1, *uv.shape[1:], dtype=torch.float64)])
    x = x.flatten(1)[:, torch.as_tensor(data.index)].T.numpy()  # [P, 3]: [u, v, 1] at the pixels
    delta = mean.copy()
    for sigma in blur:
        level = model.blurred(sigma) if sigma > 0 else model
        maps = level.maps
        gradients = np.concatenate([np.gradient(maps, axis=-1), np.gradient(maps, axis=-2)]) * (maps.shape[-1] - 1)
        for _ in range(iterations):  # Gauss-Newton, the step halved until the log posterior rises
            r, X = _registration_residual(data, uv, level, gradients, x, delta, order)
            noise = r @ r / r.size

            def cost(delta, r):  # the negative log posterior, at this step's noise level
                return 0.5 * r @ r / noise + 0.5 * (((delta - mean) / std) ** 2).sum()

            now = cost(delta, r)
            H = X @ X.T / noise + np.diag(1 / std**2)
            step = np.linalg.solve(H, X @ r / noise - (delta - mean) / std**2)
            for t in (1.0, 0.5, 0.25, 0.125):
                trial = delta + t * step
                if cost(trial, _registration_residual(data, uv, level, None, x, trial, order)) < now:
                    delta = trial
                    break
            else:
                break  # no step helps: this level has converged
    return affine(uv, AFFINE_IDENTITY + delta.reshape(3, 2))


def _registration_residual(data, uv, model, gradients, x, delta, order):
    """The residual ``r [C*P]`` of the light and texture fitted at ``W = I + delta`` (flat) and, with the maps'
    ``gradients [2 (1+J), 3, R, R]`` (d/du, then d/dv), its Jacobian ``X [6, C*P]`` in ``delta``."""
    from disent.lighting.order import score

    uv_now = affine(uv, AFFINE_IDENTITY + delta.reshape(3, 2))
    tex = model.at_pixels(uv_now, data.index)
    fit = score(data, order, texture=(tex, model.variance))
    b = np.concatenate([[1.0], fit["texture"]])
    shading = data.basis[:, : (order + 1) ** 2] @ np.array(fit["light"]).T  # [P, C]
    r = (data.y - np.einsum("j,jpc->pc", b, tex) * shading).reshape(-1)
    if gradients is None:
        return r
    grad = model.at_pixels(uv_now, data.index, gradients).reshape(2, -1, *tex.shape[1:])  # [2, 1+J, P, C]
    grad = np.einsum("j,djpc->dpc", b, grad)
    X = np.einsum("ip,dpc->idpc", x.T, grad * shading[None]).reshape(6, -1)  # d pixel / d W[i, d], W row-major
    # the light and texture are fitted again at every W: only what they cannot explain moves W (variable
    # projection), so X loses its projection on their Jacobian (d pixel / d L_ck = albedo basis_k, channel c only;
    # d pixel / d beta_j = T_j shading)
    albedo, C, K = np.einsum("j,jpc->pc", b, tex), tex.shape[2], (order + 1) ** 2
    light = np.zeros((C * K, *tex.shape[1:]))
    for c in range(C):
        light[c * K : (c + 1) * K, :, c] = (data.basis[:, :K] * albedo[:, c : c + 1]).T
    A = np.concatenate([light, tex[1:] * shading[None]]).reshape(C * K + len(tex) - 1, -1)
    return r, X - np.linalg.lstsq(A.T, X.T, rcond=None)[0].T @ A


@lru_cache(maxsize=2)
def trained_network(name: str):
    """A trained model in eval mode, loaded once: a shipped name, a run folder or a checkpoint."""
    from disent.models import load_run

    return load_run(name)[0].eval()


def network_maps(name: str, image: torch.Tensor) -> dict:
    """The maps shipped model ``name`` draws from ``image [3,H,W]``: ``normal_net``, ``matte_net`` and, from a
    model with a uv layer (implicit), ``uv_net``."""
    with torch.no_grad():
        out = trained_network(name)(image.float().clamp(0, 1)[None])
    maps = {"normal_net": out["normal"][0].double(), "matte_net": out["matte"][0]}
    return maps | ({"uv_net": out["uv"][0]} if "uv" in out else {})


__all__ = [
    "TextureModel",
    "texture_model",
    "texture_for",
    "register",
    "registration_prior",
    "affine",
    "trained_network",
    "network_maps",
]

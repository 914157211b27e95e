"""E_recon-L's targets (Eq. 9) that the trainer fits from each image, below the training loop: L-hat on M-hat
eroded, L-hat with the PCA texture model for the albedo, a trained network's own light, and that light averaged with
the texture model's refit through the network's normals (``loss.recon_L_target``; the paper's own L-hat and the
oracle targets are :func:`disent.losses.target_light`).  The lighting studies (:mod:`disent.lighting.experiments`)
score the same fits."""

from __future__ import annotations

import torch

from disent.config import NETWORK_TARGETS, loss_setting
from disent.lighting.texture import trained_network
from disent.losses import target_light

# pixels taken off the pseudo mask's edge: the coarse fit's silhouette is where its geometry is least right (grazing
# normals) and where it leaks onto hair or background (up to ~30 pixels of a val face lie outside its matte)
EDGE = 1


def eroded(mask, pixels: int) -> torch.Tensor:
    """``mask [1,H,W]`` (``[H,W]``: returned as ``[1,H,W]``; or a batch ``[B,1,H,W]``) > 0.5 less the pixels within
    ``pixels`` (chessboard distance) of its edge."""
    m = (torch.as_tensor(mask) > 0.5).float()
    shape = m.shape if m.dim() > 2 else (1, *m.shape)
    return -torch.nn.functional.max_pool2d(-m.reshape(-1, 1, *m.shape[-2:]), 2 * pixels + 1, 1, pixels).reshape(shape)


def least_squares_light(image, normal, mask, albedo=None) -> torch.Tensor:
    """``[B, 3, 9]``: the least-squares SH light (:func:`disent.render.fit_sh_packed`) of ``image`` over
    ``albedo`` (None: a constant, the paper's L-hat) through ``normal`` on the pixels where ``mask`` > 0.5."""
    from disent.render import fit_sh_packed

    return fit_sh_packed(image, normal * (mask > 0.5), mask, albedo)


def eroded_lhat(batch: dict) -> torch.Tensor:
    """``[B, 3, 9]``: the paper's L-hat (:func:`least_squares_light` with a constant albedo) fitted on M-hat eroded
    ``EDGE`` px through the pseudo normals of each image of ``batch``: M-hat's rim, where the coarse fit reaches past
    the skin, left out (``lhat_sources``' ``lhat_eroded``); E_recon-L's target with
    ``loss.recon_L_target=sh_pseudo_eroded``."""
    mask = eroded(batch["mask_pseudo"], EDGE)
    return least_squares_light(batch["image"], batch["normal_pseudo"], mask).to(batch["image"].dtype)


@torch.no_grad()
def network_lhat(batch: dict, network: str = "explicit") -> torch.Tensor:
    """``[B, 3, 9]``: the light the trained model ``network`` (a shipped name, a run folder or a checkpoint) draws
    from each image of ``batch``: no truth, its own light where it learned one from L-hat (the lighting section's
    network rows); E_recon-L's target with ``loss.recon_L_target=sh_network`` (``loss.recon_L_network``)."""
    return trained_network(str(network))(batch["image"].float().clamp(0, 1))["sh"].to(batch["image"].dtype)


# network_texture_lhat's share of the texture model's refit in its light: loss.recon_L_network_share's default
# (conf/loss/default.yaml says how it was chosen; tests hold the two equal)
NETWORK_TEXTURE_SHARE = 0.6


@torch.no_grad()
def network_texture_lhat(batch: dict, network: str = "explicit", share: float = NETWORK_TEXTURE_SHARE) -> torch.Tensor:
    """``[B, 3, 9]``: the texture model's L-hat (:func:`disent.lighting.texture.texture_light`) refitted through the
    trained model ``network``'s own normals, and its uv where it draws one (else the pseudo uv), on M-hat eroded
    ``EDGE`` px inside its matte, averaged with its own light, ``share`` of the refit. No truth. The two err apart:
    the refit through the network's normals (a little flatter than the truth: 37.9 / 38.1 deg about the face's mean
    normal against 39.1, shipped explicit / implicit, test) overshoots the light's contrast, the network's own light
    undershoots it. E_recon-L's target with ``loss.recon_L_target=sh_network_texture``
    (``loss.recon_L_network``); the lighting section's ``network_NAME_texture`` rows."""
    from disent.lighting.texture import texture_light

    out = trained_network(str(network))(batch["image"].float().clamp(0, 1))
    mask = eroded(batch["mask_pseudo"], EDGE) * (out["matte"] > 0.5)
    uv = out["uv"] if "uv" in out else batch["uv_pseudo"]
    refit = texture_light(batch["image"], out["normal"], mask, uv)
    return (share * refit + (1 - share) * out["sh"].double()).to(batch["image"].dtype)


def texture_lhat(batch: dict) -> torch.Tensor:
    """``[B, 3, 9]``: L-hat with the PCA texture model for the albedo in place of its constant
    (:func:`disent.lighting.texture.texture_light`), fitted on M-hat eroded ``EDGE`` px through the pseudo normals
    and uv of each image of ``batch``: the best light here that needs no truth (``lhat_sources``), and E_recon-L's
    target with ``loss.recon_L_target=sh_texture``."""
    from disent.lighting.texture import texture_light

    mask = eroded(batch["mask_pseudo"], EDGE)
    return texture_light(batch["image"], batch["normal_pseudo"], mask, batch["uv_pseudo"]).to(batch["image"].dtype)


# E_recon-L targets the trainer fits from each image (loss.recon_L_target) -> their fit above
FITTED_TARGETS = {
    "sh_texture": "texture_lhat",
    "sh_pseudo_eroded": "eroded_lhat",
    "sh_network": "network_lhat",
    "sh_network_texture": "network_texture_lhat",
}


def target_fit(cfg_loss):
    """The fit of E_recon-L's target from a batch (:data:`FITTED_TARGETS`), or None where the batch has it (L-hat,
    the truth); ``loss.recon_L_network`` names the network of :data:`NETWORK_TARGETS`, and
    ``loss.recon_L_network_share`` the refit's share in ``sh_network_texture``."""
    import sys
    from functools import partial

    target = loss_setting(cfg_loss, "recon_L_target")
    if target not in FITTED_TARGETS:
        return None
    fit = getattr(sys.modules[__name__], FITTED_TARGETS[target])
    if target == "sh_network_texture":
        fit = partial(fit, share=loss_setting(cfg_loss, "recon_L_network_share"))
    return partial(fit, network=loss_setting(cfg_loss, "recon_L_network")) if target in NETWORK_TARGETS else fit


def target_light_of(cfg_loss):
    """``batch -> [B, C, 9]``: E_recon-L's target light of a run's setting (:func:`disent.losses.target_light`, its
    fitted target drawn as the trainer draws it, :func:`target_fit`), which the evaluation scores on the test faces
    (``target_light_*``); None for the paper's L-hat as it is, scored as ``pseudo_light_*``."""
    target, mix = loss_setting(cfg_loss, "recon_L_target"), loss_setting(cfg_loss, "recon_L_oracle_mix")
    gray, scale = loss_setting(cfg_loss, "lhat_gray"), loss_setting(cfg_loss, "recon_L_scale")
    if target == "sh_pseudo" and not mix and not gray:
        return None
    fit = target_fit(cfg_loss)

    def light(batch: dict) -> torch.Tensor:
        return target_light({**batch, target: fit(batch)} if fit else batch, target, scale, mix, gray)

    return light


def with_fitted_lhat(batch: dict, idx, cache: dict, target: str, fit) -> dict:
    """``batch`` with ``target``, E_recon-L's target under ``loss.recon_L_target=target``: ``fit`` (:func:`target_fit`)
    of each image, L-hat with the texture model, on M-hat eroded or a network's light, made the first time its data
    index ``idx`` comes and kept in ``cache`` (index -> light), as it depends on the image alone."""
    idx = torch.as_tensor(idx).tolist()
    new = [k for k, i in enumerate(idx) if i not in cache]
    if new:
        keys = ("image", "normal_pseudo", "mask_pseudo", "uv_pseudo")
        parts = {k: batch[k][new].cpu() for k in keys}  # fitted on the CPU, wherever the batch was rendered
        cache.update(zip((idx[k] for k in new), fit(parts)))
    return {**batch, target: torch.stack([cache[i] for i in idx]).to(batch["image"].device)}

"""Every loss term of Sec. 4.2, one function each, named as in the paper.

All terms are means over the values they cover, so their weights (``conf/loss/``) compare
directly.  Foreground terms are computed under the pseudo mask M-hat (Sec. 4.2, last paragraph).

=============  =======================================  ==========================
name           term                                      needs
=============  =======================================  ==========================
``recon``      E_recon = ||I_i - I_o||^2                 every model
``recon_fg``   ||M-hat (.) (I_i - I_fg)||^2 (release)    explicit, implicit
``adv``        E_adv = D(I_o), the EBGAN energy          every model, a discriminator
``recon_N``    E_recon-N = ||N - N-hat||^2               explicit, implicit
``recon_L``    E_recon-L = ||Z_L - L-hat||^2, measured   explicit, implicit
               on shadings (see :func:`recon_L`)
``smooth_A``   E_smooth-A = ||grad A||_1                 explicit, implicit
``smooth_S``   E_smooth-S = ||grad S||^2                 explicit, implicit
``UV``         E_UV = ||UV - UV-hat||^2                  implicit
``Ni``         E_Ni = ||N_i - N_i-hat||^2 (UV space)     implicit
``BWS``        batch-wise white shading, mean S = c      explicit, implicit
``M``          E_M = ||M - M-hat||^2                     explicit, implicit (with matting)
``A_true``     ||A - A_true||^2 (not a paper term)       the supervised ceiling
``N_true``     ||N - N_true||^2 (not a paper term)       the supervised ceiling
``L_true``     ||Z_L - L_true||^2 (not a paper term)     the supervised ceiling
=============  =======================================  ==========================

The last three train on SynthFaces' ground truth (``conf/loss/ceiling.yaml``): the same network with the
supervision the paper's models lack, to measure what the architecture can reach at a budget.  Albedo and
normals count on the pixels where the layers are scored (the true face inside M-hat).

A term whose weight is 0 is not computed at all: it is absent from the loss dict and adds
nothing to the gradient (that is how ablations switch terms off).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from disent.regions import decomposed_region
from disent.render import sh_shading

TERMS = ("recon", "recon_fg", "adv", "recon_N", "recon_L", "smooth_A", "smooth_S", "UV", "Ni", "BWS", "M")
TRUTH = ("A_true", "N_true", "L_true")  # terms on the true layers
TRUTH_KEYS = ("albedo", "normal", "sh", "matte")  # the batch keys they read
# loss.recon_L_target: L-hat, L-hat on M-hat eroded, L-hat with a texture model, a trained network's light, that light
# averaged with the texture model's refit through the network's geometry, the truth
RECON_L_TARGETS = ("sh_pseudo", "sh_pseudo_eroded", "sh_texture", "sh_network", "sh_network_texture", "sh")
RECON_L_SCALES = ("target", "sh_pseudo")  # loss.recon_L_scale: each face's scale from the target itself, or from L-hat


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of ``x [B,C,H,W]`` over the pixels where ``mask [B,1,H,W]`` is on (mask acts as weight)."""
    return (x * mask).sum() / (mask.sum() * x.shape[1]).clamp_min(1e-8)


def spatial_gradients(x: torch.Tensor, mask: torch.Tensor):
    """Forward differences along x and y, each with the mask of pixel pairs both inside ``mask``."""
    dx, dy = x[..., :, 1:] - x[..., :, :-1], x[..., 1:, :] - x[..., :-1, :]
    return (dx, mask[..., :, 1:] * mask[..., :, :-1]), (dy, mask[..., 1:, :] * mask[..., :-1, :])


def norm_p(err: torch.Tensor, p: int) -> torch.Tensor:
    """``err^2`` (``p=2``) or ``|err|`` (``p=1``), elementwise."""
    return err.pow(2) if p == 2 else err.abs()


def recon(out, batch, p: int = 2):
    """E_recon: the paper's L2 (``p=2``) or the release's L1 (``p=1``) over every value of I_o."""
    return norm_p(out["recon"] - batch["image"], p).mean()


def recon_fg(out, batch, p: int = 2):
    """The release's masked reconstruction: the rendered face A (.) S itself must match the image under
    M-hat (L2 as in the release, or L1).  Without it the skip-connected background decoder can paint the
    face and the albedo dies."""
    return masked_mean(norm_p(out["foreground"] - batch["image"], p), batch["mask_pseudo"])


def recon_N(out, batch):
    return masked_mean((out["normal"] - batch["normal_pseudo"]).pow(2), batch["mask_pseudo"])


def face_shading_mean(normal, light, mask) -> torch.Tensor:
    """``[B, C]``: the mean over each face's mask of the shading S(normal, light) (Eq. 4)."""
    return (sh_shading(normal, light) * mask).sum((2, 3)) / mask.sum((2, 3)).clamp_min(1e-8)


def rescaled(light, reference, normal, mask) -> torch.Tensor:
    """``light`` scaled per face and channel to ``reference``'s mean shading over ``mask``: ``light``'s shape,
    ``reference``'s brightness and colour."""
    scale = face_shading_mean(normal, reference, mask) / face_shading_mean(normal, light, mask).clamp_min(1e-3)
    return light * scale[:, :, None]


def oracle_mixed(target, true, normal, mask, share: float) -> torch.Tensor:
    """``target`` moved ``share`` of the way to the ``true`` light, the truth scaled per face and channel to the
    target's mean shading over ``mask`` (the truth's shape, the target's brightness and colour):
    ``loss.recon_L_oracle_mix``'s E_recon-L target."""
    return target + share * (rescaled(true, target, normal, mask) - target)


def recon_L(
    out,
    batch,
    c: float | None = 0.75,
    space: str = "shading",
    gray: bool = False,
    target: str = "sh_pseudo",
    oracle_mix: float = 0.0,
    scale: str = "target",
):
    """E_recon-L = ||Z_L - L-hat||^2.

    L-hat (constant albedo) is defined up to that constant; with ``c`` set, the constant is chosen
    per channel so that L-hat's own shading obeys BWS on the batch (mean c over the face), so
    E_recon-L and BWS ask for the same shading scale (``c=None``: L-hat as given).
    The constant albedo leaves each face's skin colour in L-hat, and E_recon-L teaches it to the light;
    ``gray=True`` takes it out first: each face's three channels are scaled to one shading mean over the face
    (their average), so the target keeps the light's pattern and brightness but no colour of its own.
    ``target="sh_texture"`` puts L-hat fitted with a PCA texture model for the albedo in its place
    (:func:`disent.lighting.targets.texture_lhat`, added to the batch by the trainer), ``"sh_pseudo_eroded"``
    L-hat fitted on M-hat eroded 1 px (:func:`disent.lighting.targets.eroded_lhat`, the same), ``"sh_network"``
    the light a trained network draws from the image (:func:`disent.lighting.targets.network_lhat`, the same),
    ``"sh_network_texture"`` that light averaged with the texture model's L-hat refitted through the network's
    normals and uv (:func:`disent.lighting.targets.network_texture_lhat`, the same): no truth, not the paper's.
    ``target="sh"`` puts the true SH light there, an oracle (not the paper's): what a perfect L-hat
    would buy the model. Either is scaled by ``c`` and measured as L-hat is.
    ``scale="sh_pseudo"`` first scales the chosen target per face and channel to L-hat's mean shading over M-hat
    (its shape, L-hat's brightness and colour; ``"target"``: its own), which parts a target's shape from its
    per-face scale; not the paper's.
    ``oracle_mix`` in [0, 1] moves the target that share of the way to the true light, scaled per face and channel
    to the target's mean shading over M-hat (the truth's shape, the target's brightness and colour): a dose of
    light accuracy (0: the target as chosen; 1: the truth's shape alone), not the paper's.
    ``space="coefficients"`` is the plain L2 over the 27 numbers; ``space="shading"`` measures the
    same difference through the face's pseudo normals, ||S(N-hat, Z_L) - S(N-hat, L-hat)||^2 under
    M-hat, which ignores the SH directions a face's normal cone cannot tell apart (there the
    least-squares L-hat is noise).
    """
    target = target_light(batch, target, scale, oracle_mix, gray)
    mask, normal = batch["mask_pseudo"], batch["normal_pseudo"]
    if c is not None:
        mean = (sh_shading(normal, target) * mask).sum((0, 2, 3)) / mask.sum().clamp_min(1e-8)  # [C]
        target = target * (c / mean.clamp_min(1e-3))[None, :, None]
    target = target.detach()
    if space == "coefficients":
        return F.mse_loss(out["sh"], target)
    if space != "shading":
        raise ValueError(f"recon_L space must be 'shading' or 'coefficients', got {space!r}")
    return masked_mean(sh_shading(normal, out["sh"] - target).pow(2), mask)  # Eq. 4 is linear in L


def target_light(
    batch, target: str = "sh_pseudo", scale: str = "target", oracle_mix: float = 0.0, gray: bool = False
) -> torch.Tensor:
    """``[B, C, 9]``: E_recon-L's target light of ``batch`` before BWS's scale c (:func:`recon_L` says what each
    argument chooses): the light the network is taught, as the evaluation scores it (``target_light_*``)."""
    if target not in RECON_L_TARGETS:
        raise ValueError(f"loss.recon_L_target must be one of {', '.join(RECON_L_TARGETS)}, got {target!r}")
    if target not in batch:
        where = "the true light (SynthFaces has it)" if target == "sh" else "the trainer to add it (disent.train)"
        raise ValueError(f"loss.recon_L_target={target} needs {target} in the batch: {where}")
    if scale not in RECON_L_SCALES:
        raise ValueError(f"loss.recon_L_scale must be one of {', '.join(RECON_L_SCALES)}, got {scale!r}")
    target, mask, normal = batch[target], batch["mask_pseudo"], batch["normal_pseudo"]
    if scale == "sh_pseudo":
        target = rescaled(target, batch["sh_pseudo"], normal, mask)
    if oracle_mix:
        if "sh" not in batch:
            raise ValueError("loss.recon_L_oracle_mix needs the true light in the batch (SynthFaces has it)")
        target = oracle_mixed(target, batch["sh"], normal, mask, oracle_mix)
    if gray:
        face = face_shading_mean(normal, target, mask)  # [B, C]
        target = target * (face.mean(1, keepdim=True) / face.clamp_min(1e-3))[:, :, None]
    return target


def smooth_A(out, batch):
    grads = spatial_gradients(out["albedo"], batch["mask_pseudo"])
    return sum(masked_mean(d.abs(), m) for d, m in grads)


def smooth_S(out, batch):
    grads = spatial_gradients(out["shading"], batch["mask_pseudo"])
    return sum(masked_mean(d.pow(2), m) for d, m in grads)


def UV(out, batch):
    return masked_mean((out["uv"] - batch["uv_pseudo"]).pow(2), batch["mask_pseudo"])


def Ni(out, batch):
    valid = (batch["normal_uv_pseudo"].norm(dim=1, keepdim=True) > 0.5).to(out["normal_uv"].dtype)  # covered texels
    return masked_mean((out["normal_uv"] - batch["normal_uv_pseudo"]).pow(2), valid)


def BWS(out, batch, c: float = 0.75):
    """Batch-wise white shading: each channel's mean shading over the batch's face pixels is c."""
    mask = batch["mask_pseudo"]
    mean = (out["shading"] * mask).sum((0, 2, 3)) / mask.sum().clamp_min(1e-8)  # [C]
    return (mean - c).pow(2).mean()


def M(out, batch, p: int = 2):
    """The matte toward M-hat: the paper's L2 (``p=2``, Sec. 4.2), whose minimiser is M-hat's expectation given
    the image, soft where its edge is uncertain; or the release's L1 (``p=1``), whose minimiser is its median."""
    return norm_p(out["matte"] - batch["mask_pseudo"], p).mean()


def A_true(out, batch):
    return masked_mean((out["albedo"] - batch["albedo"]).pow(2), decomposed_region(batch))


def N_true(out, batch):
    return masked_mean((out["normal"] - batch["normal"]).pow(2), decomposed_region(batch))


def L_true(out, batch):
    return F.mse_loss(out["sh"], batch["sh"])


TERM_FUNCTIONS = {
    "recon": recon,
    "recon_fg": recon_fg,
    "recon_N": recon_N,
    "recon_L": recon_L,
    "smooth_A": smooth_A,
    "smooth_S": smooth_S,
    "UV": UV,
    "Ni": Ni,
    "BWS": BWS,
    "M": M,
    "A_true": A_true,
    "N_true": N_true,
    "L_true": L_true,
}  # adv comes from D
NEEDS = {
    "recon": "recon",
    "recon_fg": "foreground",
    "adv": "recon",
    "recon_N": "normal",
    "recon_L": "sh",
    "smooth_A": "albedo",
    "smooth_S": "shading",
    "UV": "uv",
    "Ni": "normal_uv",
    "BWS": "shading",
    "M": "matte",
    "A_true": "albedo",
    "N_true": "normal",
    "L_true": "sh",
}

# loss settings (conf/loss) that act only through these terms
TERM_SETTINGS = {
    "recon_fg_p": ("recon_fg",),
    "matte_p": ("M",),
    "lhat_white": ("recon_L",),
    "lhat_gray": ("recon_L",),
    "recon_L_space": ("recon_L",),
    "recon_L_target": ("recon_L",),
    "recon_L_oracle_mix": ("recon_L",),
    "recon_L_scale": ("recon_L",),
    "recon_L_network": ("recon_L",),
    "recon_L_network_share": ("recon_L",),
    "bws_c": ("BWS", "recon_L"),
}


def term_settings(lhat_white: bool = True) -> dict:
    """:data:`TERM_SETTINGS` for a loss config: E_recon-L's target uses c only when it is whitened (``lhat_white``,
    :func:`recon_L`), so without it c acts through BWS alone."""
    return TERM_SETTINGS if lhat_white else {**TERM_SETTINGS, "bws_c": ("BWS",)}


def active_terms(weights: dict, out: dict) -> list[str]:
    """Terms with a nonzero weight whose model output exists."""
    unknown = set(weights) - set(TERMS + TRUTH)
    if unknown:
        raise KeyError(f"unknown loss terms {sorted(unknown)}; terms are {', '.join(TERMS + TRUTH)}")
    return [t for t in TERMS + TRUTH if weights.get(t, 0) and NEEDS[t] in out]


GENERATOR_SETTINGS = (  # conf/loss settings that choose how a term is computed (generator_losses' keywords)
    *("lhat_white", "lhat_gray", "recon_L_space", "recon_p", "recon_fg_p", "matte_p"),
    *("recon_L_target", "recon_L_oracle_mix", "recon_L_scale"),
)


def generator_losses(
    out: dict,
    batch: dict,
    weights: dict,
    energy_fake=None,
    bws_c: float = 0.75,
    lhat_white: bool = True,
    lhat_gray: bool = False,
    recon_L_space: str = "shading",
    recon_p: int = 2,
    recon_fg_p: int = 2,
    matte_p: int = 2,
    recon_L_target: str = "sh_pseudo",
    recon_L_oracle_mix: float = 0.0,
    recon_L_scale: str = "target",
) -> dict:
    """Unweighted value of every active term, plus ``total`` = sum of weight x term (E_o and the priors).

    ``energy_fake`` is D's energy of ``out['recon']`` (``[B]``), needed when ``adv`` is active;
    ``lhat_white``, ``lhat_gray``, ``recon_L_target``, ``recon_L_oracle_mix``, ``recon_L_scale`` and ``recon_L_space``
    choose E_recon-L's target and metric (see :func:`recon_L`);
    ``recon_p`` E_recon's norm (2: the paper, 1: the release); ``recon_fg_p`` the masked reconstruction's
    (2: the release, 1); ``matte_p`` the matte's (2: the paper, 1: the release).
    """
    losses = {}
    for t in active_terms(weights, out):
        if t == "adv":
            if energy_fake is None:
                raise ValueError("the adv term needs energy_fake (a discriminator)")
            losses[t] = energy_fake.mean()
        else:
            fn = TERM_FUNCTIONS[t]
            if t == "BWS":
                losses[t] = fn(out, batch, bws_c)
            elif t in ("recon", "recon_fg"):
                losses[t] = fn(out, batch, recon_p if t == "recon" else recon_fg_p)
            elif t == "M":
                losses[t] = fn(out, batch, matte_p)
            elif t == "recon_L":
                c = bws_c if lhat_white else None
                losses[t] = fn(
                    out, batch, c, recon_L_space, lhat_gray, recon_L_target, recon_L_oracle_mix, recon_L_scale
                )
            else:
                losses[t] = fn(out, batch)
    losses["total"] = sum(weights[t] * v for t, v in losses.items())
    return losses


def discriminator_loss(
    energy_real: torch.Tensor, energy_fake: torch.Tensor, margin: float, prune: bool = True
) -> torch.Tensor:
    """EBGAN margin loss that trains D: ``D(x) + max(0, m - D(G))`` (batch means).

    When every generated image is past the margin the second term and its gradient are exactly
    zero; it is then left out of the graph, so that D's backward pass skips the generated batch
    (in the default runs most steps are such steps).  ``prune=False`` keeps it (models trained stacked, where
    the test would branch on one run's data)."""
    if prune and not bool((energy_fake < margin).any()):
        return energy_real.mean()
    return energy_real.mean() + F.relu(margin - energy_fake).mean()

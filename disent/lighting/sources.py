"""Where L-hat's error comes from: L-hat fitted with its inputs made true one at a time, beside the lights
that need no truth (M-hat eroded, the texture model, the networks' own)."""

from __future__ import annotations

import math

import torch

from disent.lighting.targets import (
    EDGE,
    eroded,
    least_squares_light,
    network_texture_lhat,
    texture_lhat,
    trained_network,
)
from disent.render import sh_shading

# ----------------------------------------------------------------------------- where L-hat's error comes from
# L-hat (Eq. 9, the target of E_recon-L) fitted with its inputs made true: first its pixels (M-hat holds some hair,
# ears or background), then from there the normals, the albedo (the paper's is constant; or a placed mean texture in
# its place), or both. lhat_sources sets beside them what needs no truth: M-hat eroded, the PCA texture model fitted
# with the light, and the shipped networks' own light.
LHAT_SOURCES = {  # name: (normals, albedo, pixels)
    "lhat": ("normal_pseudo", "constant", "mask_pseudo"),
    "lhat_eroded": ("normal_pseudo", "constant", "eroded"),
    "true_pixels": ("normal_pseudo", "constant", "face"),
    "true_pixels_template": ("normal_pseudo", "template", "face"),
    "true_pixels_normals": ("normal", "constant", "face"),
    "true_pixels_albedo": ("normal_pseudo", "albedo", "face"),
    "true_pixels_normals_albedo": ("normal", "albedo", "face"),
}


ORACLE_MIXES = (0.25, 0.5, 0.75)  # lhat_sources' doses of loss.recon_L_oracle_mix
SHARPENING = (0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.4)  # lhat_sources' powers k of a network's shading (its log contrast x k)


def sharpened_albedo(image, shading, albedo, region, ks=SHARPENING) -> dict:
    """``{k: si-MSE}``: the detailed albedo of Sec. 5.3, the image over the shading raised to the power ``k`` (its
    log contrast scaled by k about each face's mean; the scale this also changes is one the si-MSE forgives), scored
    against the true ``albedo`` on ``region``: what a more (k > 1) or less (k < 1) contrasty shading would give the
    albedo, all else kept."""
    from disent.eval.metrics import scale_invariant_mse
    from disent.render import detailed_albedo

    s = shading.double().clamp_min(1e-3)
    return {k: scale_invariant_mse(detailed_albedo(image.double(), s.pow(k)), albedo, region) for k in ks}


@torch.no_grad()
def source_rows(scores: dict, inputs: dict, extra: dict) -> dict:
    """:func:`lhat_sources`' rows: each light's scores (``(per-face error, shown, skin correlations, contrast
    agreement)``), its inputs, and what only a network's row has."""
    reference = scores["lhat"][0]
    rows = {}
    for k, (e, shown, skin_corr, agree) in scores.items():
        rows[k] = {
            "light_on_face": float(e.mean()),
            "light_on_face_se": float(e.std() / math.sqrt(len(e))),
            "beats_lhat": float((e < reference).double().mean()),
            "shown": shown,
            "skin_tone_corr": skin_corr["tone"],
            "skin_brightness_corr": skin_corr["brightness"],
            "contrast": agree["slope"],
            "pattern_corr": agree["corr"],
            "contrast_ratio": agree["ratio"],
            "log_error": agree["error"],
            "inputs": inputs[k],
        } | extra.get(k, {})
    return rows


def lhat_sources(test, train, n: int = 256, networks=("explicit", "implicit")) -> dict:
    """How far L-hat's light lies from the true light on the face, and with which of its inputs made true.

    The first ``n`` items of ``test`` (noise-free, as training sees them); each light is scored as the report scores
    the networks': its shading through the true normals against the true light's, scale-invariant per image and
    channel, on the scored pixels (the true face inside M-hat; ``light_on_face``, with its standard error over the
    faces, and ``beats_lhat``, the share of faces where it is below the paper's L-hat), and the SH error along the
    directions the face shows (``shown``); ``skin_tone_corr`` and ``skin_brightness_corr``: how much of each face's
    skin its shading carries there (:func:`disent.eval.scoring.skin_in_shading`; a per-face, per-channel scale that
    light on the face is blind to, and that the light hands on to the albedo); ``contrast``, ``pattern_corr``,
    ``contrast_ratio`` and ``log_error``: the medians over faces and channels of
    :func:`disent.eval.metrics.shading_contrast`'s slope, correlation, magnitude and error against the true light
    there (a slope below 1 leaves the rest of the shading to the albedo). ``LHAT_SOURCES`` are least-squares
    fits (:func:`disent.render.fit_sh_packed`) of the image over the albedo; *template*: the mean train
    albedo in UV space placed through the pseudo uv; ``texture_model``: the PCA texture model fitted with the light
    (:func:`texture_lhat`) on M-hat eroded ``EDGE`` px, and ``texture_model_lhat_scale``, the same at L-hat's mean
    shading per face and channel (:func:`disent.losses.rescaled`; E_recon-L's target under
    ``loss.recon_L_scale=sh_pseudo``); ``oracle_mix_m``: L-hat moved a share m of the way to the true light
    (:data:`ORACLE_MIXES`, :func:`disent.losses.oracle_mixed`: E_recon-L's target under
    ``loss.recon_L_oracle_mix=m``). Each row names its ``inputs`` (normals, albedo, pixels). Each shipped network
    in ``networks`` adds its light, the least-squares light of the image over its own albedo on the pseudo
    normals, inside M-hat and its matte, and the texture model's refit through its geometry averaged with its light
    (:func:`network_texture_lhat`, ``network_NAME_texture``), with its ``calibration`` (the slope of L-hat's log
    shading on the network's light's, through N-hat on M-hat, the median over faces and channels: 1 where it is
    right on average about its target) and ``sharpened_albedo`` (:func:`sharpened_albedo` of its own shading).
    ``floor``: the constant mean train light."""
    from disent.data import get_batch
    from disent.eval.metrics import light_shading_si_mse, sh_error_shown_hidden, shading_contrast
    from disent.eval.scoring import face_colour, skin_in_shading
    from disent.eval.trivial import dataset_means, template_albedo
    from disent.losses import oracle_mixed, rescaled
    from disent.regions import decomposed_region

    g = get_batch(test, range(min(n, len(test))))
    face = decomposed_region(g)
    means = dataset_means(train)
    pixels = {"mask_pseudo": g["mask_pseudo"], "eroded": eroded(g["mask_pseudo"], EDGE), "face": face}
    albedo = {"constant": None, "template": template_albedo(means["albedo_uv"], g["uv_pseudo"]), "albedo": g["albedo"]}

    skin = face_colour(g["albedo"], face)

    def scored(sh):
        e = light_shading_si_mse(sh, g["sh"], g["normal"], face, reduction="none")
        skin_corr = skin_in_shading(face_colour(sh_shading(g["normal"].double(), sh.double()), face), skin)
        agree = {k: float(v.median()) for k, v in shading_contrast(sh, g["sh"], g["normal"], face).items()}
        return e, sh_error_shown_hidden(sh, g["sh"], g["normal"], face)["shown"], skin_corr, agree

    inputs = dict(LHAT_SOURCES, texture_model=("normal_pseudo", "texture_model", "eroded"), floor=("-", "-", "-"))
    lights = {k: least_squares_light(g["image"], g[nk], pixels[p], albedo[a]) for k, (nk, a, p) in LHAT_SOURCES.items()}
    lights["texture_model"] = texture_lhat(g)
    lights["texture_model_lhat_scale"] = rescaled(
        lights["texture_model"], lights["lhat"], g["normal_pseudo"], g["mask_pseudo"]
    )
    inputs["texture_model_lhat_scale"] = inputs["texture_model"]
    for share in ORACLE_MIXES:  # doses of light accuracy (loss.recon_L_oracle_mix): L-hat moved toward the truth
        lights[f"oracle_mix_{share}"] = oracle_mixed(
            lights["lhat"], g["sh"], g["normal_pseudo"], g["mask_pseudo"], share
        )
        inputs[f"oracle_mix_{share}"] = LHAT_SOURCES["lhat"]
    extra = {}  # row -> what only a network's row has
    for name in networks:
        out = trained_network(name)(g["image"].clamp(0, 1))
        inside = g["mask_pseudo"] * (out["matte"] > 0.5)
        lights[f"network_{name}"] = out["sh"]
        # its target L-hat's log shading regressed on the network's (no truth): 1 where the network is right on
        # average about its target, E[L-hat | network] = network, whatever it cannot tell from the image left out
        calibration = shading_contrast(lights["lhat"], out["sh"], g["normal_pseudo"], g["mask_pseudo"])["slope"]
        extra[f"network_{name}"] = {
            "calibration": float(calibration.median()),
            "sharpened_albedo": sharpened_albedo(g["image"], out["shading"], g["albedo"], face),
        }
        lights[f"network_{name}_refit"] = least_squares_light(g["image"], g["normal_pseudo"], inside, out["albedo"])
        lights[f"network_{name}_texture"] = network_texture_lhat(g, name)
        inputs |= {f"network_{name}": ("network",) * 3, f"network_{name}_refit": ("normal_pseudo", "network", "matte")}
        inputs[f"network_{name}_texture"] = ("network", "texture_model", "eroded_matte")
    lights["floor"] = means["sh"].expand_as(g["sh"])
    scores = {k: scored(sh) for k, sh in lights.items()}
    rows = source_rows(scores, inputs, extra)
    return {"split": test.split, "n": len(scores["lhat"][0]), "rows": rows}

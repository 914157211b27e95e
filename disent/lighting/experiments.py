"""Experiments on SynthFaces for the report: posterior width, calibration, order choice, where L-hat's error comes
from, speed.

Every experiment fits the known-albedo model ``image = albedo * S(n, L) + noise`` on the true
normals and matte, so that the sampled L is the scene's SH light and can be checked against
it; i.i.d. Gaussian noise of std ``noise`` is added to the image with a fixed seed.  Outputs
go to the run folder (JSON and PNG); ``python -m disent.report --publish FOLDER`` copies them to
``reports/lighting/``.
"""

from __future__ import annotations

import functools
import json
import math
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from disent.lighting.order import choose, fitted, select_order
from disent.lighting.posterior import N_COEFFS, prepare, sample_posterior
from disent.render import C4, fit_sh, sh_basis, sh_shading
from disent.storage import machine_info

BANDS = {0: [0], 1: [1, 2, 3], 2: [4, 5, 6, 7, 8]}
from disent.lighting.targets import (  # noqa: E402, F401  (the fits the studies score, under their names here too)
    EDGE,
    NETWORK_TEXTURE_SHARE,
    eroded,
    eroded_lhat,
    least_squares_light,
    network_lhat,
    network_maps,
    network_texture_lhat,
    texture_lhat,
    trained_network,
)


# geometry of a lighting fit: the normals, mask and uv (of the texture model) keys of an item, the pixels eroded
# off the mask's edge, and the report's label. The oracle rows each make one thing true, to split the pseudo
# geometry's error: one layer (the normals, or the uv through which the texture model reaches the image), or one
# part of the coarse fit behind all three maps, which are then rendered again (made_true: its placement, i.e. pose,
# scale and shift, or its shape, i.e. the identity components it fits and the expression;
# coarse_fit_made_true). The registered row corrects the pseudo uv by the affine map that best registers the
# texture model to the image (disent.lighting.texture.register); the placed row renders all three maps again at the
# coarse fit's placement refined against the image (refine_placement), and the placed-registered row registers the
# uv of those re-rendered maps (under the pseudo uv's registration prior). The network rows read the maps a shipped
# model (disent.models.shipped), trained on the pseudo-GT alone, draws from the scene's (noisy) image: its normals
# and matte, and the implicit model's uv (network_maps), or the uv of the coarse fit placed and registered as above
# (network_explicit_placed); no ground truth enters them either.
class Geometry(NamedTuple):
    normals: str
    mask: str
    uv: str
    erosion: int
    label: str
    register: bool = False  # the uv corrected by registering the texture model to the image (texture.register)
    place: bool = False  # the coarse fit's placement refined against the image before its maps are rendered
    made_true: tuple = ()  # parts of the coarse fit set to the scene's truth before its maps are rendered
    network: str = ""  # the shipped model whose maps of the image (normal_net, matte_net, uv_net) the row reads


GEOMETRY = {
    "normal": Geometry("normal", "matte", "uv", 0, "true normals"),
    "normal_pseudo": Geometry("normal_pseudo", "mask_pseudo", "uv_pseudo", 0, "pseudo normals + mask"),
    "normal_pseudo_eroded": Geometry(
        "normal_pseudo", "mask_pseudo", "uv_pseudo", EDGE, f"pseudo normals + mask eroded {EDGE} px"
    ),
    "normal_pseudo_registered": Geometry(
        "normal_pseudo",
        "mask_pseudo",
        "uv_pseudo",
        EDGE,
        f"pseudo normals + mask eroded {EDGE} px, uv registered",
        register=True,
    ),
    "normal_pseudo_placed": Geometry(
        "normal_pseudo",
        "mask_pseudo",
        "uv_pseudo",
        EDGE,
        f"pseudo normals + mask eroded {EDGE} px, placement refined",
        place=True,
    ),
    "normal_pseudo_placed_registered": Geometry(
        "normal_pseudo",
        "mask_pseudo",
        "uv_pseudo",
        EDGE,
        f"pseudo normals + mask eroded {EDGE} px, placement refined, uv registered",
        register=True,
        place=True,
    ),
    "oracle_uv": Geometry(
        "normal_pseudo", "mask_pseudo", "uv", EDGE, f"pseudo normals + mask eroded {EDGE} px, true uv (oracle)"
    ),
    "oracle_normals": Geometry(
        "normal", "mask_pseudo", "uv_pseudo", EDGE, f"true normals, pseudo mask eroded {EDGE} px and uv (oracle)"
    ),
    "oracle_placement": Geometry(
        "normal_pseudo",
        "mask_pseudo",
        "uv_pseudo",
        EDGE,
        f"coarse fit at the true pose, scale and shift, mask eroded {EDGE} px (oracle)",
        made_true=("placement",),
    ),
    "oracle_shape": Geometry(
        "normal_pseudo",
        "mask_pseudo",
        "uv_pseudo",
        EDGE,
        f"coarse fit with the true shape and expression, mask eroded {EDGE} px (oracle)",
        made_true=("shape",),
    ),
    "network_explicit": Geometry(
        "normal_net",
        "matte_net",
        "uv_pseudo",
        EDGE,
        f"explicit network's normals + matte eroded {EDGE} px, pseudo uv registered",
        register=True,
        network="explicit",
    ),
    "network_implicit": Geometry(
        "normal_net",
        "matte_net",
        "uv_net",
        EDGE,
        f"implicit network's normals + matte eroded {EDGE} px + uv",
        network="implicit",
    ),
    "oracle_uv_network": Geometry(
        "normal_net",
        "matte_net",
        "uv",
        EDGE,
        f"explicit network's normals + matte eroded {EDGE} px, true uv (oracle)",
        network="explicit",
    ),
    "network_explicit_placed": Geometry(
        "normal_net",
        "matte_net",
        "uv_pseudo",
        EDGE,
        f"explicit network's normals + matte eroded {EDGE} px, uv of the placed coarse fit registered",
        register=True,
        place=True,
        network="explicit",
    ),
    "network_implicit_registered": Geometry(
        "normal_net",
        "matte_net",
        "uv_net",
        EDGE,
        f"implicit network's normals + matte eroded {EDGE} px + uv registered",
        register=True,
        network="implicit",
    ),
}
# the scene parameters behind each part of the coarse fit (coarse_fit_made_true)
COARSE_FIT_PARTS = {"placement": ("pose", "scale", "shift"), "shape": ("alpha", "expression")}


def coarse_fit_made_true(ds, index: int, item: dict, parts: tuple) -> dict:
    """``item`` (scene ``index`` of SynthFaces ``ds``) with ``normal_pseudo``, ``mask_pseudo`` and ``uv_pseudo``
    rendered again from its coarse fit with ``parts`` (keys of :data:`COARSE_FIT_PARTS`) set to the scene's own
    values; the shape keeps the fit's number of identity components."""
    p = ds.params([index])
    for name in (k for part in parts for k in COARSE_FIT_PARTS[part]):
        p[f"pseudo_{name}"] = p[name][:, : p["pseudo_alpha"].shape[1]] if name == "alpha" else p[name]
    return with_coarse_fit(item, p)


def with_coarse_fit(item: dict, p: dict) -> dict:
    """``item`` with ``normal_pseudo``, ``mask_pseudo`` and ``uv_pseudo`` rendered from the coarse fit in the scene
    parameters ``p`` (its ``pseudo_*`` entries)."""
    from disent.data.synth.scenes import render_pseudo

    maps = render_pseudo(item["image"][None], p, item["image"].shape[-1])
    return {**item, **{k: maps[k][0] for k in ("normal_pseudo", "mask_pseudo", "uv_pseudo")}}


def placement_of(p: dict, prefix: str = "pseudo_") -> np.ndarray:
    """``[6]``: the placement in scene parameters ``p`` (one scene): pose (yaw, pitch, roll; degrees), scale, shift
    (x, y); the coarse fit's (``prefix="pseudo_"``) or the scene's own (``""``)."""
    return np.concatenate([p[f"{prefix}{k}"].reshape(-1).double().numpy() for k in COARSE_FIT_PARTS["placement"]])


def placed(p: dict, q: np.ndarray) -> dict:
    """Scene parameters ``p`` with the coarse fit's placement set to ``q`` (:func:`placement_of`)."""
    q = torch.as_tensor(q, dtype=p["pseudo_pose"].dtype)
    return p | {"pseudo_pose": q[None, :3], "pseudo_scale": q[3:4], "pseudo_shift": q[None, 4:]}


@functools.lru_cache(maxsize=2)
def placement_prior(resolution: int = 64, seed: int = 0, n_scenes: int = 400) -> np.ndarray:
    """``[6]``: the std of the coarse fit's placement error (:func:`placement_of`, the scale's relative to the
    scale) over ``n_scenes`` SynthFaces train scenes: the prior of :func:`refine_placement`."""
    from disent.data import SynthFaces

    p = SynthFaces("train", resolution, seed).params(list(range(n_scenes)))
    error = torch.cat(
        [p["pseudo_pose"] - p["pose"], (p["pseudo_scale"] / p["scale"] - 1)[:, None], p["pseudo_shift"] - p["shift"]], 1
    )
    return error.double().std(0).numpy()


def placement_width(start: np.ndarray, resolution: int = 64) -> np.ndarray:
    """``[6]``: :func:`placement_prior`'s widths about the placement ``start`` (:func:`placement_of`), the scale's
    made absolute by ``start``'s scale."""
    return placement_prior(resolution) * np.array([1, 1, 1, start[3], 1, 1])


def coarse_fit_of(ds, index: int | None, item: dict) -> dict:
    """The scene parameters whose ``pseudo_*`` entries are ``item``'s coarse fit: scene ``index`` of SynthFaces
    ``ds``'s, or, for a photo (``ds`` None), its own landmark fit (the pseudo-GT's ``params``)."""
    if ds is not None:
        return ds.params([index])
    if "params" not in item:
        raise ValueError("this item has neither a SynthFaces scene nor a photo's landmark fit to draw again")
    from disent.data.photos.pseudo_gt import coarse_fit_scene

    return coarse_fit_scene(torch.as_tensor(item["params"]).double().numpy(), item["image"].shape[-1])


def placement_objective(p: dict, item: dict, noise: float, seed: int):
    """``(objective, placement)``: the coarse fit's placement (:func:`placement_of`) in scene parameters ``p`` (that
    of ``item``, :func:`coarse_fit_of`) as ``placement(z)``, ``z`` its offset in units of :func:`placement_prior`'s
    widths, and ``objective(z)``: -log p(image | placement) - log prior, up to a constant, of the image ``item`` with
    noise ``noise`` of seed ``seed`` (the pixels the lighting fit then sees).

    The likelihood is that of the texture model and an order-2 RGB light (the largest lighting candidate, so that no
    candidate is favoured) fitted to the image over a fixed set of pixels, the coarse fit's mask eroded 3 px, with
    sigma profiled (``N/2 log mse``); the prior is Gaussian around the coarse fit's placement; its shape stays the
    fit's.  No ground truth enters it."""
    from disent.lighting.order import score, texture_albedo
    from disent.lighting.texture import texture_model

    image = noisy(item["image"], noise, seed).float()
    start = placement_of(p)
    width = placement_width(start, image.shape[-1])
    pixels = eroded(item["mask_pseudo"], 3)[0] > 0.5  # the same pixels for every placement
    n_values = int(pixels.sum()) * image.shape[0]
    model = texture_model(image.shape[-1])

    def placement(z):
        return placed(p, start + np.asarray(z) * width)

    def objective(z):
        maps = with_coarse_fit({"image": image}, placement(z))
        mask = pixels & (maps["mask_pseudo"][0] > 0.5)
        if mask.sum() < 0.8 * pixels.sum():  # the face moved off the pixels: no fit there
            return 1e12
        data = prepare(image, maps["normal_pseudo"], mask)
        texture = (model.at_pixels(maps["uv_pseudo"], data.index), model.variance)
        fit = score(data, 2, texture=texture, texture_iterations=4)
        albedo = texture_albedo(texture[0], fit["texture"])
        mse = ((data.y - albedo * (data.basis @ np.array(fit["light"]).T)) ** 2).mean()
        return 0.5 * n_values * math.log(mse) + 0.5 * (np.asarray(z) ** 2).sum()

    return objective, placement


def refine_placement(p: dict, item: dict, noise: float, seed: int, evaluations: int = 200) -> dict:
    """``item`` with its coarse fit's maps rendered again at the fit's placement (pose, scale, shift; in scene
    parameters ``p``, :func:`coarse_fit_of`) refined against the image: the minimum of :func:`placement_objective`
    by Powell's method within 3 prior widths of the coarse fit, ``evaluations`` renders at most.  It finds the
    placement at which the coarse fit's shape best explains the image, which is not the scene's own where that shape
    is wrong.  The prior's widths are the SynthFaces coarse fit's errors, for a photo's landmark fit too."""
    from scipy.optimize import minimize

    objective, placement = placement_objective(p, item, noise, seed)
    z = minimize(objective, np.zeros(6), method="Powell", bounds=[(-3, 3)] * 6, options={"maxfev": evaluations})
    return with_coarse_fit(item, placement(z.x))


def scene_geometry(ds, index: int, item: dict, normals: str, noise: float, seed: int) -> dict:
    """``item`` (scene ``index`` of ``ds``; None for a photo) with the maps geometry ``normals`` reads: the coarse
    fit rendered again at its placement refined against the image (a scene's or a photo's fit) or with its parts
    set to a scene's truth, or a network's maps of the image; noise ``noise`` of seed ``seed`` on the image (the
    pixels the fit then sees, :func:`item_data`)."""
    if normals not in GEOMETRY:
        raise ValueError(f"unknown geometry {normals!r}; choose from {', '.join(GEOMETRY)}")
    geometry = GEOMETRY[normals]
    if geometry.made_true and ds is None:
        raise ValueError(f"geometry {normals!r} sets the coarse fit to a SynthFaces scene's truth: it needs one")
    if geometry.place:
        item = refine_placement(coarse_fit_of(ds, index, item), item, noise, seed)
    if geometry.made_true:
        item = coarse_fit_made_true(ds, index, item, geometry.made_true)
    if geometry.network:
        item = item | network_maps(geometry.network, noisy(item["image"], noise, seed))
    return item


ALBEDO = ("known", "constant", "texture")


def noisy(image: torch.Tensor, noise: float, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return image.double() + noise * torch.randn(image.shape, generator=g, dtype=torch.float64)


# where each uv map is defined: a texture model reaches no pixel outside it (the pseudo uv is 0 off the coarse fit's
# mask, the true uv off the matte)
UV_DEFINED = {"uv": "matte", "uv_pseudo": "mask_pseudo", "uv_net": "matte_net"}


def item_data(
    item: dict,
    noise: float = 0.02,
    seed: int = 0,
    mask=None,
    known_albedo: bool = True,
    gray=False,
    normals: str = "normal",
    texture: bool = False,
):
    """One item's pixels on its true (``normals="normal"``, matte) or pseudo (``normal_pseudo``,
    mask_pseudo) geometry; ``mask`` overrides the mask; ``texture``: only where the geometry's uv is defined
    (:data:`UV_DEFINED`), for the texture model."""
    geometry = GEOMETRY[normals]
    mask = item[geometry.mask] if mask is None else mask
    if geometry.erosion:
        mask = eroded(mask, geometry.erosion)
    if texture:
        mask = (torch.as_tensor(mask) > 0.5) & (item[UV_DEFINED[geometry.uv]] > 0.5)
    albedo = item["albedo"] if known_albedo else None
    return prepare(noisy(item["image"], noise, seed), item[geometry.normals], mask, albedo, gray=gray)


def band_width(post, level: float = 0.68) -> dict:
    """Mean credible-interval width per SH band, over channels."""
    lo, hi = post.interval(level)
    w = hi - lo
    return {f"band{b}": float(w[:, k].mean()) for b, k in BANDS.items()}


def save_json(name: str, obj, out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.json"
    path.write_text(json.dumps(obj, indent=2))
    return path


# ----------------------------------------------------------------------------- widths
def central_mask(matte: torch.Tensor, fraction: float) -> torch.Tensor:
    """The ``fraction`` of matte pixels nearest the matte's centroid."""
    m = matte[0] > 0.5
    ys, xs = torch.nonzero(m, as_tuple=True)
    d = (ys - ys.float().mean()) ** 2 + (xs - xs.float().mean()) ** 2
    keep = d <= torch.quantile(d.float(), fraction)
    out = torch.zeros_like(m)
    out[ys[keep], xs[keep]] = True
    return out[None].float()


def widths(ds, n_faces: int = 3, noise: float = 0.02) -> dict:
    """68 % interval width per SH band against yaw, mask fraction and noise (Gaussian likelihood)."""
    res = {"yaw": {}, "mask_fraction": {}, "noise": {}}
    for face in range(n_faces):
        for yaw in (0, 20, 40, 60, 80):
            item = ds.sample(face, pose=(float(yaw), 0.0, 0.0))
            res["yaw"].setdefault(yaw, []).append(band_width(sample_posterior(item_data(item, noise, face))))
        item = ds.sample(face)
        for frac in (1.0, 0.5, 0.25, 0.1):
            post = sample_posterior(item_data(item, noise, face, mask=central_mask(item["matte"], frac)))
            res["mask_fraction"].setdefault(frac, []).append(band_width(post))
        for sigma in (0.005, 0.01, 0.02, 0.05):
            res["noise"].setdefault(sigma, []).append(band_width(sample_posterior(item_data(item, sigma, face))))
    return {
        axis: {str(k): {b: float(np.mean([r[b] for r in v])) for b in v[0]} for k, v in d.items()}
        for axis, d in res.items()
    }


def plot_widths(w: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    for ax, (axis, label) in zip(
        axes, [("yaw", "yaw (deg)"), ("mask_fraction", "mask fraction"), ("noise", "noise std")]
    ):
        xs = [float(k) for k in w[axis]]
        for b in ("band0", "band1", "band2"):
            ax.plot(xs, [w[axis][k][b] for k in w[axis]], "o-", label=f"SH band {b[-1]}")
        ax.set_xlabel(label)
        ax.set_yscale("log")
        if axis == "noise":
            ax.set_xscale("log")
            ax.set_xticks(xs, [f"{x:g}" for x in xs])
            ax.minorticks_off()
    axes[0].set_ylabel("mean 68% interval width")
    axes[0].legend()
    fig.suptitle("Posterior width of the SH light (known albedo, Gaussian likelihood)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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
def lhat_sources(test, train, n: int = 256, networks=("explicit", "implicit")) -> dict:
    """How far L-hat's light lies from the true light on the face, and with which of its inputs made true.

    The first ``n`` items of ``test`` (noise-free, as training sees them); each light is scored as the report scores
    the networks': its shading through the true normals against the true light's, scale-invariant per image and
    channel, on the scored pixels (the true face inside M-hat; ``light_on_face``, with its standard error over the
    faces, and ``beats_lhat``, the share of faces where it is below the paper's L-hat), and the SH error along the
    directions the face shows (``shown``); ``skin_tone_corr`` and ``skin_brightness_corr``: how much of each face's
    skin its shading carries there (:func:`disent.eval.evaluate.skin_in_shading`; a per-face, per-channel scale that
    light on the face is blind to, and that the light hands on to the albedo); ``contrast``, ``pattern_corr``,
    ``contrast_ratio`` and ``log_error``: the medians over faces and channels of
    :func:`disent.eval.metrics.shading_contrast`'s slope, correlation, magnitude and error against the true light
    there (a slope below 1 leaves the rest of the shading to the albedo). ``LHAT_SOURCES`` are least-squares
    fits (:func:`disent.data.synth.scenes.fit_sh_packed`) of the image over the albedo; *template*: the mean train
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
    return {"split": test.split, "n": len(reference), "rows": rows}


# ----------------------------------------------------------------------------- calibration
def calibration(
    ds,
    n_images: int = 12,
    noise: float = 0.02,
    severity: float = 0.5,
    conditions=("lambertian", "specular", "cast_shadow", "specular+cast_shadow"),
    normals: str = "normal",
) -> dict:
    """Share of true SH coefficients inside the 68 % / 95 % intervals, per likelihood and effect.

    ``z_rms`` is the RMS of (posterior mean - truth) / posterior sd: 1 when calibrated, larger
    when the intervals are overconfident.
    """
    out = {}
    for condition in conditions:
        effects = None if condition == "lambertian" else {e: severity for e in condition.split("+")}
        for likelihood in ("gaussian", "student_t"):
            inside = {0.68: [], 0.95: []}
            z, conv = [], []
            for i in range(n_images):
                item = ds.sample(i, effects=effects) if effects else ds[i]
                post = sample_posterior(item_data(item, noise, i, normals=normals), likelihood=likelihood, seed=i)
                truth = item["sh"].double().numpy()
                for level in inside:
                    lo, hi = post.interval(level)
                    inside[level].append(((truth >= lo) & (truth <= hi)).ravel())
                z.append(((post.mean - truth) / post.std).ravel())
                conv.append(post.diagnostics["converged"])
            z = np.concatenate(z)
            out[f"{condition}/{likelihood}"] = {
                "inside68": float(np.concatenate(inside[0.68]).mean()),
                "inside95": float(np.concatenate(inside[0.95]).mean()),
                "z_rms": float(np.sqrt(np.mean(z**2))),
                "n_coefficients": int(z.size),
                "converged": float(np.mean(conv)),
            }
    out["settings"] = {"n_images": n_images, "noise": noise, "severity": severity, "normals": normals}
    return out


def plot_calibration(c: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    keys = [k for k in c if k != "settings"]
    fig, ax = plt.subplots(figsize=(10, 3.6))
    x = np.arange(len(keys))
    ax.bar(x - 0.2, [c[k]["inside68"] for k in keys], 0.4, label="inside 68% interval")
    ax.bar(x + 0.2, [c[k]["inside95"] for k in keys], 0.4, label="inside 95% interval")
    ax.axhline(0.68, color="C0", ls="--", lw=1)
    ax.axhline(0.95, color="C1", ls="--", lw=1)
    ax.set_xticks(x, [k.replace("/", "\n").replace("+", "+\n") for k in keys], fontsize=8)
    ax.set_ylim(0, 1)
    ax.set_ylabel("share of true coefficients")
    ax.set_title(
        f"Calibration of the SH-light intervals ({c['settings'].get('normals', 'normal')}, "
        f"{c['settings']['n_images']} images, noise "
        f"{c['settings']['noise']}, effect severity {c['settings']['severity']})"
    )
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- order choice
def light_of_order(sh: torch.Tensor, order: int) -> torch.Tensor:
    """The scene's light cut to SH band ``order``; ambient raised so the front-facing normals
    (n_z >= -0.3, as the generator checks) stay at least 4 % of the peak shading."""
    sh = sh.double().clone()
    sh[:, N_COEFFS[order] :] = 0
    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(4096, 3, generator=g, dtype=torch.float64), dim=1)
    B = sh_basis(n[n[:, 2] >= -0.3].T.contiguous(), 0)  # [9, M]
    s = sh @ B
    sh[:, 0] += (0.04 * s.amax(1) - s.amin(1)).clamp_min(0) / C4
    return sh.float()


def order_data(
    item: dict, noise: float, seed: int, albedo: str = "constant", normals: str = "normal", n_components: int = 20
):
    """``(LightingData, texture or None)`` of one item for the order choice.

    ``albedo``: ``known`` (the true map), ``constant`` (L-hat's assumption) or ``texture``
    (:mod:`disent.lighting.texture`, mapped through the geometry's UV); ``normals``:
    ``normal`` (true normals, matte, uv) or ``normal_pseudo`` (the coarse fit's, with its mask and uv).
    """
    from disent.lighting.texture import texture_for

    if albedo not in ALBEDO or normals not in GEOMETRY:
        raise ValueError(f"albedo must be one of {ALBEDO} and normals one of {tuple(GEOMETRY)}")
    data = item_data(item, noise, seed, known_albedo=albedo == "known", normals=normals, texture=albedo == "texture")
    if albedo != "texture":
        return data, None
    return data, texture_for(data, uv_of(item, data, normals, n_components), n_components)


def uv_of(item: dict, data, normals: str, n_components: int = 20) -> torch.Tensor:
    """The uv through which the texture model reaches ``data``'s pixels on geometry ``normals``: the item's,
    registered to the image first where the geometry says so (:func:`disent.lighting.texture.register`)."""
    from disent.lighting.texture import register, registration_prior, texture_model

    geometry, uv = GEOMETRY[normals], item[GEOMETRY[normals].uv]
    if not geometry.register:
        return uv
    # the prior of the affine corrections: of the pseudo uv, or of the network's own uv where the row reads that
    own = geometry.network if geometry.uv == "uv_net" else ""
    prior = registration_prior(uv.shape[-1], network=own)
    return register(data, uv, texture_model(uv.shape[-1], n_components), prior=prior)


def order_scene(ds, index: int, order: int, noise: float, albedo: str, normals: str, n_components: int = 20):
    """``(sh, item, data, texture)`` of the order study's scene: item ``index`` of ``ds`` under its own light cut to
    ``order``, noisy (seed ``1000 order + index``), on the geometry ``normals`` (:func:`scene_geometry`) with the
    albedo model ``albedo`` (:func:`order_data`)."""
    sh = light_of_order(ds[index]["sh"], order)
    seed = 1000 * order + index
    item = scene_geometry(ds, index, ds.sample(index, sh=sh), normals, noise, seed)
    return (sh, item, *order_data(item, noise, seed, albedo, normals, n_components))


def order_confusion(
    ds,
    n_per_order: int = 30,
    noise: float = 0.02,
    albedo: str = "constant",
    normals: str = "normal",
    n_components: int = 20,
    noise_model: dict | None = None,
) -> dict:
    """Confusion matrices (true order x chosen order) for the evidence and for BIC.

    Item ``i`` of ``ds`` is relit with its own light cut to each order (:func:`light_of_order`);
    ``noise_model``: keyword arguments of :func:`~disent.lighting.order.select_order` (``normal_sigma``,
    ``residual``); default i.i.d. noise.  ``band2_share``: the medians of :func:`~disent.lighting.order.band2_share`
    of the largest candidate's light by true order, and of the true order-2 lights: where the fit puts as much in
    band 2 for an order-1 scene as a true order-2 light has, no criterion built on the fit can tell them apart.
    """
    from disent.lighting.order import band2_share

    conf = {"evidence": np.zeros((3, 3), int), "bic": np.zeros((3, 3), int)}
    colour = {"evidence": {}, "bic": {}}
    band2 = {"fitted": [[], [], []], "true": []}  # the largest candidate's band-2 share by true order; the truth's
    scenes = {k: [] for k in ("index", "true_order", "evidence", "bic", "yaw", "pixels")}  # each scene's outcome
    yaw = ds.params(list(range(n_per_order)))["pose"][:, 0].tolist()  # each face's, degrees
    for order in range(3):
        for i in range(n_per_order):
            sh, item, data, texture = order_scene(ds, i, order, noise, albedo, normals, n_components)
            scores = select_order(data, texture=texture, **(noise_model or {}))["scores"]
            band2["fitted"][order].append(band2_share(list(scores.values())[-1]["light"]))
            if order == 2:
                band2["true"].append(band2_share(sh))
            for crit in conf:
                r = choose(scores, crit)
                conf[crit][order, r["order"]] += 1
                colour[crit][r["choice"]] = colour[crit].get(r["choice"], 0) + 1
                scenes[crit].append(r["order"])
            scenes["index"].append(i)
            scenes["true_order"].append(order)
            scenes["yaw"].append(round(yaw[i], 2))
            scenes["pixels"].append(len(data.y))
    return {
        crit: {
            "confusion": m.tolist(),
            "accuracy": float(np.trace(m) / m.sum()),
            "per_order_recall": (np.diag(m) / m.sum(1)).tolist(),
            "chosen_models": colour[crit],
        }
        for crit, m in conf.items()
    } | {
        "band2_share": {  # medians: what the largest candidate fits into band 2, by true order, and the truth's
            "fitted_by_true_order": [float(np.median(v)) for v in band2["fitted"]],
            "true_order2": float(np.median(band2["true"])) if band2["true"] else None,
        },
        "scenes": scenes,  # per scene: its index, true order, the order each criterion chose, yaw (deg), pixels fitted
        "settings": {
            "split": ds.split,
            "seed": ds.seed,
            "machine": machine_info(),  # the placed geometry's Powell path depends on the libraries' floating point
            "n_per_order": n_per_order,
            "noise": noise,
            "albedo": albedo,
            "normals": normals,
            "n_components": n_components if albedo == "texture" else 0,
            "noise_model": noise_model or {},
        },
    }


# The geometry-error noise model (disent.lighting.order) for pseudo geometry.  normal_sigma: the pseudo-GT's
# measured mean angular error on SynthFaces, 11.5 deg = 0.20 rad, as the per-axis std of an isotropic tangent
# Gaussian (mean |delta n| = sigma sqrt(pi/2)); set from that measurement, not fitted to the order choice.
GEOMETRY_NOISE = {"normal_sigma": 0.16}


def geometry_noise(normals: str) -> dict:
    """The geometry-error noise model of geometry ``normals``: :data:`GEOMETRY_NOISE` for the pseudo-GT's maps; for
    a network row, the same reading of the shipped model's own measured mean normal error (its test metrics in
    ``disent/weights/manifest.json``)."""
    network = GEOMETRY[normals].network
    if not network:
        return GEOMETRY_NOISE
    from disent.models.shipped import manifest

    mean = np.radians(manifest()[network]["metrics"]["normal_mean"])
    return {"normal_sigma": float(mean / np.sqrt(np.pi / 2))}


# (albedo, normals[, noise model]); "residual_process": rho, ell by fit_residual_process on train scenes, on the
# row's own geometry; "geometry_noise+residual_process": both, rho and ell fitted beside the geometry noise
ORDER_ROWS = (
    ("known", "normal"),
    ("constant", "normal"),
    ("texture", "normal"),
    ("known", "normal_pseudo"),
    ("constant", "normal_pseudo"),
    ("texture", "normal_pseudo"),
    ("known", "normal_pseudo", "geometry_noise"),
    ("texture", "normal_pseudo", "geometry_noise"),
    ("texture", "normal_pseudo", "residual_process"),
    ("texture", "normal_pseudo_eroded"),
    ("texture", "normal_pseudo_eroded", "residual_process"),
    ("texture", "normal_pseudo_registered"),
    ("texture", "normal_pseudo_registered", "residual_process"),
    ("texture", "oracle_uv"),
    ("texture", "oracle_normals"),
    ("texture", "oracle_placement"),
    ("texture", "oracle_shape"),
    ("known", "network_explicit"),
    ("known", "network_implicit"),
    ("known", "network_explicit", "geometry_noise"),
    ("known", "network_implicit", "geometry_noise"),
    ("texture", "network_explicit", "geometry_noise"),
    ("texture", "network_implicit", "geometry_noise"),
    ("texture", "network_explicit", "residual_process"),
    ("texture", "network_implicit", "residual_process"),
    ("texture", "network_implicit_registered", "geometry_noise"),
    ("texture", "normal_pseudo_registered", "geometry_noise+residual_process"),
    ("texture", "network_explicit", "geometry_noise+residual_process"),
    ("texture", "network_implicit", "geometry_noise+residual_process"),
    ("texture", "oracle_uv_network", "geometry_noise"),
    ("texture", "normal_pseudo_placed"),
    ("texture", "normal_pseudo_placed", "residual_process"),
    ("texture", "oracle_placement", "residual_process"),
    ("known", "normal_pseudo_placed", "geometry_noise"),
    ("texture", "normal_pseudo_placed_registered", "residual_process"),
    ("texture", "network_explicit_placed", "residual_process"),
    ("texture", "normal_pseudo_placed_registered", "residual_process+student_t"),
    ("texture", "network_explicit_placed", "residual_process+student_t"),
)
ORDER_TARGET = 0.85  # share of scenes whose lighting order is chosen right on pseudo geometry
NOISE_MODELS = ("geometry_noise", "residual_process", "geometry_noise+residual_process", "residual_process+student_t")
# "+student_t": the whitened noise Student-t of STUDENT_T_NU degrees of freedom (disent.lighting.order.score); nu
# chosen on val among 4 and 10 (120 scenes of the normal_pseudo_placed_registered row: 0.91 and 0.93 against 0.87;
# on all 300 of its val scenes 0.900 and 0.903)
STUDENT_T_NU = 10.0
RESIDUAL_GRID = {"rho": (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0), "ell": (0.5, 1.0, 2.0, 4.0)}


def true_light_residuals(
    ds, n_scenes: int, noise: float = 0.02, normals: str = "normal_pseudo", normal_sigma: float = 0.0
) -> list:
    """``(data, residual [P, C], extra)`` of scenes ``0..n-1`` of ``ds`` (lights cut to order ``i % 3``) on the
    pseudo geometry ``normals`` (a key of :data:`GEOMETRY`): the image less the texture model's albedo (ridge fit
    under its PCA prior, and a gain per channel) times the scene's true light through the pseudo normals, the misfit
    the right lighting model leaves; ``extra [P, C]``: the variance the geometry noise ``normal_sigma`` adds to each
    value at that light and albedo (:func:`~disent.lighting.order.geometry_variance`; None where 0)."""
    from dataclasses import replace

    from disent.lighting.order import geometry_variance, texture_albedo, texture_coefficients
    from disent.lighting.texture import texture_for

    out = []
    for i in range(n_scenes):
        sh = light_of_order(ds[i]["sh"], i % 3)
        item = scene_geometry(ds, i, ds.sample(i, sh=sh), normals, noise, 7000 + i)
        data = item_data(item, noise, 7000 + i, known_albedo=False, normals=normals, texture=True)
        tex, variance = texture_for(data, uv_of(item, data, normals))
        shading = data.basis @ sh.double().numpy().T  # [P, C]
        beta, _ = texture_coefficients(tex, variance, shading, data.y, np.full(data.y.shape, noise**2))
        albedo = texture_albedo(tex, beta)
        gain = (albedo * shading * data.y).sum(0) / ((albedo * shading) ** 2).sum(0)
        data = replace(data, albedo=gain * albedo)
        extra = geometry_variance(data, sh.double().numpy(), normal_sigma) if normal_sigma > 0 else None
        out.append((data, data.y - data.albedo * shading, extra))
    return out


def fit_residual_process(
    ds, n_scenes: int = 18, grid: dict = RESIDUAL_GRID, normals: str = "normal_pseudo", normal_sigma: float = 0.0
) -> dict:
    """``rho, ell`` of the order choice's residual process (:class:`disent.lighting.order.Whitener`) by maximum
    likelihood (sigma profiled) over :func:`true_light_residuals` of ``ds`` (the train split) on the geometry
    ``normals``, with the geometry noise ``normal_sigma`` beside it (0: the residual process alone), on a grid;
    returns ``{"rho", "ell", "log_likelihood": {"rho,ell": value}}``."""
    fit = max_likelihood_residual(true_light_residuals(ds, n_scenes, normals=normals, normal_sigma=normal_sigma), grid)
    return fit | {"n_scenes": n_scenes, "split": ds.split, "normals": normals, "normal_sigma": normal_sigma}


def max_likelihood_residual(residuals: list, grid: dict = RESIDUAL_GRID) -> dict:
    """``{"rho", "ell", "log_likelihood"}``: the grid point of the largest summed log-likelihood of the
    ``(data, residual [P, C], extra)`` triples under the residual process (beside the geometry's variance ``extra
    [P, C]``, or None), sigma at its maximum per triple."""
    from disent.lighting.order import Whitener, noise_variance, unit

    table = {}
    for rho in grid["rho"]:
        for ell in grid["ell"]:
            total = 0.0
            for data, r, extra in residuals:
                whiten = Whitener(data, rho, ell)
                v = noise_variance(r, extra, whiten)
                u = unit(r, v, whiten)
                total += -0.5 * (
                    r.size * np.log(2 * np.pi) + (u**2).sum() + np.log(v).sum() + r.shape[1] * whiten.log_det
                )
            table[f"{rho:g},{ell:g}"] = total
    rho, ell = map(float, max(table, key=table.get).split(","))
    return {"rho": rho, "ell": ell, "log_likelihood": table}


def noise_parts(model: str) -> tuple[bool, bool, bool]:
    """``(geometry noise, residual process, Student-t)``: whether the noise model ``model`` (``iid`` or one of
    :data:`NOISE_MODELS`) has each part."""
    if model not in ("iid", *NOISE_MODELS):
        raise ValueError(f"unknown noise model {model!r}; choose from iid, {', '.join(NOISE_MODELS)}")
    parts = model.split("+")
    return "geometry_noise" in parts, "residual_process" in parts, "student_t" in parts


def fit_key(normals: str, model: str) -> str:
    """The key of a row's residual fit in ``residual_process.json``: its geometry, and ``+geometry_noise`` where the
    fit had the geometry noise beside it."""
    return normals + ("+geometry_noise" if noise_parts(model)[0] else "")


def read_study(folder: Path | None, name: str = "order") -> dict:
    """``{name: rows, "residual_process": fits}`` of the order study in ``folder`` (``{}`` for a file it lacks, or
    for no folder)."""
    files = (name, "residual_process")
    return {
        f: json.loads((Path(folder) / f"{f}.json").read_text())
        if folder and (Path(folder) / f"{f}.json").exists()
        else {}
        for f in files
    }


def noise_model(normals: str, model: str, fits: dict) -> dict:
    """:func:`~disent.lighting.order.select_order`'s keyword arguments of the noise model ``model`` (``iid`` or one of
    :data:`NOISE_MODELS`) on the geometry ``normals``; ``fits``: the residual fits (``residual_process.json``)."""
    geometry, residual, student_t = noise_parts(model)
    kwargs = (geometry_noise(normals) if geometry else {}) | ({"nu": STUDENT_T_NU} if student_t else {})
    if residual:
        if fit_key(normals, model) not in fits:
            raise ValueError(f"no residual fit {fit_key(normals, model)!r} in the study; its fits: {', '.join(fits)}")
        fit = fits[fit_key(normals, model)]
        kwargs = kwargs | {"residual": (fit["rho"], fit["ell"])}
    return kwargs


def best_on_val(order: dict, accept) -> str | None:
    """The name (after ``val/``) of the order study's val row of best evidence accuracy among those whose name
    ``accept(name)`` takes; None where there is none."""
    rows = [k[4:] for k in order if k.startswith("val/") and accept(k[4:])]
    return max(rows, key=lambda k: order[f"val/{k}"]["evidence"]["accuracy"], default=None)


def chosen_noise_model(albedo: str, normals: str, study: Path, model: str = "auto") -> tuple[str, dict]:
    """``(model, select_order keyword arguments)``: the noise model ``model`` on the geometry ``normals``, its residual
    fit read from the order study in folder ``study``; ``auto``: the noise model of the study's ``albedo/normals`` row
    best on val (``iid`` where the study has no such row)."""
    study = read_study(study)
    order, fits = study["order"], study["residual_process"]
    if model == "auto":
        row = f"{albedo}/{normals}"
        best = best_on_val(order, lambda k: k == row or k.startswith(f"{row}+")) or row
        model = best[len(row) + 1 :] or "iid"
    return model, noise_model(normals, model, fits)


def row_key(row: tuple) -> str:
    """``albedo/normals[+noise model]``: an order-study row's name (its key in ``order.json`` after ``split/``)."""
    albedo, normals, *model = row
    return f"{albedo}/{normals}" + (f"+{model[0]}" if model else "")


def order_study(
    out: Path,
    splits=("val", "test"),
    rows=ORDER_ROWS,
    n_per_order: int = 20,
    noise: float = 0.02,
    resolution: int = 64,
    seed: int = 0,
    name: str = "order",
    n_train_scenes: int = 18,
    only=None,
    keep: Path | None = None,
) -> dict:
    """The order-choice confusion matrices of every ``(albedo, normals[, noise model])`` row on each split
    (the residual process fitted first on ``n_train_scenes`` train scenes, per geometry of a row that uses it,
    ``out/residual_process.json``; a fit the earlier study in ``keep`` holds is kept, so that rows on one geometry,
    compared on the same scenes, differ only in what their names say);
    written to ``out/<name>.json`` (the method and its constants are chosen on
    ``val``; ``test`` only reports).

    ``only``: names of the rows (:func:`row_key`) to compute; every other row, and its residual fit, is copied from
    the earlier study in folder ``keep`` (``<name>.json``, ``residual_process.json``) where it has one, so that a
    new row joins a published study without running the others again; so is every row of a split not in ``splits``
    (a row read again on test alone, with more scenes, keeps its val entry).
    """
    from disent.data import SynthFaces

    names = [row_key(row) for row in rows]
    unknown = sorted(set(only or ()) - set(names))
    if unknown:
        raise ValueError(f"unknown order-study rows {unknown}; rows: {', '.join(names)}")
    todo = [row for row in rows if only is None or row_key(row) in only]
    earlier = read_study(keep, name)
    result, fits = {}, dict(earlier["residual_process"])
    train = SynthFaces("train", resolution, seed)
    for normals, model in dict.fromkeys((row[1], row[2]) for row in todo if row[2:] and noise_parts(row[2])[1]):
        if fit_key(normals, model) in fits:  # kept: the rows on one geometry read with one fit
            continue
        geometry = geometry_noise(normals)["normal_sigma"] if noise_parts(model)[0] else 0.0
        fits[fit_key(normals, model)] = fit_residual_process(
            train, n_train_scenes, normals=normals, normal_sigma=geometry
        )
        save_json("residual_process", fits, out)

    # val first, then the splits computed here, then those only kept, each split's rows in the order of ``rows``
    for split in dict.fromkeys(("val", *splits, *(k.split("/", 1)[0] for k in earlier[name]))):
        ds = SynthFaces(split, resolution, seed) if split in splits else None
        for row in rows:
            key = f"{split}/{row_key(row)}"
            if row not in todo or ds is None:
                if key in earlier[name]:
                    result[key] = earlier[name][key]
                continue
            albedo, normals, *model = row
            result[key] = order_confusion(
                ds,
                n_per_order,
                noise,
                albedo,
                normals,
                noise_model=noise_model(normals, model[0], fits) if model else None,
            )
            save_json(name, result, out)
    save_json(name, result, out)
    return result


def wilson_interval(share: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``share`` observed over ``n`` trials (95 % at ``z = 1.96``)."""
    centre = (share + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(share * (1 - share) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def plot_order_accuracy(study: dict, path: Path, criterion: str = "evidence") -> None:
    """Every row of :func:`order_study` on one axis: its accuracy on val and on test with 95 % intervals (Wilson,
    over the row's scenes), against :data:`ORDER_TARGET`; the confusion matrices themselves are in the JSON."""
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(key.split("/", 1)[1] for key in study))  # rows in the study's order, val's first
    splits = {"val": ("tab:blue", "none", -0.17), "test": ("tab:orange", "tab:orange", 0.17)}  # colour, fill, shift
    fig, ax = plt.subplots(figsize=(9, 1.2 + 0.24 * len(names)))
    for split, (colour, face, shift) in splits.items():
        rows = [(i, study[f"{split}/{name}"][criterion]) for i, name in enumerate(names) if f"{split}/{name}" in study]
        if not rows:
            continue
        y = np.array([i + shift for i, _ in rows])
        acc = np.array([r["accuracy"] for _, r in rows])
        lo, hi = np.array([wilson_interval(r["accuracy"], int(np.sum(r["confusion"]))) for _, r in rows]).T
        ax.errorbar(
            acc,
            y,
            xerr=np.clip((acc - lo, hi - acc), 0, None),
            fmt="o",
            color=colour,
            mfc=face,
            ms=4,
            lw=1,
            label=split,
        )
    ax.axvline(ORDER_TARGET, color="k", ls="--", lw=1, label=f"target {ORDER_TARGET:.2f}")
    ax.axvline(1 / 3, color="grey", ls=":", lw=1, label="one order for every scene (1/3)")  # the trivial choice
    ax.set_yticks(range(len(names)), [name.replace("+", " + ") for name in names], fontsize=7)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlim(0, 1)
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlabel(f"{criterion} accuracy of the order choice (95 % interval over the row's scenes)")
    ax.legend(fontsize=8, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.9 / fig.get_figheight()))
    fig.savefig(path, dpi=110, bbox_inches="tight")  # the row names run left of the figure
    plt.close(fig)


def refit_study_scene(ds, study: dict, row: str, split: str, k: int) -> tuple:
    """``(item, data, scores, truth, chosen, residuals)``: scene ``k`` of the order-study row ``row`` on ``split``
    (``ds``; its scene records), fitted again as the study fitted it: every candidate's scores, the true order's best
    candidate and the chosen one, and those two's residuals ``[P, C]`` at the pixels fitted."""
    entry = study["order"][f"{split}/{row}"]
    records, settings = entry["scenes"], entry["settings"]  # the scene as order_confusion drew it
    albedo, geometry = row.split("/", 1)
    normals, _, model = geometry.partition("+")
    order = records["true_order"][k]
    _, item, data, texture = order_scene(
        ds, records["index"][k], order, settings["noise"], albedo, normals, settings["n_components"] or 20
    )  # n_components 0: no texture model
    result = select_order(data, texture=texture, **noise_model(normals, model or "iid", study["residual_process"]))
    scores, chosen = result["scores"], result["choice"]
    truth = max((n for n in scores if scores[n]["order"] == order), key=lambda n: scores[n]["log_evidence"])
    residuals = {name: data.y - fitted(data, scores[name], texture) for name in (truth, chosen)}
    return item, data, scores, truth, chosen, residuals


def order_failure_regions(ds, study: dict, row: str, split: str = "val", edge: int = 2) -> dict:
    """Where the misfit lies that makes the order choice fail: over every scene of ``split`` that the order-study
    row ``row`` gets wrong, fitted again (:func:`refit_study_scene`), how much the larger of the true order's best
    candidate and the chosen one lowers the squared residual (summed over channels) in each part of the face
    (:func:`~disent.data.synth.face_model.face_regions` at the scene's true uv; the pixels within ``edge`` px of
    the fitted region's border first, as the silhouette), as a share of what it lowers in all, beside the share of
    the fitted pixels each part holds. Returns ``{"row", "split", "kinds": {"TRUE->CHOSEN": {"scenes",
    "pixels_fitted", "reduction_share", "pixel_share"}}}``; a share of reduction above the share of pixels: the
    extra SH terms (chosen or turned down) fit that part more than the face as a whole."""
    from scipy.ndimage import binary_erosion

    from disent.data.synth.face_model import face_regions

    records = study["order"].get(f"{split}/{row}", {}).get("scenes")
    if not records:
        return {}
    kinds: dict = {}
    for k, (true, chosen_order) in enumerate(zip(records["true_order"], records["evidence"])):
        if true == chosen_order:
            continue
        item, data, scores, truth, chosen, residuals = refit_study_scene(ds, study, row, split, k)
        small, large = sorted((truth, chosen), key=lambda n: scores[n]["order"])
        reduction = (residuals[small] ** 2 - residuals[large] ** 2).sum(1)  # [P]
        fitted_pixels = np.zeros(data.shape, bool)
        fitted_pixels.flat[data.index] = True
        inner = binary_erosion(fitted_pixels, iterations=edge)
        parts = {"silhouette": ~inner} | {
            name: region.numpy() & inner for name, region in face_regions(item["uv"].permute(1, 2, 0)).items()
        }
        parts["rest"] = ~np.any(list(parts.values()), axis=0)  # the parts of the face, then the rest of the fit
        kind = kinds.setdefault(f"{true}->{chosen_order}", {"scenes": 0, "reduction": {}, "pixels": {}})
        kind["scenes"] += 1
        for name, part in parts.items():
            at = part.flat[data.index]
            kind["reduction"][name] = kind["reduction"].get(name, 0.0) + float(reduction[at].sum())
            kind["pixels"][name] = kind["pixels"].get(name, 0) + int(at.sum())
    for kind in kinds.values():
        total, n = sum(kind["reduction"].values()), sum(kind["pixels"].values())
        kind["pixels_fitted"] = n
        kind["reduction_share"] = {name: r / total for name, r in kind.pop("reduction").items()}
        kind["pixel_share"] = {name: p / n for name, p in kind.pop("pixels").items()}
    return {"row": row, "split": split, "kinds": dict(sorted(kinds.items()))}


def plot_order_failures(ds, study: dict, row: str, path: Path, n_scenes: int = 4) -> dict:
    """Why the order choice fails: up to ``n_scenes`` scenes of ``ds`` (val) that the order-study row ``row``
    (``albedo/normals[+noise model]``, read with its scene records) got wrong by the evidence, the first of each
    kind of error (true order, chosen order), fitted again as the study fitted them. Per scene: the noisy image, the
    pixels fitted, the residual of the true order's best candidate and of the chosen one, and their difference (what
    the chosen model's extra or missing SH terms fit).  Returns ``{"row", "scenes": [{index, true_order, chosen,
    evidence_gain}]}`` (the chosen candidate's log evidence over the true order's best); ``{}`` where the row has
    no such scene."""
    import matplotlib.pyplot as plt

    records = study["order"].get(f"val/{row}", {}).get("scenes")
    if not records:
        return {}
    pairs = list(zip(records["true_order"], records["evidence"]))
    first = {p: k for k, p in reversed(list(enumerate(pairs))) if p[0] != p[1]}  # each kind of error's first scene
    wrong = sorted(first.values())[:n_scenes]
    if not wrong:
        return {}
    fig, axes = plt.subplots(len(wrong), 5, figsize=(11, 2.4 * len(wrong)), squeeze=False)
    out = []
    for ax, k in zip(axes, wrong):
        order, i = records["true_order"][k], records["index"][k]
        item, data, scores, truth, chosen, residuals = refit_study_scene(ds, study, row, "val", k)
        picture = np.full((2, *data.shape), np.nan)
        for j, name in enumerate((truth, chosen)):
            picture[j].flat[data.index] = residuals[name].mean(1)
        gain = scores[chosen]["log_evidence"] - scores[truth]["log_evidence"]
        out.append({"index": i, "true_order": order, "chosen": scores[chosen]["order"], "evidence_gain": gain})
        mask = np.zeros(data.shape)
        mask.flat[data.index] = 1
        ax[0].imshow(item["image"].permute(1, 2, 0).clamp(0, 1).numpy())
        ax[0].set_title(f"val face {i}, true order {order}", fontsize=8)
        ax[1].imshow(mask, cmap="gray")
        ax[1].set_title(f"pixels fitted ({len(data.y)})", fontsize=8)
        limit = np.nanpercentile(np.abs(picture), 99)
        titles = (
            f"residual, order {order} ({truth})",
            f"residual, chosen order ({chosen})",
            "difference: what it fits",
        )
        for a, image, title in zip(ax[2:], (picture[0], picture[1], picture[0] - picture[1]), titles):
            a.imshow(image, cmap="RdBu", vmin=-limit, vmax=limit)
            a.set_title(title + (f"\nlog evidence {gain:+.0f} over order {order}" if a is ax[4] else ""), fontsize=8)
        for a in ax:
            a.axis("off")
    fig.suptitle(
        f"{row}\nval scenes the evidence got wrong (channel-mean residual; red: the image brighter than the fit)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return {"row": row, "scenes": out}


def plot_registration(ds, path: Path, n_scenes: int = 4, noise: float = 0.02, n_components: int = 20) -> dict:
    """The texture model's fitted albedo on the eroded pseudo mask, reached through the pseudo uv, the registered
    uv (:func:`disent.lighting.texture.register`) and the true uv, beside the image and the true albedo, for val
    scenes under order-1 light; each panel titled with its uv error (rms, pixels).  Returns those errors."""
    import matplotlib.pyplot as plt

    from disent.lighting.order import score
    from disent.lighting.texture import texture_for

    columns = {"normal_pseudo_eroded": "pseudo uv", "normal_pseudo_registered": "registered uv", "oracle_uv": "true uv"}
    fig, axes = plt.subplots(n_scenes, 2 + len(columns), figsize=(2.0 * (2 + len(columns)), 2.1 * n_scenes))
    errors = {c: [] for c in columns}
    for i in range(n_scenes):
        item = ds.sample(i, sh=light_of_order(ds[i]["sh"], 1))
        data = item_data(item, noise, 1000 + i, known_albedo=False, normals="normal_pseudo_eroded")
        truth = item["uv"].double().flatten(1)[:, data.index]
        H, W = data.shape
        panels = [(item["image"].permute(1, 2, 0).clamp(0, 1).numpy(), "image")]
        for c, label in columns.items():  # geometries with the same normals and mask, each with its uv
            uv = uv_of(item, data, c, n_components)
            tex, variance = texture_for(data, uv, n_components)
            beta = np.array(score(data, 2, texture=(tex, variance))["texture"])
            canvas = np.zeros((H * W, 3))
            canvas[data.index] = np.clip(tex[0] + np.einsum("j,jpc->pc", beta, tex[1:]), 0, None)
            canvas /= max(canvas.max(), 1e-6)
            rms = float(((uv.double().flatten(1)[:, data.index] - truth) ** 2).sum(0).mean().sqrt() * (W - 1) / 2**0.5)
            errors[c].append(rms)
            panels.append((canvas.reshape(H, W, 3), f"{label}, {rms:.1f} px"))
        albedo = item["albedo"].permute(1, 2, 0).numpy()
        panels.append((albedo / max(albedo.max(), 1e-6), "true albedo"))
        for ax, (img, title) in zip(axes[i], panels):
            ax.imshow(img)
            ax.set_title(title, fontsize=8)
            ax.axis("off")
    fig.suptitle("texture model fitted through each uv (eroded pseudo mask; uv error rms per axis, pixels)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {c: float(np.mean(v)) for c, v in errors.items()}


# ----------------------------------------------------------------------------- one image
def figures_for(post, item: dict, data, stem: Path, normal_key: str = "normal") -> list[Path]:
    """Corner plot (channel-summed light and log sigma) and the shading uncertainty map."""
    import corner
    import matplotlib.pyplot as plt

    K = N_COEFFS[post.order]
    names = [f"L{k + 1}" for k in range(K)]
    samples = np.column_stack([post.sh[:, :, :K].sum(1), post.log_sigma])
    fig = corner.corner(
        samples,
        labels=[f"$\\Sigma_c {n}$" for n in names] + [r"$\log\sigma$"],
        truths=None if "sh" not in item else list(item["sh"].double().sum(0)[:K].numpy()) + [None],
        quantiles=[0.16, 0.5, 0.84],
        show_titles=False,
    )
    corner_path = stem.with_name(stem.name + "_corner.png")
    fig.savefig(corner_path, dpi=50)
    plt.close(fig)
    mean, sd = post.shading_map(item[normal_key])
    inside = np.zeros(data.shape[0] * data.shape[1], bool)
    inside[data.index] = True
    inside = inside.reshape(data.shape)
    fig, axes = plt.subplots(1, 3, figsize=(9, 3.2))
    axes[0].imshow(item["image"].permute(1, 2, 0).clamp(0, 1).numpy())
    axes[0].set_title("image")
    axes[1].imshow(np.where(inside, mean.mean(0), np.nan), cmap="gray")
    axes[1].set_title("posterior mean shading")
    im = axes[2].imshow(np.where(inside, sd.mean(0), np.nan), cmap="magma")
    axes[2].set_title("posterior sd of shading")
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    map_path = stem.with_name(stem.name + "_shading_sd.png")
    fig.savefig(map_path, dpi=100)
    plt.close(fig)
    return [corner_path, map_path]


# ----------------------------------------------------------------------------- speed
def speed(ds=None, batch: int = 256, rounds: int = 3) -> dict:
    """Least-squares L-hat per image (batched ``fit_sh``) and the posterior (27 params, 64x64)."""
    from disent.bench import median_time
    from disent.data import SynthFaces

    ds = ds or SynthFaces("test", 64)
    item = ds[0]
    image = item["image"][None].expand(batch, -1, -1, -1).contiguous()
    normal = item["normal"][None].expand(batch, -1, -1, -1).contiguous()
    matte = item["matte"][None].expand(batch, -1, -1, -1).contiguous()
    ls = median_time(lambda: fit_sh(image, normal, matte), rounds)
    cpu = []  # CPU time too: on a shared machine wall time counts other people's work
    for _ in range(rounds):
        c0 = time.process_time()
        fit_sh(image, normal, matte)
        cpu.append(time.process_time() - c0)
    data = item_data(item, 0.02, 0)
    out = {
        "threads": torch.get_num_threads(),
        "ls_batch": batch,
        "ls_ms_per_image": 1000 * ls / batch,
        "ls_cpu_ms_per_image": 1000 * float(np.median(cpu)) / batch,
        "n_pixels": data.n_pixels,
    }
    for likelihood in ("gaussian", "student_t"):
        diag = [sample_posterior(data, likelihood=likelihood, seed=s).diagnostics for s in range(rounds)]
        out[f"posterior_{likelihood}_s"] = float(np.median([d["seconds"] for d in diag]))
        out[f"posterior_{likelihood}_cpu_s"] = float(np.median([d["cpu_seconds"] for d in diag]))
        out[f"posterior_{likelihood}_steps"] = float(np.median([d["n_steps"] for d in diag]))
    return out | {"order_choice_s": order_choice_speed(ds, rounds), "order_choice_items": rounds}


# the geometries whose order choice speed() times: the pseudo rows a photo can use, and the networks' best
SPEED_GEOMETRIES = (
    "normal_pseudo_registered",
    "normal_pseudo_placed",
    "normal_pseudo_placed_registered",
    "network_explicit_placed",
)


def order_choice_speed(ds, rounds: int = 3, geometries=SPEED_GEOMETRIES) -> dict:
    """``{geometry: seconds}``: the median over test items ``0..rounds-1`` of ``ds`` of one order choice without
    the true albedo (the geometry's maps, the texture model, the five candidates under the residual process), one
    core, the network's weights loaded beforehand."""
    for name in {GEOMETRY[g].network for g in geometries} - {""}:
        trained_network(name)
    times = {}
    for g in geometries:
        seconds = []
        for i in range(rounds):
            start = time.perf_counter()
            item = scene_geometry(ds, i, ds[i], g, 0.02, i)
            data, texture = order_data(item, 0.02, i, "texture", g)
            select_order(data, texture=texture, residual=(3.0, 1.0))
            seconds.append(time.perf_counter() - start)
        times[g] = float(np.median(seconds))
    return times


# ----------------------------------------------------------------------------- all of it
def order_report(
    out: Path,
    split: str = "test",
    resolution: int = 64,
    seed: int = 0,
    quick: bool = False,
    only=None,
    keep: Path | None = None,
    splits=None,
    n_per_order: int = 20,
    geometry: str | None = None,
) -> dict:
    """The report's order study on val and ``split`` (or on ``splits``) with ``n_per_order`` scenes per true order,
    its accuracy figure (:func:`plot_order_accuracy`; ``python -m disent.lighting task=order``; also part of
    :func:`run_all`), the registration figure (:func:`plot_registration`) and, for the row of the texture model on
    ``geometry`` with its noise model best on val, the scenes it gets wrong (:func:`plot_order_failures`) and where
    their misfit lies (:func:`order_failure_regions`, on val and ``split``); ``only``, ``keep``: compute only some
    rows and copy the rest (:func:`order_study`)."""
    from disent.data import SynthFaces

    n = 2 if quick else 1
    study = order_study(
        out,
        tuple(splits or ("val", split)),
        n_per_order=n_per_order // n,
        resolution=resolution,
        seed=seed,
        n_train_scenes=18 // n,
        only=only,
        keep=keep,
    )
    plot_order_accuracy(study, out / "order_accuracy.png")
    val = SynthFaces("val", resolution, seed)
    save_json("registration", plot_registration(val, out / "registration.png"), out)
    if geometry:
        model = chosen_noise_model("texture", geometry, out)[0]
        row = row_key(("texture", geometry) + ((model,) if model != "iid" else ()))
        written = read_study(out)  # the study as written, with its residual fits
        if failures := plot_order_failures(val, written, row, out / "order_failures.png"):
            save_json("order_failures", failures, out)
        regions = {
            s: order_failure_regions(val if s == "val" else SynthFaces(s, resolution, seed), written, row, s)
            for s in dict.fromkeys(("val", split))
        }
        if any(regions.values()):
            save_json("order_failure_regions", regions, out)
    return study


def run_all(
    out: Path,
    split: str = "test",
    resolution: int = 64,
    seed: int = 0,
    quick: bool = False,
    geometry: str | None = None,
) -> dict:
    """Every experiment of the report's lighting section; writes ``out/*`` (JSON and PNG), which
    ``python -m disent.report --publish OUT`` copies to ``reports/lighting/``."""
    from disent.data import SynthFaces
    from disent.runtime import single_core

    with single_core():
        return _run_all(SynthFaces(split, resolution, seed), Path(out), resolution, seed, quick, geometry)


def _run_all(ds, out: Path, resolution: int, seed: int, quick: bool, geometry: str | None = None) -> dict:
    from disent.data import SynthFaces

    split = ds.split
    out.mkdir(parents=True, exist_ok=True)
    summary, t0 = {}, time.perf_counter()
    n = 2 if quick else 1

    item = ds[0]
    data = item_data(item, 0.02, 0)
    post = sample_posterior(data)
    figures_for(post, item, data, out / "example")
    summary["example"] = post.summary() | {"true_sh": item["sh"].tolist()}
    save_json("example", summary["example"], out)

    summary["widths"] = widths(ds, n_faces=2 // n)
    save_json("widths", summary["widths"], out)
    plot_widths(summary["widths"], out / "widths.png")

    summary["calibration"] = calibration(ds, n_images=10 // n)
    save_json("calibration", summary["calibration"], out)
    plot_calibration(summary["calibration"], out / "calibration.png")

    summary["calibration_pseudo"] = calibration(
        ds, n_images=8 // n, normals="normal_pseudo", conditions=("lambertian", "specular", "cast_shadow")
    )
    save_json("calibration_pseudo", summary["calibration_pseudo"], out)
    plot_calibration(summary["calibration_pseudo"], out / "calibration_pseudo.png")

    summary["order"] = order_report(out, split, resolution, seed, quick, geometry=geometry)

    summary["lhat_sources"] = lhat_sources(ds, SynthFaces("train", resolution, seed))
    save_json("lhat_sources", summary["lhat_sources"], out)

    summary["speed"] = speed(ds)
    save_json("speed", summary["speed"], out)
    summary["seconds"] = time.perf_counter() - t0
    save_json("summary", {k: v for k, v in summary.items() if k != "example"}, out)
    return summary


__all__ = [
    "item_data",
    "widths",
    "calibration",
    "order_confusion",
    "order_data",
    "order_study",
    "fit_residual_process",
    "light_of_order",
    "figures_for",
    "speed",
    "run_all",
    "central_mask",
    "band_width",
    "plot_order_accuracy",
    "order_report",
    "eroded",
    "lhat_sources",
]

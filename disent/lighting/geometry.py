"""The geometry a lighting fit reads: the normals, mask and uv of each geometry row (the pseudo-GT, the
coarse fit placed or made partly true, a network's maps), the noisy image, and the data of a fit."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from disent.lighting.posterior import prepare
from disent.lighting.targets import EDGE, eroded
from disent.lighting.texture import network_maps

BANDS = {0: [0], 1: [1, 2, 3], 2: [4, 5, 6, 7, 8]}


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


TABLES = Path(__file__).with_name("tables.yaml")  # the lighting studies' tables, as data


def load_tables(path: Path = TABLES) -> dict:
    """``tables.yaml``: ``geometry`` as :class:`Geometry` rows (``erosion: edge`` and ``{edge}`` in a label: EDGE
    px) and ``order_rows`` as tuples."""
    import yaml

    raw = yaml.safe_load(path.read_text())
    geometry = {}
    for name, row in raw["geometry"].items():
        erosion = EDGE if row["erosion"] == "edge" else int(row["erosion"])
        row = {**row, "erosion": erosion, "label": row["label"].format(edge=EDGE)}
        geometry[name] = Geometry(**{**row, "made_true": tuple(row.get("made_true", ()))})
    return {"geometry": geometry, "order_rows": tuple(tuple(r) for r in raw["order_rows"])}


GEOMETRY = load_tables()["geometry"]


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

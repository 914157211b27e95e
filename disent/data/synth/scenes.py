"""SynthFaces scenes: the generator behind :class:`disent.data.SynthFaces`.

A scene is a face model instance (identity, expression, senior shape), a pose, an
albedo painted in UV space, an SH light, a background and, optionally, effects that
break the paper's image model.  With effects off the image is exactly Eqs. 2-6::

    image = composite(matte, image_formation(albedo, sh_shading(normal, sh)), background)

Randomness is counter-based: every number of item ``index`` of split ``split`` is a hash
of ``(seed, split, index, stream)`` (identity-level numbers hash the identity id), so an
item is the same whichever batch renders it, and any set of indices renders as one
vectorized batch.
"""

from __future__ import annotations

import math
from functools import lru_cache

import torch
import torch.nn.functional as F

from disent.data.attributes import ATTRIBUTES
from disent.render import (
    C2,
    C4,
    composite,
    eq5_coefficients,
    eq5_planes,
    fit_sh_packed,
    image_formation,
    sh_basis,
    sh_from_directions,
)
from disent.runtime import per_device, single_thread

from .face_model import (
    BROW_X,
    BROW_Y,
    CHIN_Y,
    EYE_H,
    EYE_W,
    EYE_X,
    EYE_Y,
    GRID_U,
    GRID_V,
    HAIRLINE_Y,
    MOUTH_W,
    MOUTH_Y,
    NOSE_BASE_Y,
    SLIT_ROWS,
    face_model,
    is_neck,
    layout,
    uv_to_angles,
)
from .raster import (
    grid_faces,
    grid_to_uv_map,
    grid_vertex_normals,
    interpolate_covered,
    paste,
    pick,
    rasterize_grids,
    sample_texture,
    to_camera,
    unit_planes,
)

EFFECTS = ("specular", "cast_shadow", "noise", "occluder")
ATTR_PRIOR = {"smiling": 0.5, "beard": 0.25, "eyeglasses": 0.2, "senior": 0.25}  # P(label = 1) in train/val/test
POSE_RANGE = (45.0, 20.0, 10.0)  # yaw, pitch, roll half-ranges in degrees
SCALE_RANGE = (0.70, 0.86)  # model units -> image units (head about 70% of the crop)
SHIFT_RANGE = 0.07  # image units of position jitter
PSEUDO_COMPONENTS = 4  # identity components the coarse fit recovers
PSEUDO_POSE_STD = (4.0, 3.0, 1.5)  # its pose error (degrees)
PSEUDO_GRID_STEP = 2  # the fit's mesh keeps every 2nd row and column of the grid


# ----------------------------------------------------------------------------- counter-based random numbers
_M32 = 0xFFFFFFFF


def _mix(x: torch.Tensor) -> torch.Tensor:
    """A 32-bit integer hash (lowbias32 shape, multipliers below 2**31 so int64 never overflows)."""
    x = x & _M32
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & _M32
    x = x ^ (x >> 15)
    x = (x * 0x2C1B3C6D) & _M32
    return x ^ (x >> 16)


STREAMS = {
    name: k
    for k, name in enumerate(("shape", "skin", "attrs", "expr", "pose", "light", "bg", "pseudo", "effects", "style"))
}


def uniform(key: torch.Tensor, stream: str, n: int, seed: int) -> torch.Tensor:
    """``[len(key), n]`` uniforms in (0, 1), a pure function of (seed, stream, key, column)."""
    key = key.long()
    h = _mix(_mix(torch.tensor(seed * 0x9E3779B1 + STREAMS[stream] * 0x85EBCA77)) ^ (key & _M32))
    h = _mix(h ^ _mix((key >> 32) & _M32))
    h = _mix(h[:, None] ^ ((torch.arange(n) * 0x27D4EB2F + 0x165667B1) & _M32))
    return ((h >> 8).float() + 0.5) / 2**24


def normal(key: torch.Tensor, stream: str, n: int, seed: int) -> torch.Tensor:
    u = uniform(key, stream, 2 * n, seed)
    return torch.sqrt(-2 * torch.log(u[:, :n])) * torch.cos(2 * math.pi * u[:, n:])  # Box-Muller


# ----------------------------------------------------------------------------- lighting
_CHECK_NORMALS = None


def _check_normals() -> torch.Tensor:
    """Normals the light must shade non-negatively: the visible hemisphere plus a margin
    (n_z >= -0.3), a dense Fibonacci set, as SH basis values ``[9, P]``."""
    global _CHECK_NORMALS
    if _CHECK_NORMALS is None:
        k = torch.arange(600, dtype=torch.float64) + 0.5
        z = 1 - 2 * k / 600
        phi = k * math.pi * (3 - math.sqrt(5))
        r = (1 - z * z).sqrt()
        n = torch.stack([r * phi.cos(), r * phi.sin(), z])
        _CHECK_NORMALS = sh_basis(n[:, z >= -0.3], 0)
    return _CHECK_NORMALS


def lights_to_sh(
    direction: torch.Tensor, intensity: torch.Tensor, ambient: torch.Tensor, exposure: torch.Tensor, floor: float = 0.04
) -> torch.Tensor:
    """Distant lights + ambient -> SH ``[N, 3, 9]``, made physically plausible.

    The order-2 projection of ``max(0, n.d)`` rings slightly negative; ambient is raised
    until the shading over the visible hemisphere is at least ``floor`` times its maximum,
    then the light is scaled so that the brightest channel peaks at ``exposure``.  Any
    albedo in [0, 1] then gives an image in [0, 1].
    """
    # float64: a scene's light must not depend on the batch it is drawn in (GEMM rounding).
    sh = sh_from_directions(direction.double(), intensity.double(), torch.as_tensor(ambient).double())  # [N, 3, 9]
    basis = _check_normals()
    s = sh @ basis  # [N, 3, P]
    lo, hi = s.amin(2), s.amax(2)
    sh[..., 0] += (floor * hi - lo).clamp_min(0) / C4
    hi = (sh @ basis).amax(2).amax(1)
    return (sh * (torch.as_tensor(exposure).double() / hi)[:, None, None]).float()


def _direction(az_deg: torch.Tensor, el_deg: torch.Tensor) -> torch.Tensor:
    a, e = torch.deg2rad(az_deg), torch.deg2rad(el_deg)
    return torch.stack([torch.sin(a) * torch.cos(e), torch.sin(e), torch.cos(a) * torch.cos(e)], -1)


def _tint(t: torch.Tensor, amount: float) -> torch.Tensor:
    """Colour temperature shift: t > 0 warm, t < 0 cool; ``[..., 3]``."""
    return torch.stack([1 + amount * t, torch.ones_like(t), 1 - amount * t], -1)


def sample_lights(u: torch.Tensor) -> dict:
    """The lighting prior from 12 uniforms per scene: a key light, a fill, a rim, ambient.

    Key light from the front half (azimuth +-75 deg, elevation -15..60 deg), a weaker fill
    from the other side, an optional rim light from behind, ambient 5-35% of the key,
    each slightly coloured.  Returns ``sh [N,3,9]``, ``direction [N,3,3]``, ``intensity [N,3,3]``.
    """
    key_az = -75 + 150 * u[:, 0]
    key = _direction(key_az, -15 + 75 * u[:, 1])
    fill = _direction(-torch.sign(key_az) * (20 + 60 * u[:, 2]), -10 + 50 * u[:, 3])
    rim = _direction(torch.sign(u[:, 4] - 0.5) * (110 + 50 * u[:, 5]), 10 + 40 * u[:, 6])
    strength = torch.stack([torch.ones_like(u[:, 0]), 0.1 + 0.45 * u[:, 7], 0.6 * u[:, 8] ** 2], 1)  # [N, 3]
    tints = _tint(2 * u[:, 9:12] - 1, 0.12)  # key, fill, ambient colours
    intensity = strength[..., None] * torch.stack([tints[:, 0], tints[:, 1], _tint(torch.zeros_like(u[:, 0]), 0)], 1)
    ambient = (0.05 + 0.3 * u[:, 10:11]) * tints[:, 2]
    exposure = 0.8 + 0.2 * u[:, 11]
    direction = torch.stack([key, fill, rim], 1)
    return {"sh": lights_to_sh(direction, intensity, ambient, exposure), "direction": direction, "intensity": intensity}


@single_thread()
def _light_bank() -> tuple[list[str], dict]:
    """At least 20 named conditions: a Multi-PIE-like arc of flashes, elevated lights and moods."""
    specs = []  # name, [(az, el, intensity, tint)], ambient, ambient tint
    for az in range(-90, 91, 15):
        specs.append((f"flash_az{az:+d}", [(az, 0, 1.0, 0.0)], 0.12, 0.0))
    specs += [
        ("top_left", [(-45, 45, 1.0, 0.0)], 0.12, 0.0),
        ("top", [(0, 60, 1.0, 0.0)], 0.12, 0.0),
        ("top_right", [(45, 45, 1.0, 0.0)], 0.12, 0.0),
        ("below", [(0, -35, 1.0, 0.0)], 0.15, 0.0),
        ("ambient", [(0, 0, 0.0, 0.0)], 1.0, 0.0),
        ("overcast", [(0, 70, 0.5, -0.5)], 0.5, -0.5),
        ("warm_left", [(-50, 20, 1.0, 1.0), (40, 0, 0.3, -0.5)], 0.15, 0.5),
        ("cool_right", [(50, 20, 1.0, -1.0), (-40, 0, 0.3, 0.5)], 0.15, -0.5),
        ("rembrandt_left", [(-45, 35, 1.0, 0.3)], 0.08, 0.0),
        ("rim_both", [(-130, 20, 0.8, 0.0), (130, 20, 0.8, 0.0), (0, 10, 0.35, 0.0)], 0.1, 0.0),
        ("sunset", [(70, 5, 1.0, 1.5)], 0.2, -1.0),
    ]
    names, sh = [], []
    for name, lights, amb, amb_tint in specs:
        K = len(lights)
        d = _direction(
            torch.tensor([l[0] for l in lights], dtype=torch.float32),
            torch.tensor([l[1] for l in lights], dtype=torch.float32),
        )
        inten = torch.tensor([l[2] for l in lights])[:, None] * _tint(torch.tensor([l[3] for l in lights]), 0.12)
        ambient = amb * _tint(torch.tensor(float(amb_tint)), 0.12)
        sh.append(lights_to_sh(d[None], inten[None].reshape(1, K, 3), ambient[None], torch.tensor([0.9]))[0])
        names.append(name)
    return names, torch.stack(sh)


LIGHT_NAMES, _BANK_SH = _light_bank()
LIGHT_BANK = {n: _BANK_SH[k] for k, n in enumerate(LIGHT_NAMES)}


# ----------------------------------------------------------------------------- albedo painted in UV space
LAYERS = (
    "lips",
    "blush",
    "brows",
    "sclera",
    "iris",
    "pupil",
    "lashes",
    "nostrils",
    "teeth",
    "mouth",
    "hair_short",
    "hair_long",
    "beard_full",
    "beard_goatee",
    "glasses_round",
    "glasses_square",
    "wrinkles",
    "eyebags",
)


def _ellipse(X, Y, cx, cy, rx, ry, soft=0.25):
    r = ((X - cx) / rx) ** 2 + ((Y - cy) / ry) ** 2
    return torch.sigmoid((1 - r) / soft)


def _ring(X, Y, cx, cy, rx, ry, width, square=False):
    p = 8.0 if square else 2.0
    r = (((X - cx) / rx).abs() ** p + ((Y - cy) / ry).abs() ** p) ** (1 / p)
    return torch.exp(-0.5 * ((r - 1) / width) ** 2)


@per_device
@lru_cache(maxsize=4)
@single_thread()
def paint_layers(res: int) -> torch.Tensor:
    """The fixed masks ``[L, res*res]`` in UV space (texel centres, align-corners grid).

    One mask per painted layer, in ``LAYERS`` order, each a few shapes on the face's angles: a catalogue read
    top to bottom, longer than a function should be because cutting it would only scatter the face's landmarks
    (``EYE_X``, ``MOUTH_Y``, ...) across helpers."""
    t = torch.linspace(0, 1, res, dtype=torch.float64)
    uv = torch.stack(torch.meshgrid(t, t, indexing="xy"), -1)
    theta, phi, slit = uv_to_angles(uv, layout().slit_row)
    X, Y, Z = torch.sin(theta) * torch.cos(phi), torch.sin(phi), torch.cos(theta) * torch.cos(phi)
    front = (Z > 0).double()
    ax = X.abs()
    in_slit = (slit >= 0).double()
    inside_mouth = in_slit * torch.sigmoid((MOUTH_W - 0.01 - ax) / 0.01)  # elsewhere the slit is closed skin
    out_slit = 1 - inside_mouth  # painting is continuous across the closed part of the slit
    g = torch.Generator().manual_seed(7)
    hair_noise = F.interpolate(
        torch.rand(1, 1, res // 2, res // 8, generator=g, dtype=torch.float64),
        size=(res, res),
        mode="bilinear",
        align_corners=False,
    )[0, 0]
    stubble = torch.rand(res, res, generator=g, dtype=torch.float64)
    L = {}
    L["lips"] = (
        out_slit
        * front
        * (
            _ellipse(X, Y, 0, MOUTH_Y + 0.025, MOUTH_W * 0.95, 0.045, 0.3)
            + _ellipse(X, Y, 0, MOUTH_Y - 0.04, MOUTH_W * 0.85, 0.055, 0.3)
        ).clamp(max=1)
    )
    L["blush"] = front * (_ellipse(ax, Y, 0.38, -0.12, 0.14, 0.1, 0.6))
    brow_c = BROW_Y + 0.035 - 0.18 * (ax - BROW_X) ** 2
    L["brows"] = (
        front
        * torch.sigmoid((0.028 - (Y - brow_c).abs()) / 0.008)
        * torch.sigmoid((0.11 - (ax - BROW_X - 0.01).abs() * (1 + 0.3 * (ax < BROW_X + 0.01))) / 0.015)
    )
    eye = _ellipse(ax, Y, EYE_X, EYE_Y, EYE_W, EYE_H, 0.12) * front
    L["sclera"] = eye
    L["iris"] = eye * _ellipse(ax, Y, EYE_X, EYE_Y, 0.045, 0.045, 0.15)
    L["pupil"] = eye * _ellipse(ax, Y, EYE_X, EYE_Y, 0.018, 0.018, 0.2)
    L["lashes"] = front * _ring(ax, Y, EYE_X, EYE_Y, EYE_W * 1.05, EYE_H * 1.3, 0.12) * (Y > EYE_Y - 0.01)
    L["nostrils"] = front * _ellipse(ax, Y, 0.05, NOSE_BASE_Y + 0.01, 0.025, 0.014, 0.3)
    L["teeth"] = inside_mouth * (slit < 0.55) * torch.sigmoid((MOUTH_W * 0.8 - ax) / 0.01)
    L["mouth"] = inside_mouth - L["teeth"]
    hairline = HAIRLINE_Y - 0.08 * ax
    side = torch.sigmoid((0.42 - Z) / 0.04)  # over the temples and ears
    hair_base = torch.sigmoid((Y - hairline) / 0.02).maximum(side * torch.sigmoid((Y - 0.02) / 0.03))
    hair_base = hair_base * (0.75 + 0.25 * hair_noise)
    L["hair_short"] = hair_base * out_slit
    L["hair_long"] = (
        torch.sigmoid((Y - hairline + 0.12) / 0.03).maximum(torch.sigmoid((-Z + 0.55) / 0.06))
        * (0.8 + 0.2 * hair_noise)
        * out_slit
    )
    jaw = front * torch.sigmoid((-0.28 - Y) / 0.03) * torch.sigmoid((0.8 - ax) / 0.05)
    not_lips = 1 - L["lips"]
    moustache = front * _ellipse(X, Y, 0, MOUTH_Y + 0.085, MOUTH_W * 1.3, 0.045, 0.3) * (1 - L["nostrils"])
    L["beard_full"] = ((jaw + moustache).clamp(max=1) * not_lips * out_slit) * (0.55 + 0.45 * stubble)
    goatee = front * _ellipse(X, Y, 0, CHIN_Y + 0.12, 0.17, 0.2, 0.3)
    L["beard_goatee"] = ((goatee + moustache).clamp(max=1) * not_lips * out_slit) * (0.55 + 0.45 * stubble)
    bridge = torch.exp(-0.5 * ((Y - EYE_Y - 0.02) / 0.012) ** 2) * (ax < EYE_X - EYE_W - 0.02)
    temple = torch.exp(-0.5 * ((Y - EYE_Y - 0.04) / 0.012) ** 2) * (ax > EYE_X + 0.13)
    L["glasses_round"] = (
        front * (1 - L["brows"]) * (_ring(ax, Y, EYE_X, EYE_Y, 0.15, 0.12, 0.1) + bridge + temple).clamp(max=1)
    )
    L["glasses_square"] = (
        front
        * (1 - L["brows"])
        * (_ring(ax, Y, EYE_X, EYE_Y - 0.01, 0.16, 0.1, 0.1, True) + bridge + temple).clamp(max=1)
    )
    forehead = sum(torch.exp(-0.5 * ((Y - y0 - 0.02 * torch.cos(4 * X)) / 0.006) ** 2) for y0 in (0.36, 0.41, 0.46)) * (
        ax < 0.35
    )
    crow = sum(torch.exp(-0.5 * ((Y - EYE_Y - k * (ax - EYE_X - 0.13)) / 0.006) ** 2) for k in (-0.5, 0.0, 0.5)) * (
        (ax - EYE_X - 0.14).abs() < 0.05
    )
    naso = (
        torch.exp(-0.5 * ((ax - (0.12 + 0.5 * (NOSE_BASE_Y - Y))) / 0.012) ** 2)
        * (Y < NOSE_BASE_Y + 0.02)
        * (Y > MOUTH_Y - 0.1)
    )
    L["wrinkles"] = front * out_slit * (forehead + crow + naso).clamp(max=1)
    L["eyebags"] = front * _ellipse(ax, Y, EYE_X, EYE_Y - 0.07, 0.09, 0.03, 0.4)
    head = (~is_neck(phi)).double()  # the neck is bare skin
    return (torch.stack([L[n] for n in LAYERS]) * head).reshape(len(LAYERS), -1).float()


@per_device
@lru_cache(maxsize=4)
@single_thread()
def noise_bank(res: int, n: int = 16, seed: int = 11) -> torch.Tensor:
    """Fixed fields ``[n, res, res]`` of fine skin texture (std about 1), shared by every scene."""
    g = torch.Generator().manual_seed(seed)
    fine = torch.randn(n, 1, res, res, generator=g)
    mid = F.interpolate(
        torch.randn(n, 1, res // 4, res // 4, generator=g), size=(res, res), mode="bilinear", align_corners=False
    )
    return (0.5 * fine + mid)[:, 0]


def _desaturate(c: torch.Tensor, amount: torch.Tensor) -> torch.Tensor:
    gray = c.mean(-1, keepdim=True)
    return c + amount[..., None] * (gray - c)


SKIN_LIGHT = torch.tensor([0.92, 0.76, 0.66])
SKIN_DARK = torch.tensor([0.36, 0.23, 0.15])
HAIR_COLOURS = torch.tensor(
    [
        [0.05, 0.04, 0.035],
        [0.18, 0.11, 0.06],
        [0.35, 0.22, 0.12],
        [0.62, 0.48, 0.28],
        [0.45, 0.18, 0.08],
        [0.10, 0.07, 0.05],
    ]
)
IRIS_COLOURS = torch.tensor([[0.25, 0.14, 0.07], [0.12, 0.07, 0.04], [0.25, 0.40, 0.55], [0.30, 0.38, 0.22]])
FRAME_COLOURS = torch.tensor([[0.03, 0.03, 0.03], [0.25, 0.12, 0.05], [0.55, 0.5, 0.45], [0.1, 0.1, 0.3]])


def paint_albedo(p: dict, res: int) -> torch.Tensor:
    """Albedo in UV space ``[N, 3, res, res]`` from a scene's appearance parameters.

    A base skin colour with a skin texture field, plus one coloured layer per feature
    (``LAYERS``), summed as one matrix product ``[N,3,L] @ [L,res^2]``.
    """
    layers = paint_layers(res)
    N = p["skin"].shape[0]
    senior = p["senior"]
    skin = _desaturate(p["skin"], 0.35 * senior)
    hair = p["hair"] + (0.6 * senior[:, None]) * (torch.tensor([0.62, 0.60, 0.58]) - p["hair"])  # greying
    coef = torch.zeros(N, len(LAYERS), 3)

    def put(name, colour, weight=1.0):
        coef[:, LAYERS.index(name)] = (colour - skin) * (weight if isinstance(weight, float) else weight[:, None])

    put("lips", p["lips"])
    put("blush", skin * torch.tensor([1.06, 0.86, 0.86]), p["blush"])
    put("brows", p["brow"], p["brow_density"])
    put("sclera", torch.tensor([0.80, 0.77, 0.74]).expand(N, 3))
    put("iris", p["iris"] - torch.tensor([0.80, 0.77, 0.74]) + skin)  # layered on the sclera
    put("pupil", torch.tensor([0.03, 0.03, 0.03]) - p["iris"] + skin)
    put("lashes", p["brow"] * 0.6, 0.7)
    put("nostrils", skin * 0.35)
    put("teeth", torch.tensor([0.82, 0.78, 0.68]).expand(N, 3))
    put("mouth", torch.tensor([0.22, 0.06, 0.06]).expand(N, 3))
    put("hair_short", hair, 1 - p["long_hair"])
    put("hair_long", hair, p["long_hair"])
    beard = p["beard"]
    put("beard_full", p["brow"] * 0.9, beard * (1 - p["goatee"]))
    put("beard_goatee", p["brow"] * 0.9, beard * p["goatee"])
    coef[:, LAYERS.index("wrinkles")] = -0.35 * senior[:, None] * skin
    coef[:, LAYERS.index("eyebags")] = -0.2 * senior[:, None] * skin
    # Eyeglass frames: albedo only, no geometry.
    put("glasses_round", p["frame"], p["eyeglasses"] * (1 - p["square"]))
    put("glasses_square", p["frame"], p["eyeglasses"] * p["square"])
    # Skin texture: one of the fixed noise fields, scaled by the skin colour.
    tex = noise_bank(res).reshape(-1, 1, res * res).index_select(0, p["noise_id"])  # [N, 1, res^2]
    albedo = torch.addcmul(skin[:, :, None], tex, 0.045 * skin[:, :, None])
    albedo.baddbmm_(coef.transpose(1, 2), layers.expand(N, -1, -1))
    return albedo.clamp_(0.02, 0.95).reshape(N, 3, res, res)


# ----------------------------------------------------------------------------- backgrounds
_BG_NAMES = (
    "brick",
    "chelsea",
    "clock",
    "coffee",
    "coins",
    "grass",
    "gravel",
    "hubble_deep_field",
    "immunohistochemistry",
    "moon",
    "page",
    "rocket",
    "text",
    "colorwheel",
    "retina",
    "cell",
)


@per_device
@lru_cache(maxsize=1)
@single_thread()
def background_atlas(tile: int = 192) -> torch.Tensor:
    """scikit-image's bundled pictures and textures (no faces), plus smooth noise, as a 5x4 atlas ``[1,3,H,W]``."""
    import numpy as np
    import skimage.data

    tiles = []
    for name in _BG_NAMES:
        try:
            im = getattr(skimage.data, name)()
        except Exception:  # a picture missing from this scikit-image build
            continue
        im = torch.from_numpy(np.asarray(im, dtype=np.float32) / (255.0 if im.dtype == np.uint8 else 1.0))
        im = (im[..., None].expand(-1, -1, 3) if im.dim() == 2 else im[..., :3]).permute(2, 0, 1)
        s = min(im.shape[1:])
        im = F.interpolate(im[None, :, :s, :s], size=(tile, tile), mode="bilinear", antialias=True, align_corners=False)
        tiles.append(im[0].clamp(0, 1))
    g = torch.Generator().manual_seed(3)
    while len(tiles) < 20:  # smooth colour noise
        tiles.append(
            F.interpolate(torch.rand(1, 3, 6, 6, generator=g), size=(tile, tile), mode="bicubic", align_corners=False)[
                0
            ].clamp(0, 1)
        )
    tiles = tiles[:20]
    rows = [torch.cat(tiles[r * 5 : (r + 1) * 5], 2) for r in range(4)]
    return torch.cat(rows, 1)[None]


BG_CROPS = 12  # fixed random crops of each atlas tile


@per_device
@lru_cache(maxsize=2)
@single_thread()
def background_bank(res: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Fixed crops ``[K, 3, res*res]`` of the atlas tiles (random position and scale 30-100%,
    flipped or not) and their channel means ``[K, 3]``; scenes pick one and recolour it."""
    atlas = background_atlas()
    tile = atlas.shape[-1] // 5
    g = torch.Generator().manual_seed(5)
    u = torch.rand(20 * BG_CROPS, 4, generator=g)
    k = torch.arange(20).repeat_interleave(BG_CROPS)
    frac = 0.3 + 0.7 * u[:, 0]
    x0 = (k % 5).float() * tile + u[:, 1] * (1 - frac) * tile
    y0 = (k // 5).float() * tile + u[:, 2] * (1 - frac) * tile
    flip = torch.where(u[:, 3] < 0.5, -1.0, 1.0)
    t = (torch.arange(res, dtype=torch.float32) + 0.5) / res
    gx = x0[:, None] + frac[:, None] * tile * (0.5 + flip[:, None] * (t - 0.5))
    gy = y0[:, None] + frac[:, None] * tile * t
    K, (Ha, Wa) = k.numel(), atlas.shape[-2:]
    grid = torch.stack(
        [
            (gx[:, None, :].expand(K, res, res) + 0.5) / Wa * 2 - 1,
            (gy[:, :, None].expand(K, res, res) + 0.5) / Ha * 2 - 1,
        ],
        -1,
    )
    crops = F.grid_sample(atlas.expand(K, -1, -1, -1), grid, mode="bilinear", align_corners=False)
    crops = crops.reshape(K, 3, res * res).contiguous()
    return crops, crops.mean(2)


def paint_background(u: torch.Tensor, res: int) -> torch.Tensor:
    """Backgrounds ``[N, 3, res, res]`` from 16 uniforms per scene: a crop of a picture or
    texture, recoloured (contrast, per-channel gain, desaturation), a two-colour
    gradient, or a blend of both.  The recolouring is an affine colour map and the
    gradient is bilinear, so the whole background is two batched products."""
    crops, means = background_bank(res)
    N = u.shape[0]
    k = (u[:, 0] * crops.shape[0]).long().clamp(max=crops.shape[0] - 1)
    contrast = 0.5 + 0.8 * u[:, 5]
    gain = 0.6 + 0.6 * u[:, 6:9]
    d = 0.7 * u[:, 9]
    D = (1 - d)[:, None, None] * torch.eye(3) + (d / 3)[:, None, None]  # desaturation
    M = D * gain[:, None, :]  # D @ diag(gain)
    offset = (M @ ((1 - contrast)[:, None] * means[k])[..., None])[..., 0]  # contrast about the crop mean
    M = contrast[:, None, None] * M
    # Gradient between two colours along a random direction: its 4 corners, bilinear between.
    ang = 2 * math.pi * u[:, 10]
    cx = torch.tensor([-0.5, 0.5, -0.5, 0.5])  # corners (top-left, top-right, bottom-left, bottom-right)
    cy = torch.tensor([0.5, 0.5, -0.5, -0.5])
    s = (cx * torch.cos(ang)[:, None] + cy * torch.sin(ang)[:, None] + 0.5).clamp(0, 1)  # [N, 4]
    c0 = u[:, 11:14]
    c1 = c0 * (0.3 + 0.7 * u[:, 14:15])
    corners = c0[:, :, None] + s[:, None, :] * (c1 - c0)[:, :, None]  # [N, 3, 4]
    kind = u[:, 15]  # 55% picture, 25% gradient, 20% blend
    w = torch.where(kind < 0.55, 1.0, torch.where(kind < 0.8, 0.0, 0.5))
    corners = w[:, None, None] * offset[:, :, None] + (1 - w)[:, None, None] * corners
    bg = torch.bmm(w[:, None, None] * M, crops.index_select(0, k))
    bg.baddbmm_(corners, _bilinear_weights(res).expand(N, -1, -1))  # + the bilinear ramp between the corners
    return bg.clamp_(0, 1).reshape(N, 3, res, res)


@per_device
@lru_cache(maxsize=4)
def _bilinear_weights(res: int) -> torch.Tensor:
    """``[4, res*res]``: bilinear interpolation (align-corners) from the corners top-left,
    top-right, bottom-left, bottom-right of a ``res x res`` image."""
    t = torch.linspace(0, 1, res)
    y, x = t[:, None].expand(res, res).reshape(-1), t[None].expand(res, res).reshape(-1)
    return torch.stack([(1 - y) * (1 - x), (1 - y) * x, y * (1 - x), y * x])


# ----------------------------------------------------------------------------- scene parameters
def scene_params(item_key: torch.Tensor, identity: torch.Tensor, seed: int, labels: dict | None = None) -> dict:
    """All generator parameters of a batch of scenes (see :func:`render_scenes`).

    ``item_key [N]`` keys per-image draws, ``identity [N]`` the identity-level ones;
    ``labels`` may force attribute labels (attribute pools).
    """
    N = item_key.shape[0]
    pid = identity
    p = {"identity": identity}
    p["alpha"] = normal(pid, "shape", face_model().identity.shape[0], seed)
    u = uniform(pid, "skin", 16, seed)
    tone = u[:, 0] ** 1.3
    skin = SKIN_LIGHT + tone[:, None] * (SKIN_DARK - SKIN_LIGHT)
    skin = skin * (1 + 0.08 * (u[:, 1:4] - 0.5))
    p["skin"] = skin
    p["lips"] = skin * torch.tensor([0.85, 0.55, 0.55]) * (0.85 + 0.3 * u[:, 4:5])
    p["blush"] = 0.5 * u[:, 5]
    hair_k = (u[:, 6] * len(HAIR_COLOURS)).long().clamp(max=len(HAIR_COLOURS) - 1)
    hair = HAIR_COLOURS[hair_k] * (0.8 + 0.4 * u[:, 7:8])
    p["hair"] = hair
    p["brow"] = hair * 0.8
    p["brow_density"] = 0.6 + 0.4 * u[:, 8]
    p["iris"] = IRIS_COLOURS[(u[:, 9] * len(IRIS_COLOURS)).long().clamp(max=len(IRIS_COLOURS) - 1)]
    p["long_hair"] = (u[:, 10] < 0.4).float()
    p["goatee"] = (u[:, 11] < 0.3).float()
    p["square"] = (u[:, 12] < 0.5).float()
    p["frame"] = FRAME_COLOURS[(u[:, 13] * len(FRAME_COLOURS)).long().clamp(max=len(FRAME_COLOURS) - 1)]
    p["noise_id"] = (u[:, 14] * 16).long().clamp(max=15)
    # Attributes: beard, eyeglasses, senior belong to the identity, smiling to the image.
    # Label = (strength >= 0.5, attribute_labels): positives have strengths in [0.5, 1], negatives 0
    # (beard, eyeglasses) or a little below the threshold (senior: age; smiling: a faint smile).
    u_id, u_img = uniform(pid, "attrs", 6, seed), uniform(item_key, "attrs", 2, seed)
    draws = {
        "beard": (u_id[:, 0], u_id[:, 3]),
        "eyeglasses": (u_id[:, 1], u_id[:, 4]),
        "senior": (u_id[:, 2], u_id[:, 5]),
        "smiling": (u_img[:, 0], u_img[:, 1]),
    }
    for name, (u_on, u_s) in draws.items():
        on = labels[name] if labels is not None and name in labels else u_on < ATTR_PRIOR[name]
        below = torch.zeros_like(u_s) if name in ("beard", "eyeglasses") else 0.3 * u_s
        p[name] = torch.where(on.bool(), 0.5 + 0.5 * u_s, below)
    ue = uniform(item_key, "expr", 2, seed)
    smile = p["smiling"]  # a real smile opens the mouth and shows teeth; otherwise lips part a little
    opening = torch.where(smile >= 0.5, (0.4 + 0.6 * ue[:, 0]) * smile, 0.1 * ue[:, 1] ** 2)
    p["expression"] = torch.stack([smile, opening], 1)
    up = uniform(item_key, "pose", 8, seed)
    tri = lambda a, b: a + b - 1  # triangular on [-1, 1]
    p["pose"] = torch.stack(
        [
            POSE_RANGE[0] * tri(up[:, 0], up[:, 1]),
            POSE_RANGE[1] * tri(up[:, 2], up[:, 3]),
            POSE_RANGE[2] * tri(up[:, 4], up[:, 5]),
        ],
        1,
    )
    p["scale"] = SCALE_RANGE[0] + (SCALE_RANGE[1] - SCALE_RANGE[0]) * up[:, 6]
    p["shift"] = SHIFT_RANGE * (2 * uniform(item_key, "pose", 10, seed)[:, 8:10] - 1) + torch.tensor([0.0, -0.02])
    light = sample_lights(uniform(item_key, "light", 12, seed))
    p.update(sh=light["sh"], light_direction=light["direction"], light_intensity=light["intensity"])
    p["light_id"] = torch.full((N,), -1, dtype=torch.long)
    p["bg"] = uniform(item_key, "bg", 16, seed)
    # The coarse fit behind the pseudo ground truth, and the effects' own draws.
    zp = normal(item_key, "pseudo", 12, seed)
    p["pseudo_alpha"] = p["alpha"][:, :PSEUDO_COMPONENTS] * (1 + 0.25 * zp[:, :PSEUDO_COMPONENTS])
    p["pseudo_expression"] = (p["expression"] + 0.12 * zp[:, 4:6]).clamp(0, 1)
    p["pseudo_pose"] = p["pose"] + torch.tensor(PSEUDO_POSE_STD) * zp[:, 6:9]
    p["pseudo_scale"] = p["scale"] * (1 + 0.025 * zp[:, 9])
    p["pseudo_shift"] = p["shift"] + 0.02 * zp[:, 10:12]
    p["effects_u"] = uniform(item_key, "effects", 12, seed)
    p["effect_noise_id"] = (uniform(item_key, "effects", 13, seed)[:, 12] * 16).long().clamp(max=15)
    return p


def attribute_labels(p: dict) -> dict[str, torch.Tensor]:
    """Each attribute's binary label of the scenes ``p`` (:func:`scene_params`): its strength at least 0.5."""
    return {a: p[a] >= 0.5 for a in ATTRIBUTES}


# ----------------------------------------------------------------------------- rendering
@per_device
@lru_cache(maxsize=1)
def pseudo_mesh() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, tuple[int, int]]:
    """The coarse fit's mesh: every ``PSEUDO_GRID_STEP``-th row and column of the grid, keeping
    both inner-lip rows.  Returns (vertex indices, faces, uv, grid shape)."""
    lay = layout()
    rows = set(range(0, GRID_V, PSEUDO_GRID_STEP)) | {GRID_V - 1}
    rows -= set(range(lay.slit_row - 1, lay.slit_row + SLIT_ROWS + 1))
    rows |= {lay.slit_row, lay.slit_row + SLIT_ROWS - 1}
    rows = sorted(rows)
    cols = sorted(set(range(0, GRID_U, PSEUDO_GRID_STEP)) | {GRID_U - 1})
    idx = (torch.tensor(rows)[:, None] * GRID_U + torch.tensor(cols)[None]).flatten()
    gv, gu = len(rows), len(cols)
    return idx, grid_faces(gv, gu), face_model().uv[idx], (gv, gu)


@per_device
@lru_cache(maxsize=1)
def pseudo_quads() -> torch.Tensor:
    """The quads of :func:`pseudo_mesh` that touch the face region: the only ones whose pixels
    can enter ``mask_pseudo``, so the only ones drawn (a 3DMM has no hair, ears or neck)."""
    idx, _, _, (gv, gu) = pseudo_mesh()
    r = face_model().face_region[idx].view(gv, gu) > 0
    return (r[:-1, :-1] | r[:-1, 1:] | r[1:, :-1] | r[1:, 1:]).flatten()


def _uv_map_from_subgrid(vals: torch.Tensor, res: int) -> torch.Tensor:
    """Lay values on the pseudo mesh's (non-uniform) sub-grid out over UV space."""
    _, _, uv, (gv, gu) = pseudo_mesh()
    uv = uv.reshape(gv, gu, 2)
    return grid_to_uv_map(vals, res, (gv, gu), knots=(uv[:, 0, 1], uv[0, :, 0]))


def render_scenes(p: dict, res: int, effects: dict | None = None, pseudo: bool = True) -> dict:
    """Render a batch of scenes ``p`` (from :func:`scene_params`) at ``res`` x ``res``.

    The true face and the coarse fit behind the pseudo ground truth are rasterized together."""
    fm = face_model()
    cam = to_camera(
        fm.shape_planes(p["alpha"], p["expression"], p["senior"]).transpose(1, 2), p["pose"], p["scale"], p["shift"]
    )
    vn = grid_vertex_normals(cam, (GRID_V, GRID_U))
    meshes = [(cam, (GRID_V, GRID_U))]
    if pseudo:
        fit = _pseudo_geometry(p)
        meshes.append((fit["cam"], fit["grid"], pseudo_quads()))
    rasters = rasterize_grids(meshes, res)
    r = rasters[0]
    matte = paste(torch.ones(1, r["batch"].numel()), r)
    at = interpolate_covered([vn, fm.uv, fm.face_region[:, None]], r)  # normal, uv, face region at the covered pixels
    albedo_uv = paint_albedo(p, res)
    normal, uv = paste(unit_planes(at[None, :3], inplace=True)[0], r), paste(at[3:5], r)
    albedo_at = sample_texture(albedo_uv, at[3:5], r["batch"])
    albedo = paste(albedo_at, r)
    sh = p["sh"]
    shading = shade(normal, sh, matte)
    background = paint_background(p["bg"], res)
    # Eq. 2 on the face, composited over the background (Eq. 6; the matte is binary).
    image = paste(image_formation(albedo_at, pick(shading, r)), r, background)
    out = {
        "image": image,
        "background": background,
        "matte": matte,
        # the skin a 3DMM covers (not hair, ears, neck) on the true mesh: what M-hat estimates and the paper's matte
        # is trained towards (Sec. 3.3), so the matte is scored against it
        "mask_face": paste(torch.gt(at[5:6], 0.5).to(at.dtype), r),
        "normal": normal,
        "albedo": albedo,
        "shading": shading,
        "sh": sh,
        "uv": uv,
        "normal_uv": grid_to_uv_map(vn, res, (GRID_V, GRID_U)),
        "albedo_uv": albedo_uv,
    }
    if effects:
        out["image"] = apply_effects(out, p, effects)
    if pseudo:
        out.update(_pseudo_maps(out["image"], fit, rasters[1], res))
    return out


def shade(normal: torch.Tensor, sh: torch.Tensor, matte: torch.Tensor) -> torch.Tensor:
    """``sh_shading(normal, sh) * matte`` (Eq. 4) in the form of Eq. 5 for a binary ``matte`` and normals
    that are 0 off it: one batched product of :func:`eq5_coefficients` with :func:`eq5_planes`."""
    B, _, H, W = normal.shape
    planes = eq5_planes(normal.reshape(B, 3, H * W), matte.reshape(B, H * W))
    return torch.bmm(eq5_coefficients(sh.to(normal.dtype)), planes).view(B, -1, H, W)


def render_pseudo(image: torch.Tensor, p: dict, res: int) -> dict:
    """Pseudo ground truth from the coarse fit (first few identity components, perturbed pose
    and expression, no senior shape, a mesh at half the grid density, the face region only);
    ``sh_pseudo`` is the paper's L-hat: fit_sh(image, normal_pseudo, mask_pseudo), constant albedo."""
    fit = _pseudo_geometry(p)
    return _pseudo_maps(image, fit, rasterize_grids([(fit["cam"], fit["grid"], pseudo_quads())], res)[0], res)


def _pseudo_geometry(p: dict) -> dict:
    """The coarse fit's mesh in the camera frame and its vertex normals."""
    idx, _, _, grid = pseudo_mesh()
    planes = face_model().shape_planes(p["pseudo_alpha"], p["pseudo_expression"], vertices=idx)
    cam = to_camera(planes.transpose(1, 2), p["pseudo_pose"], p["pseudo_scale"], p["pseudo_shift"])
    return {"cam": cam, "grid": grid, "vn": grid_vertex_normals(cam, grid)}


def _pseudo_maps(image: torch.Tensor, fit: dict, r: dict, res: int) -> dict:
    idx, _, uv, _ = pseudo_mesh()
    at = interpolate_covered([fit["vn"], face_model().face_region[idx, None], uv], r)  # at the covered pixels
    inside = torch.gt(at[3:4], 0.5, out=torch.empty_like(at[3:4]))  # the face region, where a 3DMM fits
    normal = paste(unit_planes(at[None, :3], inplace=True)[0].mul_(inside), r)
    mask = paste(inside, r)
    return {
        "normal_pseudo": normal,
        "mask_pseudo": mask,
        "uv_pseudo": paste(at[4:6].mul_(inside), r),
        "normal_uv_pseudo": _uv_map_from_subgrid(fit["vn"], res),
        "sh_pseudo": fit_sh_packed(image, normal, mask),
    }


def dominant_light(sh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The directional part of an SH light ``[N, C, 9]``: unit direction ``[N, 3]`` (camera frame) of
    its order-1 band averaged over channels, and the intensity ``[N, C]`` of each channel along it.
    For one distant light (:func:`disent.render.sh_from_directions`) these are its direction and
    intensity; ambient light alone has none (zero direction and intensity)."""
    lin = sh[..., [3, 1, 2]]  # (L4, L2, L3): the x, y, z terms
    d = F.normalize(lin.mean(1), dim=1)
    return d, 4 * C2 * (lin * d[:, None]).sum(-1).clamp_min(0)  # a unit light's linear band has length 1 / (4 C2)


def apply_effects(out: dict, p: dict, effects: dict) -> torch.Tensor:
    """Effects that break the paper's image model, each with a severity in [0, 1]:

    * ``specular``: a Blinn-Phong highlight of the light's dominant direction (:func:`dominant_light`
      of the scene's ``sh``, so it follows a light given to ``SynthFaces.sample``) added to the face;
    * ``cast_shadow``: a soft-edged shadow cast across the face by an object outside the
      frame (the shading is attenuated on one side of a random line);
    * ``noise``: sensor noise, Gaussian with std ``0.1 * severity``;
    * ``occluder``: an opaque ellipse of a random colour over part of the face.
    """
    unknown = set(effects) - set(EFFECTS)
    if unknown:
        raise ValueError(f"unknown effects {sorted(unknown)}; choose from {EFFECTS}")
    for k, v in effects.items():
        if not 0 <= float(v) <= 1:
            raise ValueError(f"effect severity must be in [0, 1], got {k}={v}")
    u = p["effects_u"]
    matte, normal, albedo, shading, bg = out["matte"], out["normal"], out["albedo"], out["shading"], out["background"]
    N, _, H, W = matte.shape
    fg = image_formation(albedo, shading)
    ys = torch.linspace(1, -1, H)[:, None].expand(H, W)
    xs = torch.linspace(-1, 1, W)[None].expand(H, W)
    if effects.get("cast_shadow", 0) > 0:
        a = 2 * math.pi * u[:, 0]
        d = xs * torch.cos(a)[:, None, None] + ys * torch.sin(a)[:, None, None] - (0.4 * u[:, 1] - 0.2)[:, None, None]
        shadow = torch.sigmoid(d / 0.04)[:, None]
        fg = fg * (1 - 0.85 * float(effects["cast_shadow"]) * shadow)
    if effects.get("specular", 0) > 0:
        d, key = dominant_light(out["sh"])
        h = F.normalize(d + torch.tensor([0.0, 0.0, 1.0]), dim=1)
        ndh = (normal * h[:, :, None, None]).sum(1, keepdim=True).clamp_min(0)
        fg = fg + float(effects["specular"]) * 0.6 * ndh**24 * key[:, :, None, None] * matte
    image = composite(matte, fg.clamp(0, 1), bg)
    if effects.get("occluder", 0) > 0:
        s = float(effects["occluder"])
        cx, cy = p["shift"][:, 0] + 0.5 * (u[:, 2] - 0.5), p["shift"][:, 1] + 0.5 * (u[:, 3] - 0.5)
        rx, ry = (0.15 + 0.35 * s) * (0.6 + 0.8 * u[:, 4]), (0.15 + 0.35 * s) * (0.6 + 0.8 * u[:, 5])
        occ = _ellipse(xs, ys, cx[:, None, None], cy[:, None, None], rx[:, None, None], ry[:, None, None], 0.05)[
            :, None
        ]
        colour = u[:, 6:9, None, None]
        image = image + occ * (colour - image)
    if effects.get("noise", 0) > 0:
        bank = noise_bank(H)[p["effect_noise_id"]]
        z = torch.stack([bank, bank.flip(1), bank.flip(2)], 1) / bank.std()
        image = (image + 0.1 * float(effects["noise"]) * z).clamp(0, 1)
    return image


__all__ = [
    "ATTRIBUTES",
    "attribute_labels",
    "EFFECTS",
    "LIGHT_BANK",
    "LIGHT_NAMES",
    "lights_to_sh",
    "sample_lights",
    "scene_params",
    "render_scenes",
    "render_pseudo",
    "dominant_light",
    "apply_effects",
    "paint_albedo",
    "paint_background",
    "uniform",
    "normal",
]

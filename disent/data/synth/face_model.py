"""A small linear morphable face model, written here: mean head + identity + expression.

The mesh is a regular grid in UV space, so the UV parametrization is fixed and the texture
of every face lives on the same ``[0,1]^2`` map:  u runs across the head (the subject's
right ear at u=0, the left at u=1), v runs down (top of the head at v=0, the base of the
neck at v=1).  Column ``u`` is the azimuth theta, row ``v`` the elevation phi on a deformed
ellipsoid; both are warped so that the grid is densest on the face.  Four rows at the
mouth line are collapsed onto one curve in the mean shape (the closed mouth); the
``open`` expression pulls them apart into a cavity, so the mouth can open without
changing the topology.

Model frame: x to the subject's left (image right in a frontal view), y up, z out of the
face, head centre at the origin, head half-width about 0.8.

Shape (the usual linear 3DMM form)::

    vertices = mean + sum_k alpha_k * identity[k] + sum_j beta_j * expression[j] + s * senior

with ``alpha_k ~ N(0, 1)`` (components carry their own scale, ordered by variance),
``beta = (smile, open)`` in [0, 1] and ``s`` the senior strength.

Size: ``GRID_U x GRID_V = 41 x 53 = 2,173`` vertices (48 rows of head, 5 of neck),
4,160 triangles (3,920 non-degenerate while the mouth is closed), ``N_IDENTITY = 40``
identity and 2 expression components plus the senior shape.  At 64x64 a loosely
cropped head spans about 45 pixels and the front of the face (about 30 columns by 35
rows of the grid) puts roughly one vertex per pixel there, so facets stay below the
pixel footprint and normals interpolated across triangles are smooth; at 128x128 a
triangle covers about 2 pixels, still below the scale of any feature the albedo paints
(eyes, lips, brows live in the UV texture, not in the geometry).  Forty identity
components (17 semantic, 23 smooth random fields) give more shape variation than a
64-pixel face can show; the coarse fit behind the pseudo ground truth uses only the
first few.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import torch

from disent.data.synth.raster import grid_faces
from disent.runtime import per_device, single_thread

GRID_U, GRID_V = 41, 53
NECK_ROWS = 5  # the last rows of the grid: a short neck below the head
NECK_SPAN = math.radians(30.0)  # elevation parameter the neck rows continue over
THETA_MAX = math.radians(100.0)  # azimuth range of the mesh, +-
PHI_TOP, PHI_BOTTOM = math.radians(82.0), math.radians(-64.0)
N_IDENTITY = 40
EXPRESSIONS = ("smile", "open")
SLIT_ROWS = 4  # rows collapsed at the mouth line: upper inner lip, 2 interior, lower inner lip

# Facial anchors in front coordinates X = sin(theta) cos(phi), Y = sin(phi) of the unit
# sphere; geometry, the painted albedo and the landmarks all read them from here.
EYE_X, EYE_Y, EYE_W, EYE_H = 0.38, 0.10, 0.115, 0.036
BROW_X, BROW_Y = EYE_X, 0.25  # brow arch peak
NOSE_TIP_Y, NOSE_BASE_Y = -0.20, -0.27
MOUTH_Y, MOUTH_W = -0.47, 0.17
CHIN_Y = -0.80
HAIRLINE_Y = 0.47


def _warp(s: torch.Tensor, a: float) -> torch.Tensor:
    """Odd monotone warp of [-1,1]: slope a at 0, denser sampling near the middle."""
    return a * s + (1 - a) * s**3


def _unwarp(w: float, a: float) -> float:
    lo, hi = -1.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if a * mid + (1 - a) * mid**3 < w else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Layout:
    """Where the grid lies on the head: per-vertex angles and UV."""

    theta: torch.Tensor  # [V]
    phi: torch.Tensor  # [V]
    uv: torch.Tensor  # [V, 2]
    slit_frac: torch.Tensor  # [V]: 0 on the upper inner lip row ... 1 on the lower one; -1 elsewhere
    slit_row: int  # index of the upper inner-lip row


def _phi_of_t(t: torch.Tensor) -> torch.Tensor:
    mid, half = 0.5 * (PHI_TOP + PHI_BOTTOM), 0.5 * (PHI_TOP - PHI_BOTTOM)
    return mid + half * _warp(t, 0.6)


def uv_to_angles(uv: torch.Tensor, slit_row: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(theta, phi, slit_frac) of UV points ``[..., 2]`` (also used to paint textures).

    Neck rows continue ``phi`` below ``PHI_BOTTOM`` (a parameter there, see :func:`_surface`).
    """
    u, v = uv.unbind(-1)
    theta = THETA_MAX * _warp(2 * u - 1, 0.55)
    h = 1.0 / (GRID_V - 1)
    v_head = (GRID_V - NECK_ROWS - 1) * h
    v0, v1 = slit_row * h, (slit_row + SLIT_ROWS - 1) * h
    span = v_head - (v1 - v0)  # rows outside the slit cover the elevation range of the head
    v_eff = torch.where(v < v0, v, torch.where(v > v1, v - (v1 - v0), torch.full_like(v, v0)))
    phi = _phi_of_t(1 - 2 * v_eff / span)
    phi = torch.where(v > v_head, PHI_BOTTOM - NECK_SPAN * (v - v_head) / (1 - v_head), phi)
    slit = torch.where((v >= v0) & (v <= v1), (v - v0) / (v1 - v0), torch.full_like(v, -1.0))
    return theta, phi, slit


# Parts of the face around the anchors, as boxes in front coordinates (|X|, Y): the eyes with the brows above them,
# the nose from between the eyes to below its base, the mouth with the lips (face_regions)
FACE_REGIONS = {
    "eyes and brows": ((EYE_X - EYE_W - 0.1, EYE_X + EYE_W + 0.1), (EYE_Y - 0.08, BROW_Y + 0.08)),
    "nose": ((0.0, 0.14), (NOSE_BASE_Y - 0.06, EYE_Y)),
    "mouth": ((0.0, MOUTH_W + 0.1), (MOUTH_Y - 0.12, MOUTH_Y + 0.11)),
}


def face_regions(uv: torch.Tensor) -> dict[str, torch.Tensor]:
    """``{name: bool [...]}``: which of the UV points ``[..., 2]`` (a SynthFaces ``uv`` map, channels last) fall in
    each part of the face of :data:`FACE_REGIONS`."""
    theta, phi, _ = uv_to_angles(uv.double(), layout().slit_row)
    ax, y = (torch.sin(theta) * torch.cos(phi)).abs(), torch.sin(phi)
    return {
        name: (ax >= x0) & (ax <= x1) & (y >= y0) & (y <= y1) & (torch.cos(theta) > 0)
        for name, ((x0, x1), (y0, y1)) in FACE_REGIONS.items()
    }


@per_device
@lru_cache(maxsize=1)
def layout() -> Layout:
    # Put the slit where the elevation of the mouth line falls.
    h = 1.0 / (GRID_V - 1)
    span = (GRID_V - NECK_ROWS - 1) * h - (SLIT_ROWS - 1) * h
    half = 0.5 * (PHI_TOP - PHI_BOTTOM)
    t_m = _unwarp((math.asin(MOUTH_Y) - 0.5 * (PHI_TOP + PHI_BOTTOM)) / half, 0.6)
    slit_row = round((1 - t_m) / 2 * span / h)
    v = torch.arange(GRID_V, dtype=torch.float64) * h
    u = torch.linspace(0, 1, GRID_U, dtype=torch.float64)
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).reshape(-1, 2)  # row-major: v rows, u cols
    theta, phi, slit = uv_to_angles(uv, slit_row)
    return Layout(theta, phi, uv, slit, slit_row)


def is_neck(phi: torch.Tensor) -> torch.Tensor:
    return phi < PHI_BOTTOM - 1e-9


@per_device
@lru_cache(maxsize=1)
def faces() -> torch.Tensor:
    """Triangles ``[T, 3]`` (int64), counter-clockwise seen from outside (x right, y up)."""
    return grid_faces(GRID_V, GRID_U)


def _g(x: torch.Tensor, s: float) -> torch.Tensor:
    return torch.exp(-0.5 * (x / s) ** 2)


def _smoothstep(e0: float, e1: float, x: torch.Tensor) -> torch.Tensor:
    t = ((x - e0) / (e1 - e0)).clamp(0, 1)
    return t * t * (3 - 2 * t)


# Mean-shape parameters; each identity component is the linearised effect of one of them.
SHAPE_PARAMS = {  # name: (mean, std)
    "width": (0.78, 0.035),
    "height": (1.02, 0.035),
    "depth": (0.90, 0.04),
    "jaw": (0.20, 0.06),
    "nose_height": (0.20, 0.04),
    "nose_width": (1.0, 0.15),
    "nose_length": (0.0, 0.03),
    "muzzle": (0.06, 0.02),
    "chin": (0.05, 0.025),
    "cheekbone": (0.04, 0.02),
    "eye_socket": (0.07, 0.02),
    "brow_ridge": (0.035, 0.015),
    "lips": (0.035, 0.012),
    "bridge": (0.03, 0.015),
    "chin_length": (0.0, 0.03),
    "forehead": (0.0, 0.03),
    "eye_sep": (0.0, 0.02),
}


def _front(theta, phi):
    return torch.sin(theta) * torch.cos(phi), torch.sin(phi), torch.cos(theta) * torch.cos(phi)


def _surface(theta, phi, slit, p: dict) -> torch.Tensor:
    """Mean-type head surface for shape parameters ``p`` -> ``[V, 3]``."""
    X, Y, Z = _front(theta, phi)
    front = _smoothstep(0.05, 0.45, Z)
    ax = X.abs()
    ex = EYE_X + p["eye_sep"]
    nose_w = p["nose_width"] * (0.045 + 0.05 * _smoothstep(0.2, NOSE_TIP_Y, Y))
    nose_prof = p["bridge"] + (p["nose_height"] - p["bridge"]) * _smoothstep(0.18, NOSE_TIP_Y + p["nose_length"], Y)
    nose_prof = nose_prof * _smoothstep(NOSE_BASE_Y - 0.05 + p["nose_length"], NOSE_TIP_Y - 0.01 + p["nose_length"], Y)
    nose_prof = nose_prof * _smoothstep(0.3, 0.18, Y)
    h = _g(X, 1.0) * nose_prof * torch.exp(-0.5 * (X / nose_w) ** 2)
    h = h + 0.05 * _g(ax - 0.085 * p["nose_width"], 0.04) * _g(Y - NOSE_BASE_Y - 0.03, 0.035)  # alae
    socket = _g(ax - ex, 0.12) * _g(Y - EYE_Y, 0.075)
    h = h - p["eye_socket"] * socket + 0.5 * p["eye_socket"] * _g(ax - ex, 0.06) * _g(Y - EYE_Y, 0.035)
    h = h + p["brow_ridge"] * _g(Y - BROW_Y - 0.02, 0.06) * _smoothstep(0.55, 0.3, ax)
    h = h + p["cheekbone"] * _g(ax - 0.45, 0.12) * _g(Y + 0.07, 0.1)
    h = h + p["muzzle"] * _g(X, 0.26) * _g(Y - MOUTH_Y, 0.17)
    h = h + p["lips"] * _g(X, 0.14) * (_g(Y - MOUTH_Y - 0.035, 0.03) + 1.1 * _g(Y - MOUTH_Y + 0.045, 0.035))
    h = h - 0.018 * _g(X, 0.12) * _g(Y - MOUTH_Y + 0.13, 0.03)  # mentolabial groove
    h = h + p["chin"] * _g(X, 0.16) * _g(Y - CHIN_Y - 0.06 + p["chin_length"], 0.08)
    h = h - 0.02 * _g(ax - 0.62, 0.08) * _g(Y - 0.28, 0.1)  # temples
    h = h + p["forehead"] * _smoothstep(0.2, 0.7, Y)
    h = h * front
    hair = _smoothstep(HAIRLINE_Y - 0.1, HAIRLINE_Y + 0.1, Y + 0.35 * _smoothstep(0.5, 0.0, Z)) * _smoothstep(
        -0.3, 0.0, Y
    )
    h = h + 0.05 * hair
    # Ellipsoid, narrowed towards the jaw and flattened at the front of the face.
    taper = 1 - p["jaw"] * _smoothstep(-0.2, -0.95, Y) * front
    x = p["width"] * X * taper
    y = p["height"] * Y + p["chin_length"] * _smoothstep(-0.5, -0.9, Y)
    z = p["depth"] * Z + 0.06 * front
    head = torch.stack([x, y, z], -1) * (1 + h)[..., None]
    # The neck: a cylinder under the jaw, the same for every face.
    k = ((PHI_BOTTOM - phi) / NECK_SPAN).clamp(0, 1)
    neck = torch.stack([0.42 * torch.sin(theta), -0.86 - 0.8 * k, -0.1 + 0.42 * torch.cos(theta)], -1)
    return torch.where(is_neck(phi)[..., None], neck, head)


def _smooth_fields(theta, phi, n: int, seed: int = 1234) -> torch.Tensor:
    """``n`` smooth random radial fields on the face (fine identity detail), ``[n, V]``."""
    g = torch.Generator().manual_seed(seed)
    X, Y, Z = _front(theta, phi)
    front = _smoothstep(0.1, 0.5, Z)
    out = []
    for k in range(n):
        f = 2.0 + 6.0 * k / n  # rising frequency, falling amplitude
        w = torch.randn(2, generator=g, dtype=torch.float64)
        ph = torch.rand(1, generator=g, dtype=torch.float64) * 2 * math.pi
        field = torch.cos(f * (w[0] * X + w[1] * Y) + ph) * front
        out.append(0.012 * field * (1.0 / (1 + 0.15 * k)))
    return torch.stack(out)


@dataclass(frozen=True)
class FaceModel:
    mean: torch.Tensor  # [V, 3]
    identity: torch.Tensor  # [K, V, 3]: one std of each component
    expression: torch.Tensor  # [2, V, 3]: smile, open at full strength
    senior: torch.Tensor  # [V, 3]: the ageing shape change at full strength
    faces: torch.Tensor  # [T, 3]
    uv: torch.Tensor  # [V, 2]
    landmarks: torch.Tensor  # [68] vertex indices (iBUG / dlib order)
    face_region: torch.Tensor  # [V] 1 on the skin of the face a 3DMM would cover (not hair, ears, neck)
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def n_vertices(self) -> int:
        return self.mean.shape[0]

    def shape(self, alpha: torch.Tensor, beta: torch.Tensor, senior: torch.Tensor | None = None) -> torch.Tensor:
        """Vertices ``[B, V, 3]`` from identity ``alpha [B, K']`` (K' <= K) and expression ``beta [B, 2]``."""
        return self.shape_planes(alpha, beta, senior).transpose(1, 2).contiguous()

    def shape_planes(
        self,
        alpha: torch.Tensor,
        beta: torch.Tensor,
        senior: torch.Tensor | None = None,
        vertices: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """:meth:`shape` as coordinate planes ``[B, 3, V]`` (x, y, z rows: the layout the renderer
        reads), optionally of the ``vertices`` subset only."""
        K = alpha.shape[1]
        if K > self.identity.shape[0] or beta.shape[1] != len(EXPRESSIONS):
            raise ValueError(
                f"alpha [B,<= {self.identity.shape[0]}], beta [B,2]; got {tuple(alpha.shape)}, {tuple(beta.shape)}"
            )
        mean, basis = self._planar_basis(K, senior is not None, vertices)
        coef = torch.cat([alpha, beta] + ([senior[:, None]] if senior is not None else []), 1).double()
        # In float64, one row at a time in effect: a face's vertices do not depend on which
        # other faces share its batch (float32 GEMM rounding would change with the batch size).
        return torch.addmm(mean, coef, basis).float().view(alpha.shape[0], 3, -1)

    def _planar_basis(self, K: int, senior: bool, vertices: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """The mean ``[3V']`` and components ``[K+2(+1), 3V']`` in float64, planar order, cached."""
        key = (K, senior, None if vertices is None else tuple(vertices.tolist()))
        if key not in self._cache:
            comps = [self.identity[:K], self.expression] + ([self.senior[None]] if senior else [])
            basis, mean = torch.cat(comps), self.mean
            if vertices is not None:
                basis, mean = basis[:, vertices], mean[vertices]
            self._cache[key] = (
                mean.t().reshape(-1).double(),
                basis.transpose(1, 2).reshape(basis.shape[0], -1).double(),
            )
        return self._cache[key]


def _expressions(lay: Layout, mean: torch.Tensor) -> torch.Tensor:
    X, Y, Z = _front(lay.theta, lay.phi)
    rows = torch.arange(mean.shape[0]) // GRID_U
    below = (rows >= lay.slit_row + SLIT_ROWS - 1).double()
    # open: the jaw drops; lips are pinned at the mouth corners, the chin moves fully.
    depth_below = (MOUTH_Y - Y).clamp_min(0)
    sigma = 0.13 + 1.2 * depth_below.clamp_max(0.3)
    w = below * torch.exp(-0.5 * (X / sigma) ** 2) * _smoothstep(0.0, 0.5, Z)
    opn = torch.zeros_like(mean)
    opn[:, 1] = -0.16 * w
    opn[:, 2] = -0.05 * w
    slit = lay.slit_frac >= 0
    lower_edge = rows == lay.slit_row + SLIT_ROWS - 1
    f = lay.slit_frac.clamp_min(0)
    wl = torch.exp(-0.5 * (X / 0.13) ** 2) * _smoothstep(MOUTH_W + 0.02, MOUTH_W - 0.06, X.abs())
    opn[lower_edge] = 0
    opn[lower_edge, 1] = -0.16 * wl[lower_edge]
    opn[lower_edge, 2] = -0.05 * wl[lower_edge]
    opn[slit, 1] = -0.16 * f[slit] * wl[slit]
    opn[slit, 2] = -0.05 * f[slit] * wl[slit] - 0.10 * torch.sin(math.pi * f[slit]) * wl[slit]
    # Lower lip rows just below the slit follow the lower edge.
    # smile: corners up, out and back; lips stretch; cheeks rise.
    smile = torch.zeros_like(mean)
    corner = _g(X.abs() - MOUTH_W, 0.08) * _g(Y - MOUTH_Y, 0.08)
    lips = _g(X, 0.2) * _g(Y - MOUTH_Y, 0.08)
    cheek = _g(X.abs() - 0.28, 0.1) * _g(Y + 0.25, 0.1)
    smile[:, 0] = 0.05 * torch.sign(X) * corner + 0.12 * X * lips
    smile[:, 1] = 0.06 * corner + 0.025 * cheek
    smile[:, 2] = -0.03 * corner + 0.03 * cheek
    smile[slit, 1] += 0.015 * (1 - f[slit]) * _g(X[slit], 0.12)  # upper lip lifts: teeth show when open
    return torch.stack([smile, opn]) * _smoothstep(0.0, 0.4, Z)[None, :, None]


# The iBUG jaw contour, points 0-8 (subject right to the chin), about where the 300-W mean
# shape places it: (x, y) in eye-to-eye units from the midpoint of the eye centres, y down
# (real faces: jaw ends near +-1.1, chin near 1.7).  0 sits at the eye line on the face's
# outline, 3-4 at the nose base and mouth corners, 8 the chin; the other half mirrors it.
# Placed on the mean face by :func:`_jaw_targets`.
JAW_IBUG = [
    (-1.11, -0.03),
    (-1.10, 0.28),
    (-1.06, 0.58),
    (-0.99, 0.87),
    (-0.87, 1.14),
    (-0.68, 1.37),
    (-0.45, 1.55),
    (-0.18, 1.69),
    (0.0, 1.71),
]


def _jaw_targets() -> list[tuple[float, float]]:
    """``JAW_IBUG`` in front coordinates (X, Y) of the mean head: one eye-to-eye unit is
    ``2 EYE_X`` across (``width``) and the same length down (``height``)."""
    w, h = SHAPE_PARAMS["width"][0], SHAPE_PARAMS["height"][0]
    e = 2 * EYE_X * w  # the eye-to-eye distance in model units
    return [(x * e / w, EYE_Y - y * e / h) for x, y in JAW_IBUG]


def _landmark_targets() -> list[tuple[str, float, float]]:
    """The 68 iBUG points as (kind, X, Y) in front coordinates; kind 'upper'/'lower' pins inner-lip rows."""
    pts = []
    jaw = _jaw_targets()
    for x, y in jaw + [(-x, y) for x, y in jaw[-2::-1]]:  # jaw 0-16, image left (subject right, x<0) to image right
        pts.append(("front", x, y))
    for xs in (-1, 1):  # brows 17-21 (x<0), 22-26
        xs_list = [BROW_X + d for d in (0.20, 0.11, 0.01, -0.09, -0.18)]
        seq = xs_list if xs < 0 else xs_list[::-1]
        for x in seq:
            pts.append(("front", xs * x, BROW_Y + 0.035 - 0.18 * (abs(x) - BROW_X) ** 2))
    for y in (0.17, 0.06, -0.06, NOSE_TIP_Y):
        pts.append(("front", 0.0, y))
    for x, dy in ((-0.1, 0.0), (-0.05, -0.015), (0.0, -0.02), (0.05, -0.015), (0.1, 0.0)):
        pts.append(("front", x, NOSE_BASE_Y + dy))
    for sgn in (-1, 1):  # eyes 36-41 (x<0, from the outer corner), 42-47 (from the inner corner)
        c = sgn * EYE_X
        # both start at the image-left corner and run clockwise in the image, as dlib does
        ring = [(-1, 0), (-0.35, 1), (0.35, 1), (1, 0), (0.35, -1), (-0.35, -1)]
        ring = [(c + dx * EYE_W, EYE_Y + dy * EYE_H) for dx, dy in ring]
        pts += [("front", x, y) for x, y in ring]
    W, M = MOUTH_W, MOUTH_Y
    outer = [
        (-W, 0),
        (-0.65 * W, 0.06),
        (-0.35 * W, 0.065),
        (0, 0.06),
        (0.35 * W, 0.065),
        (0.65 * W, 0.06),
        (W, 0),
        (0.65 * W, -0.06),
        (0.3 * W, -0.08),
        (0, -0.085),
        (-0.3 * W, -0.08),
        (-0.65 * W, -0.06),
    ]
    pts += [("upper" if dy == 0 else "front", x, M + dy) for x, dy in outer]
    inner = [
        ("upper", -0.7 * W),
        ("upper", -0.35 * W),
        ("upper", 0.0),
        ("upper", 0.35 * W),
        ("upper", 0.7 * W),
        ("lower", 0.35 * W),
        ("lower", 0.0),
        ("lower", -0.35 * W),
    ]
    pts += [(k, x, M) for k, x in inner]
    return pts


def _landmarks(lay: Layout) -> torch.Tensor:
    X, Y, Z = _front(lay.theta, lay.phi)
    rows = torch.arange(X.shape[0]) // GRID_U
    idx = []
    for kind, a, b in _landmark_targets():
        d = (X - a) ** 2 + (Y - b) ** 2 + 10.0 * (Z < 0)
        if kind == "upper":
            d = d + 10.0 * (rows != lay.slit_row)
        elif kind == "lower":
            d = d + 10.0 * (rows != lay.slit_row + SLIT_ROWS - 1)
        elif kind == "front":
            d = d + 10.0 * ((lay.slit_frac > 0) & (lay.slit_frac < 1))
        idx.append(int(d.argmin()))
    return torch.tensor(idx)


@per_device
@lru_cache(maxsize=1)
@single_thread()
def face_model() -> FaceModel:
    """The model (float32), built once from the parametric definitions above."""
    lay = layout()
    # Mean and central differences (one std of each parameter), evaluated in one broadcast call.
    names = list(SHAPE_PARAMS)
    P = len(names)
    table = torch.tensor([m for m, _ in SHAPE_PARAMS.values()], dtype=torch.float64).repeat(2 * P + 1, 1)
    std = torch.tensor([s for _, s in SHAPE_PARAMS.values()], dtype=torch.float64)
    table[1 : P + 1] += torch.diag(std)
    table[P + 1 :] -= torch.diag(std)
    surf = _surface(lay.theta, lay.phi, lay.slit_frac, {k: table[:, i : i + 1] for i, k in enumerate(names)})
    mean = surf[0]
    comps = list(0.5 * (surf[1 : P + 1] - surf[P + 1 :]))
    radial = mean / mean.norm(dim=-1, keepdim=True)
    n_rand = N_IDENTITY - len(comps)
    comps += list(_smooth_fields(lay.theta, lay.phi, n_rand)[..., None] * radial)
    body = (~is_neck(lay.phi)).to(mean.dtype)[:, None]  # identity and expression leave the neck alone
    ident = torch.stack(comps) * body
    order = ident.flatten(1).norm(dim=1).argsort(descending=True)  # by variance, as PCA would order them
    ident = ident[order]
    expr = _expressions(lay, mean)
    X, Y, Z = _front(lay.theta, lay.phi)
    # senior: sagging cheeks and jowls, a longer nose, thinner lips, hollow temples.
    senior = torch.zeros_like(mean)
    jowl = _g(X.abs() - 0.42, 0.12) * _g(Y + 0.55, 0.12)
    senior[:, 1] = -0.03 * jowl - 0.02 * _g(X, 0.08) * _g(Y - NOSE_TIP_Y, 0.06)
    senior[:, 0] = 0.02 * torch.sign(X) * jowl
    senior = (
        senior
        - radial
        * (
            0.012 * _g(X, 0.14) * _g(Y - MOUTH_Y, 0.05)
            + 0.015 * _g(X.abs() - 0.6, 0.08) * _g(Y - 0.28, 0.1)
            + 0.012 * _g(X.abs() - 0.33, 0.08) * _g(Y + 0.02, 0.05)
        )[:, None]
    )
    senior = senior * _smoothstep(0.0, 0.4, Z)[:, None]
    expr, senior = expr * body, senior * body
    face_region = ((Z > 0.2) & (Y < HAIRLINE_Y - 0.02) & (Y > CHIN_Y - 0.08) & (X.abs() < 0.78)).double()
    f = lambda t: t.float().contiguous()
    return FaceModel(f(mean), f(ident), f(expr), f(senior), faces(), f(lay.uv), _landmarks(lay), f(face_region))


__all__ = [
    "FaceModel",
    "face_model",
    "faces",
    "layout",
    "uv_to_angles",
    "is_neck",
    "GRID_U",
    "GRID_V",
    "NECK_ROWS",
    "N_IDENTITY",
    "EXPRESSIONS",
]

"""A vectorized triangle rasterizer in torch: z-buffer and barycentric interpolation.

Camera: orthographic (weak perspective, as 3DMM fits use at face-crop distances).
``vertices_cam [B, V, 3]`` are in the camera frame of :mod:`disent.render`: x right, y up,
z towards the camera, with x and y in normalised image units (``[-1, 1]`` spans the
image, pixel centres at ``-1 + (2j + 1) / W``).  Larger z is nearer.

How it works, all in batched tensor ops:

1. keep front-facing triangles (counter-clockwise in x-right/y-up), over the whole batch;
2. every (triangle, pixel centre inside its bounding box) pair is tested with the
   triangle's edge functions: the first centre of every box in one pass that needs no
   gathering (most triangles are about a pixel), the other centres of the larger boxes
   in a second pass;
3. the z-buffer is a ``scatter_reduce(amax)`` over keys that pack quantised depth above
   the triangle id, so the nearest triangle wins in one pass;
4. the winners' barycentric coordinates interpolate the per-vertex attributes.

:func:`rasterize_grids` is the same rasterizer for meshes that are regular grids (the face
model and its coarse fit), faster by working on quads, several meshes in one call; it
returns what :func:`rasterize` returns for :func:`grid_faces` (less the dense maps), and the
tests hold the two to the same pixels.  A raster lists the covered pixels; per-pixel work can
stay on that list (:func:`interpolate_covered`, :func:`sample_texture`, :func:`pick`) and
become an image only at the end (:func:`paste`, :func:`interpolate`).  Vertex data may be
stored as coordinate planes ``[B, 3, V]`` (seen as ``[B, V, 3]`` through ``transpose(1, 2)``):
every function here reads either layout.
"""

from __future__ import annotations

import torch

from disent.render import unit

_ID_BITS = 20  # triangle ids below 2**20
_DEPTH_LEVELS = 2**38  # depth quantisation over [-DEPTH_RANGE, DEPTH_RANGE]
_DEPTH_RANGE = 16.0
_CAND_BITS = 31  # rasterize_grids: candidate ids below 2**31 (the key packs 31 depth bits above them)
_FOLD = 1e30  # rasterize_grids: a bias beyond any cross product, to force one triangle of a folded quad
MAX_WINDOW = 64  # triangles wider than this many pixels are refused (refine the mesh)
_MAX_PIXELS = 2**24  # rasterize_grids: pixel ids are float32 integers, exact below 2**24


def pose_matrix(pose_deg: torch.Tensor) -> torch.Tensor:
    """Rotation ``[B, 3, 3]`` from ``pose [B, 3]`` = (yaw, pitch, roll) in degrees.

    Positive yaw turns the face towards image right (about +y), positive pitch tilts it
    up (about -x), positive roll turns it counter-clockwise in the image (about +z).
    Applied as R = R_roll @ R_pitch @ R_yaw to model-frame vectors.
    """
    if pose_deg.dim() != 2 or pose_deg.shape[1] != 3:
        raise ValueError(f"pose must be [B,3] (yaw, pitch, roll in degrees), got {tuple(pose_deg.shape)}")
    y, p, r = torch.deg2rad(pose_deg).unbind(1)
    one, zero = torch.ones_like(y), torch.zeros_like(y)

    def mat(rows):
        return torch.stack([torch.stack(row, -1) for row in rows], -2)

    Ry = mat(((y.cos(), zero, y.sin()), (zero, one, zero), (-y.sin(), zero, y.cos())))
    Rx = mat(((one, zero, zero), (zero, p.cos(), p.sin()), (zero, -p.sin(), p.cos())))
    Rz = mat(((r.cos(), -r.sin(), zero), (r.sin(), r.cos(), zero), (zero, zero, one)))
    return Rz @ Rx @ Ry


def to_camera(vertices: torch.Tensor, pose_deg: torch.Tensor, scale: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Model-frame ``vertices [B, V, 3]`` -> camera frame: ``scale * R v + (shift_x, shift_y, 0)``.

    ``scale [B]`` maps model units to normalised image units; ``shift [B, 2]`` in image units.
    Computed on coordinate planes: the result is a ``[B, V, 3]`` view of ``[B, 3, V]`` planes
    (as is the input of :meth:`FaceModel.shape_planes` transposed), the renderer's layout.
    """
    sR = pose_matrix(pose_deg).to(vertices.dtype) * scale.to(vertices.dtype)[:, None, None]
    t = torch.nn.functional.pad(shift.to(vertices.dtype), (0, 1))[:, :, None]
    return torch.baddbmm(t, sR, vertices.transpose(1, 2)).transpose(1, 2)


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals ``[B, V, 3]`` (outward for counter-clockwise faces)."""
    B, V, _ = vertices.shape
    vt = vertices.permute(1, 0, 2).reshape(V, B * 3)  # vertex-major: gathers copy contiguous rows
    v0, v1, v2 = (vt.index_select(0, faces[:, k]).view(-1, B, 3) for k in range(3))
    fn = torch.linalg.cross(v1 - v0, v2 - v0, dim=-1).reshape(-1, B * 3)  # [T, B*3], length = 2 * area
    n = torch.zeros_like(vt)
    for k in range(3):
        n.index_add_(0, faces[:, k], fn)
    return unit(n.view(V, B, 3), -1).permute(1, 0, 2)


def rasterize(vertices_cam: torch.Tensor, faces: torch.Tensor, resolution: int) -> dict:
    """Visible triangle and barycentrics per pixel.

    Returns ``face_id [B, H, W]`` (int64, -1 on background), ``size`` (B, H, W) and the covered pixels as
    flat lists: ``batch [M]``, ``pixel [M]`` (row-major index, row 0 at the top),
    ``face [M]``, ``bary [M, 3]`` and ``corners [3, M]``, the face's vertices as flat ids
    ``batch * V + vertex`` (what :func:`interpolate` gathers).
    """
    if vertices_cam.dim() != 3 or vertices_cam.shape[-1] != 3:
        raise ValueError(f"vertices_cam must be [B,V,3], got {tuple(vertices_cam.shape)}")
    if faces.dim() != 2 or faces.shape[1] != 3 or faces.shape[0] >= 2**_ID_BITS:
        raise ValueError(f"faces must be [T,3] with T < {2**_ID_BITS}, got {tuple(faces.shape)}")
    B, V, _ = vertices_cam.shape
    H = W = resolution
    dev, dt = vertices_cam.device, vertices_cam.dtype
    # Vertex-major planes [V, B]; pixel coordinates with y up: pixel (col j, row H-1-i) has its centre at (j, i).
    vt = vertices_cam.permute(2, 1, 0)  # [3, V, B]
    x = ((vt[0] + 1) * (0.5 * W) - 0.5).contiguous()
    y = ((vt[1] + 1) * (0.5 * H) - 0.5).contiguous()
    z = vt[2].contiguous()
    X = [x.index_select(0, faces[:, k]) for k in range(3)]  # [T, B] each
    Y = [y.index_select(0, faces[:, k]) for k in range(3)]
    area2 = (X[1] - X[0]) * (Y[2] - Y[0]) - (Y[1] - Y[0]) * (X[2] - X[0])  # twice the signed area
    x_lo = torch.minimum(torch.minimum(X[0], X[1]), X[2]).ceil_().clamp_min_(0)
    y_lo = torch.minimum(torch.minimum(Y[0], Y[1]), Y[2]).ceil_().clamp_min_(0)
    nx = (torch.maximum(torch.maximum(X[0], X[1]), X[2]).floor_().clamp_max_(W - 1) - x_lo + 1).clamp_min_(0)
    ny = (torch.maximum(torch.maximum(Y[0], Y[1]), Y[2]).floor_().clamp_max_(H - 1) - y_lo + 1).clamp_min_(0)
    count = (nx * ny).masked_fill_(area2 <= 1e-9, 0).long().view(-1)  # pixel centres in each box
    k = count.nonzero().squeeze(1)  # flat (triangle, image) ids, t * B + b
    face_id = torch.full((B * H * W,), -1, dtype=torch.long, device=dev)
    empty = torch.zeros(0, dtype=torch.long, device=dev)
    if k.numel() == 0:
        bary = torch.zeros(0, 3, dtype=dt, device=dev)
        return {"face_id": face_id.view(B, H, W), "size": (B, H, W), "bary": bary, "corners": empty.view(3, 0)} | {
            "batch": empty,
            "pixel": empty,
            "face": empty,
        }
    big = int(torch.maximum(nx.max(), ny.max()))
    if big > MAX_WINDOW:
        raise ValueError(f"a triangle spans {big} pixels; the rasterizer expects a mesh finer than {MAX_WINDOW} px")
    # Edge functions w_j = A_j x + B_j y + C_j (barycentrics) and depth z = A_z x + B_z y + C_z,
    # one row per kept triangle; x, y at the triangle's box origin.
    x0, x1, x2, y0, y1, y2 = (v.view(-1).index_select(0, k) for v in (*X, *Y))
    inv = 1.0 / area2.view(-1).index_select(0, k)
    zt = [z.index_select(0, faces[:, j]).view(-1).index_select(0, k) for j in range(3)]
    A = [(y1 - y2) * inv, (y2 - y0) * inv, (y0 - y1) * inv]
    Bc = [(x2 - x1) * inv, (x0 - x2) * inv, (x1 - x0) * inv]
    xl, yl, nxk = x_lo.view(-1).index_select(0, k), y_lo.view(-1).index_select(0, k), nx.view(-1).index_select(0, k)
    C = [(x1 * y2 - x2 * y1) * inv, (x2 * y0 - x0 * y2) * inv, (x0 * y1 - x1 * y0) * inv]
    lin = [(A[0], Bc[0], C[0]), (A[1], Bc[1], C[1]), (A[2], Bc[2], C[2])]
    lin.append(tuple(a * zt[0] + b * zt[1] + c * zt[2] for a, b, c in zip(*lin)))
    # Slot s is the s-th pixel centre of a box: slot 0 covers every kept triangle without
    # any gathering; the later slots of the larger boxes follow in one gathered pass.
    cnt = count.index_select(0, k)
    cand = []

    def test(sel, slot):  # the `slot`-th centre of the boxes `sel`
        take = (lambda v: v) if sel is None else (lambda v: v.index_select(0, sel))
        n_ = take(nxk)
        px = take(xl) + torch.remainder(slot, n_)
        py = take(yl) + torch.div(slot, n_, rounding_mode="floor")
        w = [take(a) * px + take(b) * py + take(c) for a, b, c in lin]  # w0 w1 w2 z
        ok = ((w[0] >= -1e-6) & (w[1] >= -1e-6) & (w[2] >= -1e-6)).nonzero().squeeze(1)
        ids = ok if sel is None else sel.index_select(0, ok)
        cand.append((ids, px.index_select(0, ok), py.index_select(0, ok), *(v.index_select(0, ok) for v in w)))

    test(None, torch.zeros_like(nxk))
    more = (cnt > 1).nonzero().squeeze(1)
    if more.numel():  # the boxes with more centres: all their remaining (box, slot) pairs at once
        extra = cnt.index_select(0, more) - 1
        row = torch.repeat_interleave(extra)
        first = torch.cumsum(extra, 0) - extra
        slot = (torch.arange(row.numel(), device=dev) - first.index_select(0, row) + 1).to(dt)
        test(more.index_select(0, row), slot)
    rep, px, py, w0, w1, w2, depth = (torch.cat(c) for c in zip(*cand))
    return _nearest(k.index_select(0, rep), px, py, (w0, w1, w2), depth, faces, (B, V, H, W), face_id)


def _nearest(kk, px, py, bary_raw, depth, faces, shape, face_id) -> dict:
    """:func:`rasterize`'s z-buffer: of the candidates (``kk``: flat (triangle, image) ids ``t * B + b``, at pixel
    centres ``px, py`` with barycentrics ``bary_raw`` and ``depth``), the nearest of each pixel, as its dict."""
    B, V, H, W = shape
    tri_t, tri_b = kk // B, kk % B
    pix = tri_b * (H * W) + (H - 1 - py.long()) * W + px.long()
    # z-buffer: nearest (largest z) wins; the key packs quantised depth above the triangle id.
    zq = (
        (depth.double().clamp(-_DEPTH_RANGE, _DEPTH_RANGE) + _DEPTH_RANGE) * (_DEPTH_LEVELS / (2 * _DEPTH_RANGE))
    ).long()
    key = (zq << _ID_BITS) | tri_t
    zbuf = torch.full((B * H * W,), -1, dtype=torch.long, device=kk.device)
    zbuf.scatter_reduce_(0, pix, key, reduce="amax")
    win = (zbuf.index_select(0, pix) == key).nonzero().squeeze(1)
    win_pix, win_t = pix.index_select(0, win), tri_t.index_select(0, win)
    face_id[win_pix] = win_t
    bary = torch.stack([w.index_select(0, win) for w in bary_raw], 1).clamp_min(0)
    bary = bary / bary.sum(1, keepdim=True)
    batch = win_pix // (H * W)
    corners = torch.stack([faces[:, j].index_select(0, win_t) for j in range(3)]) + batch * V
    return {
        "face_id": face_id.view(B, H, W),
        "size": (B, H, W),
        "batch": batch,
        "pixel": win_pix % (H * W),
        "face": win_t,
        "bary": bary,
        "corners": corners,
    }


def interpolate(attr, raster: dict) -> torch.Tensor:
    """Per-vertex ``attr [B, V, C]`` (or shared ``[V, C]``, or a list of such) -> per-pixel
    ``[B, C, H, W]`` (0 on background; a list's channels are concatenated)."""
    return paste(interpolate_covered(attr, raster), raster)


def interpolate_covered(attr, raster: dict) -> torch.Tensor:
    """:func:`interpolate` at the covered pixels only: ``[C, M]`` in the order of ``raster``'s lists,
    from their ``corners`` (flat vertex ids ``batch * V + vertex``) and ``bary``.

    One channel at a time with flat gathers (gathering small rows is slow on the CPU); a
    channel stored as a plane (``attr.transpose(1, 2)`` of a ``[B, C, V]`` tensor) is read
    without a copy."""
    attrs = list(attr) if isinstance(attr, (list, tuple)) else [attr]
    bi, corners = raster["batch"], raster["corners"]
    w = raster["bary"].to(attrs[0].dtype).t()
    if w.stride(1) != 1:  # rasterize_grids already stores barycentrics as planes
        w = w.contiguous()
    out = torch.empty(sum(a.shape[-1] for a in attrs), bi.numel(), dtype=attrs[0].dtype, device=attrs[0].device)
    shared = {}  # vertex ids within one mesh, for attributes shared by the batch
    c = 0
    for a in attrs:
        if a.dim() == 2 and a.shape[0] not in shared:
            shared[a.shape[0]] = corners - bi * a.shape[0]
        rows = shared[a.shape[0]] if a.dim() == 2 else corners
        for plane in a.permute(-1, *range(a.dim() - 1)):  # [(B,) V] per channel
            v = plane.reshape(-1)
            val = torch.mul(v.index_select(0, rows[0]), w[0], out=out[c])
            val.addcmul_(v.index_select(0, rows[1]), w[1]).addcmul_(v.index_select(0, rows[2]), w[2])
            c += 1
    return out


def paste(values: torch.Tensor, raster: dict, background: torch.Tensor | None = None) -> torch.Tensor:
    """Values at the covered pixels ``[C, M]`` -> an image ``[B, C, H, W]`` that is ``background``
    (default 0) elsewhere: Eq. 6's composite for a binary matte, with no pass over the background's pixels."""
    B, H, W = raster["size"]
    C = values.shape[0]
    if background is None:
        out = torch.zeros(B * C * H * W, dtype=values.dtype, device=values.device)
    else:
        out = background.to(values.dtype, memory_format=torch.contiguous_format, copy=True).view(-1)
    at = _pixel_index(raster, C)
    for c in range(C):
        out.scatter_(0, at + c * (H * W) if c else at, values[c])
    return out.view(B, C, H, W)


def pick(image: torch.Tensor, raster: dict) -> torch.Tensor:
    """``image [B, C, H, W]`` at the covered pixels of ``raster``: ``[C, M]`` (what :func:`paste` undoes)."""
    C, HW = image.shape[1], image[0, 0].numel()
    flat, at = image.contiguous().view(-1), _pixel_index(raster, C)
    return torch.stack([flat.index_select(0, at + c * HW if c else at) for c in range(C)])


def _pixel_index(raster: dict, C: int) -> torch.Tensor:
    """Flat index of channel 0 of each covered pixel in a ``[B, C, H, W]`` image."""
    _, H, W = raster["size"]
    return raster["batch"] * (C * H * W) + raster["pixel"]


def face_ids(raster: dict) -> torch.Tensor:
    """The visible face of every pixel, ``[B, H, W]`` int64, -1 on background (for :func:`rasterize_grids`,
    the :func:`grid_faces` id, from the corners)."""
    B, H, W = raster["size"]
    face = raster.get("face")
    if face is None:  # quad q = (row, column) of corner a; its second triangle is q + Q
        gv, gu = raster["grid"]
        k = raster["corners"][1] - gu
        a = k - raster["batch"] * (gv * gu)
        face = a - torch.div(a, gu, rounding_mode="floor") + (raster["corners"][0] - k) * ((gv - 1) * (gu - 1))
    out = torch.full((B * H * W,), -1, dtype=torch.long, device=face.device)
    return out.scatter_(0, _pixel_index(raster, 1), face).view(B, H, W)


def sample_texture(texture: torch.Tensor, uv: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of ``texture [B, C, R, R]`` at ``uv [2, M]`` (in [0, 1], u right, v down) of the
    images ``batch [M]``: ``[C, M]``, what ``grid_sample(texture, 2 uv - 1, align_corners=True)`` gives
    at those pixels (up to float rounding)."""
    B, C, R, _ = texture.shape
    x, y = uv[0] * (R - 1), uv[1] * (R - 1)
    x0, y0 = x.floor().clamp_(0, R - 2), y.floor().clamp_(0, R - 2)
    fx, fy = x.sub_(x0), y.sub_(y0)
    corner = (batch * (C * R * R)).add_(y0.mul_(R).add_(x0).long()).int()  # top-left texel, channel 0 of image b
    flat = texture.contiguous().view(-1)
    out = torch.empty(C, uv.shape[1], dtype=texture.dtype, device=texture.device)
    for c in range(C):  # the texel to the right, below, below right: the same index into shifted views
        t00, t01, t10, t11 = (flat[c * R * R + d :].index_select(0, corner) for d in (0, 1, R, R + 1))
        torch.lerp(t00.lerp_(t01, fx), t10.lerp_(t11, fx), fy, out=out[c])
    return out


def grid_vertex_normals(vertices: torch.Tensor, grid_shape: tuple[int, int]) -> torch.Tensor:
    """Unit vertex normals ``[B, V, 3]`` of a mesh that is a regular ``rows x cols`` grid
    (row-major, rows running down, columns to the right), from central differences on
    the grid: the fast path for the face model; same orientation as :func:`vertex_normals`.
    Computed on coordinate planes; the result is a ``[B, V, 3]`` view of ``[B, 3, V]`` planes."""
    B, V, _ = vertices.shape
    gv, gu = grid_shape
    P = vertices.transpose(1, 2).reshape(B, 3, gv, gu)
    du, dv = torch.empty_like(P), torch.empty_like(P)
    for d, dim in ((du, 3), (dv, 2)):  # central differences inside, one-sided at the borders
        n = P.shape[dim]
        torch.sub(P.narrow(dim, 2, n - 2), P.narrow(dim, 0, n - 2), out=d.narrow(dim, 1, n - 2))
        torch.sub(P.narrow(dim, 1, 1), P.narrow(dim, 0, 1), out=d.narrow(dim, 0, 1))
        torch.sub(P.narrow(dim, n - 1, 1), P.narrow(dim, n - 2, 1), out=d.narrow(dim, n - 1, 1))
    # Collapsed rows (a closed mouth) have no extent along v: take a two-row stencil there.  The
    # test is relative (|dv| < 1e-3 |du|): a collapsed row's dv is float32 rounding, not a direction.
    flat = _squared_norm(dv) < _squared_norm(du).mul_(1e-6)  # [B, gv, gu]
    rows = flat.any(0).any(1).nonzero().squeeze(1)
    if rows.numel():
        dv2 = P[:, :, (rows + 2).clamp(max=gv - 1)] - P[:, :, (rows - 2).clamp(min=0)]
        dv[:, :, rows] = torch.where(flat[:, None, rows], dv2, dv[:, :, rows])
    (vx, vy, vz), (ux, uy, uz) = dv.unbind(1), du.unbind(1)
    n, tmp = torch.empty_like(P), torch.empty_like(vx)
    for k, (a, b, c, d) in enumerate(((vy, uz, vz, uy), (vz, ux, vx, uz), (vx, uy, vy, ux))):
        torch.mul(a, b, out=n[:, k]).sub_(torch.mul(c, d, out=tmp))  # dv x du, on planes
    return unit_planes(n, inplace=True).view(B, 3, V).transpose(1, 2)


def grid_faces(gv: int, gu: int) -> torch.Tensor:
    """Triangles ``[2Q, 3]`` of a ``gv x gu`` vertex grid (row-major, rows running down), counter-clockwise
    seen from outside: quad ``q`` at (row r, column c) with corners a=(r,c), b=(r,c+1), c'=(r+1,c),
    d=(r+1,c+1) is split along b-c' into triangle ``q`` = (a, c', b) and triangle ``Q + q`` = (b, c', d)."""
    r, c = torch.meshgrid(torch.arange(gv - 1), torch.arange(gu - 1), indexing="ij")
    a = (r * gu + c).flatten()
    return torch.cat([torch.stack([a, a + gu, a + 1], 1), torch.stack([a + 1, a + gu, a + gu + 1], 1)])


def _window(extreme, v: torch.Tensor, gu: int, K: int, out: torch.Tensor | None = None) -> torch.Tensor:
    """``extreme`` (torch.minimum or torch.maximum) of the four corners k, k + 1, k + gu, k + gu + 1 of
    each quad k < K of the flat vertex values ``v``."""
    pairs = extreme(v[:-1], v[1:])
    return extreme(pairs[:K], pairs[gu : gu + K], out=out)


_LAYOUTS: dict = {}


def _grid_layout(
    B: int, gv: int, gu: int, drawn, img0: int, H: int, W: int, dt, dev
) -> tuple[torch.Tensor, torch.Tensor]:
    """For the flat quad ids k < K of :func:`rasterize_grids` on ``B`` images of a ``gv x gu`` grid: 1 where
    k is a quad (its corner a is in neither the last row nor the last column) that is drawn, and the pixel
    index of the top-left corner of its image, ``image * H * W + (H - 1) * W``.  The same for every batch
    of a mesh, so they are kept (a few entries)."""
    key = (B, gv, gu, None if drawn is None else drawn.cpu().numpy().tobytes(), img0, H, W, dt, str(dev))
    layout = _LAYOUTS.get(key)  # (a loader thread may render beside the main one: no check-then-read)
    if layout is None:
        V, K = gv * gu, B * gv * gu - gu - 1
        one = torch.zeros(gv, gu, dtype=dt, device=dev)
        one[:-1, :-1] = 1 if drawn is None else drawn.view(gv - 1, gu - 1)
        image = torch.arange(img0, img0 + B, device=dev, dtype=dt).mul_(H * W).add_((H - 1) * W)
        layout = (one.view(1, V).expand(B, V).reshape(-1)[:K], image[:, None].expand(B, V).reshape(-1)[:K])
        if len(_LAYOUTS) >= 8:
            _LAYOUTS.clear()
        _LAYOUTS[key] = layout
    return layout


def _in_halves(meshes: list[tuple], info: list, resolution: int) -> list[dict]:
    """:func:`rasterize_grids` on each half of the batch, the two results joined (a batch too large for exact
    float32 pixel ids)."""
    H = W = resolution
    if len({B for B, _ in info}) != 1 or info[0][0] < 2:
        raise ValueError("rasterize_grids: too many pixels for one call and the meshes' batches differ")
    h = info[0][0] // 2
    halves = [rasterize_grids([(m[0][s], *m[1:]) for m in meshes], resolution) for s in (slice(0, h), slice(h, None))]
    return [
        {
            "size": (a["size"][0] + b["size"][0], H, W),
            "batch": torch.cat([a["batch"], b["batch"] + h]),
            "corners": torch.cat([a["corners"], b["corners"] + h * m[0].shape[1]], 1),
            "grid": m[1],
            **{k: torch.cat([a[k], b[k]]) for k in ("pixel", "bary")},
        }
        for a, b, m in zip(*halves, meshes)
    ]


def _quad_tables(meshes: list[tuple], info: list, sizes: list, H: int, W: int):
    """Per-quad and per-triangle data of :func:`rasterize_grids`, every mesh's quads in one table, and each quad's
    count of pixel centres in its box: ``(table [9, Q], tri [4, 2, Q], count [Q], Q)``."""
    dev, dt = meshes[0][0].device, meshes[0][0].dtype
    # Quads on the flattened vertex planes of each mesh: quad k has the corners a = k, b = k + 1, c = k + gu,
    # d = k + gu + 1 (flat ids over the batch), so each column below is a few contiguous slices; a k whose
    # corner a lies in the last row or column of its grid is no quad and is never drawn.
    n_quads = sum(sizes)
    # Per quad, written in place: the box origin about corner c, its width, the diagonal b - c, the fold
    # bias, the depth at c and along c -> b, and the box origin's pixel index; per triangle (quad q's
    # triangle (a,c,b) at q, (b,c,d) at n_quads + q): 1 / its doubled area, the far corner's edge about
    # c over that area (the barycentric of b), and the depth along c -> far corner.
    table = torch.empty(9, n_quads, dtype=dt, device=dev)
    tri = torch.empty(4, 2, n_quads, dtype=dt, device=dev)
    count = torch.empty(n_quads, dtype=dt, device=dev)
    q0, img0 = 0, 0
    for (verts, (gv, gu), *drawn), (B, _), K in zip(meshes, info, sizes):
        V = gv * gu
        if verts.shape[1] != V:
            raise ValueError(f"a {gv}x{gu} grid has {V} vertices, got {verts.shape[1]}")
        col, (inv, far_x, far_y, far_z) = table[:, q0 : q0 + K], (t[:, q0 : q0 + K] for t in tri)
        x = torch.addcmul(
            torch.tensor(0.5 * W - 0.5, dtype=dt), verts[..., 0], torch.tensor(0.5 * W, dtype=dt)
        ).reshape(-1)
        y = torch.addcmul(
            torch.tensor(0.5 * H - 0.5, dtype=dt), verts[..., 1], torch.tensor(0.5 * H, dtype=dt)
        ).reshape(-1)
        z = verts[..., 2].reshape(-1)
        xa, xb, xc, xd = x[:K], x[1 : K + 1], x[gu : K + gu], x[gu + 1 :]
        ya, yb, yc, yd = y[:K], y[1 : K + 1], y[gu : K + gu], y[gu + 1 :]
        za, zb, zc, zd = z[:K], z[1 : K + 1], z[gu : K + gu], z[gu + 1 :]
        ax, ay, dx, dy = xa - xc, ya - yc, xd - xc, yd - yc  # corners about c
        bx, by = torch.sub(xb, xc, out=col[3]), torch.sub(yb, yc, out=col[4])
        area1 = bx * ay
        area1.addcmul_(by, ax, value=-1)  # twice the signed areas of (a,c,b) and (b,c,d)
        area2 = dx * by
        area2.addcmul_(dy, bx, value=-1)
        # The box of pixel centres: extremes over each 2x2 window of corners, pairs along rows, then rows.
        x_lo = _window(torch.minimum, x, gu, K).ceil_().clamp_min_(0)
        y_lo = _window(torch.minimum, y, gu, K).ceil_().clamp_min_(0)
        nx = _window(torch.maximum, x, gu, K, out=col[2]).floor_().clamp_max_(W - 1).sub_(x_lo).add_(1).clamp_min_(0)
        ny = _window(torch.maximum, y, gu, K).floor_().clamp_max_(H - 1).sub_(y_lo).add_(1).clamp_min_(0)
        drawn_quads, origin = _grid_layout(B, gv, gu, drawn[0] if drawn else None, img0, H, W, dt, dev)
        f1 = torch.gt(area1, 1e-9, out=torch.empty_like(area1))
        f2 = torch.gt(area2, 1e-9, out=torch.empty_like(area2))
        torch.maximum(f1, f2, out=count[q0 : q0 + K]).mul_(nx).mul_(ny).mul_(drawn_quads)
        # Which triangle a centre p falls in: (a,c,b) iff s >= bias, with s = cross(b - c, p - c) (a's side of
        # the diagonal); the bias forces the front-facing triangle of a folded quad.
        torch.sub(f2, f1, out=col[5]).mul_(_FOLD)
        torch.sub(x_lo, xc, out=col[0])
        torch.sub(y_lo, yc, out=col[1])
        col[6].copy_(zc)
        torch.sub(zb, zc, out=col[7])
        torch.add(origin, x_lo, out=col[8]).addcmul_(y_lo, torch.tensor(-W, dtype=dt))  # pixel index of the box origin
        for t, (area, far) in enumerate(((area1, (ax, ay, za)), (area2.neg_(), (dx, dy, zd)))):
            torch.reciprocal(area, out=inv[t])  # (b,c,d) with the sign flipped: d's barycentric is s / (-area2)
            torch.mul(far[0], inv[t], out=far_x[t])
            torch.mul(far[1], inv[t], out=far_y[t])
            torch.sub(far[2], zc, out=far_z[t])
        q0, img0 = q0 + K, img0 + B
    return table, tri, count, n_quads


def _per_mesh(info, sizes, cov, quad, second, bary, H: int, W: int) -> list[dict]:
    """The winners of :func:`rasterize_grids`, in pixel order over the meshes in turn, cut into one raster dict per
    mesh: its images' covered pixels, barycentrics and grid_faces corners."""
    dev = cov.device
    out, q0, p0 = [], 0, 0
    bounds = [0] + torch.searchsorted(cov, torch.tensor([B * H * W for B, _ in info], device=dev).cumsum(0)).tolist()
    for m, ((B, (gv, gu)), K) in enumerate(zip(info, sizes)):
        lo, hi = bounds[m], bounds[m + 1]
        p = cov[lo:hi] - p0
        if H * W & (H * W - 1) == 0:  # a power of two: a shift and a mask, no division
            batch, pixel = p >> (H * W).bit_length() - 1, p & (H * W - 1)
        else:
            batch = torch.div(p, H * W, rounding_mode="floor")
            pixel = p - batch * (H * W)
        k, sec = quad[lo:hi] - q0, second[lo:hi]  # flat id of corner a; the quad's second triangle
        corners = torch.stack([k + sec, k + gu, k.add(sec, alpha=gu).add_(1)])  # grid_faces order
        out.append(
            {
                "size": (B, H, W),
                "grid": (gv, gu),
                "batch": batch,
                "pixel": pixel,
                "bary": bary[lo:hi],
                "corners": corners,
            }
        )
        q0, p0 = q0 + K, p0 + B * H * W
    return out


def rasterize_grids(meshes: list[tuple], resolution: int) -> list[dict]:
    """:func:`rasterize` for meshes that are regular grids triangulated by :func:`grid_faces`, several
    meshes in one pass: ``meshes`` is a list of (``vertices_cam [B, gv*gu, 3]``, ``(gv, gu)``) or
    (``vertices_cam``, ``(gv, gu)``, ``quads [(gv-1)*(gu-1)]`` bool: the quads drawn, default all).

    Returns, per mesh, the dict of :func:`rasterize` for that mesh and ``grid_faces(gv, gu)``
    (the same pixels, triangles and barycentrics up to float rounding and depth ties), with the
    ``grid`` shape and without the ``face`` list and the dense ``face_id`` map, which
    :func:`face_ids` builds from the corners when it is wanted.

    The grid saves work: the primitive is the quad (half as many as triangles), and on the
    flattened vertex planes a quad's four corners are the same planes shifted by 0, 1, gu and
    gu + 1, so its per-quad data is a few passes over contiguous memory.  Each pixel centre
    in a quad's box is put on one side of the quad's diagonal b-c, which picks one of its two
    triangles, and tested against that triangle only.  The z-buffer key packs the depth's
    order-preserving integer above the candidate's index; the winners are the candidates
    whose key their pixel keeps.
    """
    H = W = resolution
    dev, dt = meshes[0][0].device, meshes[0][0].dtype
    info = [(m[0].shape[0], m[1]) for m in meshes]  # (B, (gv, gu))
    n_images = sum(B for B, _ in info)
    if n_images * H * W >= _MAX_PIXELS:  # pixel ids must stay exact in float32: halve the batch
        return _in_halves(meshes, info, resolution)
    sizes = [B * gv * gu - gu - 1 for B, (gv, gu) in info]  # quad ids k per mesh (see _quad_tables)
    table, tri, count, n_quads = _quad_tables(meshes, info, sizes, H, W)
    # Candidates: every (quad, pixel centre of its box), quad after quad: candidate i belongs to the quad
    # whose run of ``count`` candidates covers i (the number of runs ending at or before i: a running sum
    # of marks at the run ends), and is the s-th centre of its box (row-major), s = i - the run's start.
    count = count.int()
    ends = torch.cumsum(count, 0, dtype=torch.int32)
    n = int(ends[-1]) if ends.numel() else 0
    if n >= 2**_CAND_BITS:
        raise ValueError(f"rasterize_grids: {n} candidate pixels, at most {2**_CAND_BITS}; split the batch")
    marks = torch.zeros(n + 1, dtype=torch.int32, device=dev)
    marks.index_add_(0, ends, torch.ones(1, dtype=torch.int32, device=dev).expand(n_quads))
    quad = torch.cumsum(marks[:n], 0, dtype=torch.int32)
    slot = torch.arange(n, dtype=torch.int32, device=dev).sub_((ends - count).index_select(0, quad)).to(dt)
    ox, oy, nx, bx, by, bias, zc, dzb, base = (t.index_select(0, quad) for t in table.unbind(0))
    sy = (slot / nx).floor_()
    sx = torch.addcmul(slot, sy, nx, value=-1)
    qx, qy = ox + sx, oy + sy  # the centre about c
    s = bx * qy
    s.addcmul_(by, qx, value=-1)
    second = torch.lt(s, bias, out=torch.empty_like(s))  # 0: triangle (a,c,b), 1: (b,c,d)
    t = quad.add(second.int(), alpha=n_quads)  # the triangle's entry in the per-triangle table
    inv, far_x, far_y, far_z = (v.view(-1).index_select(0, t) for v in tri)
    w_far = s.mul_(inv)  # barycentric of a (first) or d (second)
    w_b = qx.mul_(far_y).addcmul_(qy, far_x, value=-1)  # barycentric of b
    w_c = 1 - w_far - w_b
    ok = torch.ge(torch.minimum(torch.minimum(w_far, w_b), w_c), -1e-6, out=w_c)  # 1: inside (w_c no longer needed)
    depth = torch.addcmul(zc, w_far, far_z)
    depth.addcmul_(w_b, dzb)
    pix = base.add_(sx).addcmul_(sy, torch.tensor(-W, dtype=dt)).long()
    # z-buffer: nearest (largest z) wins; key = order-preserving integer of the float depth, then the candidate.
    # Positive floats order as their bits; a failed candidate gets -1.0, whose bits are negative, and so a negative key.
    depth.add_(_DEPTH_RANGE).clamp_min_(0).mul_(ok).add_(ok).sub_(1)
    key = torch.arange(n, device=dev).add_(depth.view(torch.int32).long(), alpha=2**_CAND_BITS)
    zbuf = torch.full((n_images * H * W,), -1, dtype=torch.long, device=dev)
    zbuf.scatter_reduce_(0, pix, key, reduce="amax")
    # The winners, read off the z-buffer: each covered pixel keeps its winning candidate's key (a failed
    # candidate's key is below the empty buffer's -1), listed in pixel order, which runs over the meshes in turn.
    cov = (zbuf >= 0).nonzero().squeeze(1)
    win = zbuf.index_select(0, cov).bitwise_and_(2**_CAND_BITS - 1)
    second, w_far, w_b, quad = (t.index_select(0, win) for t in (second, w_far, w_b, quad))
    # Clamp the tolerance's tiny negatives and renormalise, as rasterize does; stored as planes ([M, 3] seen).
    w_far.clamp_min_(0)
    w_b.clamp_min_(0)
    w_c = (1 - w_far - w_b).clamp_min_(0)
    total = (w_far + w_b).add_(w_c)
    w_far, w_b, w_c = (t.div_(total) for t in (w_far, w_b, w_c))
    w_b, w_far = w_far.lerp(w_b, second), w_b.lerp(w_far, second)  # (a, c, b) or (b, c, d) in grid_faces order
    bary = torch.stack([w_b, w_c, w_far]).t()
    return _per_mesh(info, sizes, cov, quad, second.int(), bary, H, W)


def render_face(
    vertices_cam: torch.Tensor,
    faces: torch.Tensor,
    uv: torch.Tensor,
    resolution: int,
    grid_shape: tuple[int, int],
    vertex_normal: torch.Tensor | None = None,
) -> dict:
    """Render the G-buffer of a face mesh: the layers the paper's decoders predict.

    Args:
        vertices_cam: ``[B, V, 3]`` in the camera frame (see the module docstring).
        faces: ``[T, 3]`` int64, counter-clockwise from outside.
        uv: ``[V, 2]`` texture coordinates in ``[0, 1]`` (u right, v down).
        resolution: output size H = W.
        grid_shape: ``(rows, columns)`` of the mesh's UV grid, for ``normal_uv``.
        vertex_normal: optional ``[B, V, 3]``; computed from the mesh when omitted.

    Returns a dict of ``[B, C, H, W]`` float tensors: ``mask`` (1 where the face is
    visible), ``normal`` (unit camera-frame normals inside, 0 outside), ``uv``,
    ``depth`` (camera z), and ``normal_uv`` (the camera-frame vertex normals laid out
    over UV space at the same resolution, the implicit model's target), plus ``face_id``.
    """
    if vertex_normal is None:
        vertex_normal = vertex_normals(vertices_cam, faces)
    r = rasterize(vertices_cam, faces, resolution)
    mask = (r["face_id"] >= 0)[:, None].to(vertices_cam.dtype)
    attrs = torch.cat(
        [vertex_normal, vertices_cam[..., 2:], uv.to(vertices_cam.dtype).expand(vertices_cam.shape[0], -1, -1)], -1
    )
    pix = interpolate(attrs, r)
    normal = unit(pix[:, :3], 1) * mask
    return {
        "mask": mask,
        "normal": normal,
        "depth": pix[:, 3:4],
        "uv": pix[:, 4:6],
        "normal_uv": grid_to_uv_map(vertex_normal, resolution, grid_shape),
        "face_id": r["face_id"],
    }


def grid_to_uv_map(
    vertex_attr: torch.Tensor,
    resolution: int,
    grid_shape: tuple[int, int],
    knots: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """Lay per-vertex values of a UV-grid mesh out as a ``[B, C, res, res]`` UV-space map
    (3-channel values, normals, are renormalised to unit length).

    The mesh's vertices form a regular ``grid_shape = (rows, columns)`` grid in UV space (the face
    model's is ``GRID_V x GRID_U``), so the map is a bilinear resize of that grid (texel centres at
    ``linspace(0, 1, res)``, as ``align_corners=True``); a grid with uneven rows and columns gives its ``knots``
    (v of each row, u of each column) and is interpolated linearly between them.  The
    resize is separable: along v a blend of two gathered rows per texel row, along u a
    batched product with the fixed interpolation matrix.
    """
    gv, gu = grid_shape
    B, V, C = vertex_attr.shape
    if V != gv * gu:
        raise ValueError(f"vertex_attr has {V} vertices, the UV grid {gv}x{gu}")
    if knots is None:
        knots = (torch.linspace(0, 1, gv, dtype=torch.float64), torch.linspace(0, 1, gu, dtype=torch.float64))
    grid = vertex_attr.reshape(B, gv, gu, C).permute(0, 3, 1, 2).reshape(B * C, gv, gu)
    # Along v first (fewer columns to carry): each texel row mixes two grid rows, gathered whole.
    i, f = _linear_taps(knots[0], resolution)
    f = f.to(vertex_attr.dtype)[:, None]
    rows = grid.index_select(1, i).mul_(1 - f).addcmul_(grid.index_select(1, i + 1), f)  # [B*C, res, gu]
    Wu = _linear_weights(knots[1], resolution).to(vertex_attr)  # [res, gu]
    out = torch.bmm(rows.view(B, C * resolution, gu), Wu.t().expand(B, gu, resolution)).view(
        B, C, resolution, resolution
    )
    return unit_planes(out, inplace=True) if C == 3 else out


def unit_planes(v: torch.Tensor, inplace: bool = False) -> torch.Tensor:
    """:func:`disent.render.unit` of ``[B, 3, ...]`` along dim 1, on the three planes (fewer passes);
    ``inplace`` scales ``v`` itself."""
    return v.mul_(_rsqrt_norm(v)) if inplace else v * _rsqrt_norm(v)


def _squared_norm(v: torch.Tensor) -> torch.Tensor:
    """``|v|^2`` of ``[B, 3, ...]`` along dim 1, ``[B, ...]``."""
    x, y, z = v.unbind(1)
    s = x * x
    return s.addcmul_(y, y).addcmul_(z, z)


def _rsqrt_norm(v: torch.Tensor) -> torch.Tensor:
    return _squared_norm(v).clamp_min_(1e-24).rsqrt_().unsqueeze(1)


def _linear_taps(knots: torch.Tensor, res: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Piecewise-linear interpolation at ``linspace(0, 1, res)`` between sorted ``knots [n]``:
    texel t is ``(1 - f[t]) * value[i[t]] + f[t] * value[i[t] + 1]``; returns ``i [res]``, ``f [res]`` (float64)."""
    t = torch.linspace(0, 1, res, dtype=torch.float64)
    knots = knots.double()
    i = torch.searchsorted(knots, t, right=True).clamp(1, len(knots) - 1)
    f = ((t - knots[i - 1]) / (knots[i] - knots[i - 1])).clamp(0, 1)
    return i - 1, f


def _linear_weights(knots: torch.Tensor, res: int) -> torch.Tensor:
    """:func:`_linear_taps` as a ``[res, n]`` matrix."""
    i, f = _linear_taps(knots, res)
    W = torch.zeros(res, len(knots), dtype=torch.float64)
    W[torch.arange(res), i] = 1 - f
    W[torch.arange(res), i + 1] += f
    return W


__all__ = [
    "pose_matrix",
    "to_camera",
    "vertex_normals",
    "grid_vertex_normals",
    "grid_faces",
    "rasterize",
    "rasterize_grids",
    "interpolate",
    "interpolate_covered",
    "paste",
    "pick",
    "face_ids",
    "sample_texture",
    "render_face",
    "grid_to_uv_map",
    "unit_planes",
    "MAX_WINDOW",
]

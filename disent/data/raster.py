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
"""
from __future__ import annotations

import torch

from disent.render import unit

_ID_BITS = 20  # triangle ids below 2**20
_DEPTH_LEVELS = 2**38  # depth quantisation over [-DEPTH_RANGE, DEPTH_RANGE]
_DEPTH_RANGE = 16.0
MAX_WINDOW = 64  # triangles wider than this many pixels are refused (refine the mesh)


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
    """
    R = pose_matrix(pose_deg).to(vertices.dtype)
    cam = scale.to(vertices.dtype)[:, None, None] * (vertices @ R.transpose(1, 2))
    return cam + torch.nn.functional.pad(shift.to(vertices.dtype), (0, 1))[:, None, :]


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

    Returns ``face_id [B, H, W]`` (int64, -1 on background) and the covered pixels as
    flat lists: ``batch [M]``, ``pixel [M]`` (row-major index, row 0 at the top),
    ``face [M]`` and ``bary [M, 3]``.
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
        return {"face_id": face_id.view(B, H, W), "batch": empty, "pixel": empty, "face": empty,
                "bary": torch.zeros(0, 3, dtype=dt, device=dev)}
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
    kk = k.index_select(0, rep)
    tri_t, tri_b = kk // B, kk % B
    pix = tri_b * (H * W) + (H - 1 - py.long()) * W + px.long()
    # z-buffer: nearest (largest z) wins; the key packs quantised depth above the triangle id.
    zq = ((depth.double().clamp(-_DEPTH_RANGE, _DEPTH_RANGE) + _DEPTH_RANGE) * (_DEPTH_LEVELS / (2 * _DEPTH_RANGE))).long()
    key = (zq << _ID_BITS) | tri_t
    zbuf = torch.full((B * H * W,), -1, dtype=torch.long, device=dev)
    zbuf.scatter_reduce_(0, pix, key, reduce="amax")
    win = (zbuf.index_select(0, pix) == key).nonzero().squeeze(1)
    win_pix, win_t = pix.index_select(0, win), tri_t.index_select(0, win)
    face_id[win_pix] = win_t
    bary = torch.stack([w0.index_select(0, win), w1.index_select(0, win), w2.index_select(0, win)], 1).clamp_min(0)
    bary = bary / bary.sum(1, keepdim=True)
    return {"face_id": face_id.view(B, H, W), "batch": win_pix // (H * W), "pixel": win_pix % (H * W),
            "face": win_t, "bary": bary}


def interpolate(attr: torch.Tensor, faces: torch.Tensor, raster: dict) -> torch.Tensor:
    """Per-vertex ``attr [B, V, C]`` (or shared ``[V, C]``) -> per-pixel ``[B, C, H, W]`` (0 on background)."""
    B, H, W = raster["face_id"].shape
    bi, pi = raster["batch"], raster["pixel"]
    corner = faces.index_select(0, raster["face"])  # [M, 3]
    C = attr.shape[-1]
    if attr.dim() == 2:
        flat, rows = attr, corner
    else:
        flat, rows = attr.reshape(-1, C), corner + (bi * attr.shape[1])[:, None]
    bary = raster["bary"].to(attr.dtype)
    mixed = sum(flat.index_select(0, rows[:, j]) * bary[:, j:j + 1] for j in range(3))  # [M, C]
    out = torch.zeros(B * H * W, C, dtype=attr.dtype, device=attr.device)
    out.index_copy_(0, bi * (H * W) + pi, mixed)
    return out.view(B, H, W, C).permute(0, 3, 1, 2)


def grid_vertex_normals(vertices: torch.Tensor, grid_shape: tuple[int, int]) -> torch.Tensor:
    """Unit vertex normals ``[B, V, 3]`` of a mesh that is a regular ``rows x cols`` grid
    (row-major, rows running down, columns to the right), from central differences on
    the grid: the fast path for the face model; same orientation as :func:`vertex_normals`."""
    B, V, _ = vertices.shape
    gv, gu = grid_shape
    P = vertices.view(B, gv, gu, 3)
    du = torch.cat([P[:, :, 1:2] - P[:, :, :1], P[:, :, 2:] - P[:, :, :-2], P[:, :, -1:] - P[:, :, -2:-1]], 2)
    dv = torch.cat([P[:, 1:2] - P[:, :1], P[:, 2:] - P[:, :-2], P[:, -1:] - P[:, -2:-1]], 1)
    # Collapsed rows (a closed mouth) have no extent along v: take a two-row stencil there.
    r = torch.arange(gv, device=vertices.device)
    dv2 = P[:, (r + 2).clamp(max=gv - 1)] - P[:, (r - 2).clamp(min=0)]
    dv = torch.where((dv * dv).sum(-1, keepdim=True) < 1e-12, dv2, dv)
    n = torch.linalg.cross(dv, du, dim=-1)
    return unit(n, -1).view(B, V, 3)


def render_face(vertices_cam: torch.Tensor, faces: torch.Tensor, uv: torch.Tensor, resolution: int,
                vertex_normal: torch.Tensor | None = None) -> dict:
    """Render the G-buffer of a face mesh: the layers the paper's decoders predict.

    Args:
        vertices_cam: ``[B, V, 3]`` in the camera frame (see the module docstring).
        faces: ``[T, 3]`` int64, counter-clockwise from outside.
        uv: ``[V, 2]`` texture coordinates in ``[0, 1]`` (u right, v down).
        resolution: output size H = W.
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
    attrs = torch.cat([vertex_normal, vertices_cam[..., 2:], uv.to(vertices_cam.dtype).expand(vertices_cam.shape[0], -1, -1)], -1)
    pix = interpolate(attrs, faces, r)
    normal = unit(pix[:, :3], 1) * mask
    return {"mask": mask, "normal": normal, "depth": pix[:, 3:4], "uv": pix[:, 4:6],
            "normal_uv": grid_to_uv_map(vertex_normal, resolution), "face_id": r["face_id"]}


def grid_to_uv_map(vertex_attr: torch.Tensor, resolution: int, grid_shape: tuple[int, int] | None = None) -> torch.Tensor:
    """Lay per-vertex values of a UV-grid mesh out as a ``[B, C, res, res]`` UV-space map.

    The face model's vertices form a regular ``GRID_V x GRID_U`` grid in UV space, so the
    map is a bilinear resize of that grid (normals are renormalised by the caller as needed).
    """
    from .face_model import GRID_U, GRID_V

    gv, gu = grid_shape or (GRID_V, GRID_U)
    B, V, C = vertex_attr.shape
    if V != gv * gu:
        raise ValueError(f"vertex_attr has {V} vertices, the UV grid {gv}x{gu}")
    grid = vertex_attr.reshape(B, gv, gu, C).permute(0, 3, 1, 2)
    out = torch.nn.functional.interpolate(grid, size=(resolution, resolution), mode="bilinear", align_corners=True)
    if C == 3:
        out = unit(out, 1)
    return out


__all__ = ["pose_matrix", "to_camera", "normalize", "vertex_normals", "grid_vertex_normals", "rasterize", "interpolate", "render_face", "grid_to_uv_map", "MAX_WINDOW"]

"""A vectorized triangle rasterizer in torch: z-buffer and barycentric interpolation.

Camera: orthographic (weak perspective, as 3DMM fits use at face-crop distances).
``vertices_cam [B, V, 3]`` are in the camera frame of :mod:`disent.render`: x right, y up,
z towards the camera, with x and y in normalised image units (``[-1, 1]`` spans the
image, pixel centres at ``-1 + (2j + 1) / W``).  Larger z is nearer.

How it works, all in batched tensor ops:

1. keep front-facing triangles (counter-clockwise in x-right/y-up), over the whole batch;
2. every (triangle, pixel centre inside its bounding box) pair becomes one row, made
   with ``repeat_interleave``, and is tested with the triangle's edge functions;
3. the z-buffer is a ``scatter_reduce(amax)`` over keys that pack quantised depth above
   the triangle id, so the nearest triangle wins in one pass;
4. the winners' barycentric coordinates interpolate the per-vertex attributes.
"""
from __future__ import annotations

import math

import torch

_ID_BITS = 20  # triangle ids below 2**20
_DEPTH_LEVELS = 2**38  # depth quantisation over [-DEPTH_RANGE, DEPTH_RANGE]
_DEPTH_RANGE = 16.0
MAX_WINDOW = 16  # triangles wider than this many pixels are refused (refine the mesh)


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
    v0, v1, v2 = (vertices[:, faces[:, k]] for k in range(3))
    fn = torch.linalg.cross(v1 - v0, v2 - v0)  # [B, T, 3], length = 2 * area
    n = torch.zeros_like(vertices)
    for k in range(3):
        n.index_add_(1, faces[:, k], fn)
    return torch.nn.functional.normalize(n, dim=-1, eps=1e-12)


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
    B, H = vertices_cam.shape[0], resolution
    W = H
    dev, dt = vertices_cam.device, vertices_cam.dtype
    # Pixel coordinates with y up: pixel (col j, row H-1-i) has its centre at integer (j, i).
    xy = (vertices_cam[..., :2] + 1) * (0.5 * W) - 0.5
    tri = xy[:, faces]  # [B, T, 3, 2]
    e1, e2 = tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0]
    area2 = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]  # twice the signed area
    lo = tri.amin(2).ceil().clamp_min(0)
    hi = torch.minimum(tri.amax(2).floor(), torch.tensor([W - 1.0, H - 1.0], dtype=dt, device=dev))
    n = (hi - lo + 1).clamp_min(0)
    count = torch.where(area2 > 1e-9, n[..., 0] * n[..., 1], 0).long()  # pixel centres in the bounding box
    b_idx, t_idx = count.nonzero(as_tuple=True)
    face_id = torch.full((B * H * W,), -1, dtype=torch.long, device=dev)
    if b_idx.numel() == 0:
        e = torch.zeros(0, dtype=torch.long, device=dev)
        return {"face_id": face_id.reshape(B, H, W), "batch": e, "pixel": e, "face": e, "bary": torch.zeros(0, 3, dtype=dt, device=dev)}
    if int(n.amax()) > MAX_WINDOW:
        raise ValueError(f"a triangle spans {int(n.amax())} pixels; the rasterizer expects a mesh finer than {MAX_WINDOW} px")
    # Edge functions w_k(x, y) = A_k x + B_k y + C_k (normalised barycentrics), one triangle per row.
    p = tri[b_idx, t_idx]  # [N, 3, 2]
    a2 = area2[b_idx, t_idx][:, None]
    x0, y0 = p[..., 0], p[..., 1]
    x1, y1, x2, y2 = x0.roll(-1, 1), y0.roll(-1, 1), x0.roll(-2, 1), y0.roll(-2, 1)
    coef = torch.stack([(y1 - y2) / a2, (x2 - x1) / a2, (x1 * y2 - x2 * y1) / a2], -1)  # [N, 3, 3]
    # One row per (triangle, pixel centre in its box): exactly the candidates, no padding.
    cnt = count[b_idx, t_idx]
    rep = torch.repeat_interleave(torch.arange(cnt.numel(), device=dev), cnt)
    start = torch.cumsum(cnt, 0) - cnt
    local = torch.arange(rep.numel(), device=dev) - start[rep]
    nx = n[b_idx, t_idx, 0].long()[rep]
    lo_k = lo[b_idx, t_idx].long()[rep]
    px, py = lo_k[:, 0] + local % nx, lo_k[:, 1] + local // nx
    c = coef[rep]  # [P, 3, 3]
    w = c[..., 0] * px[:, None].to(dt) + c[..., 1] * py[:, None].to(dt) + c[..., 2]  # [P, 3]
    inside = w.amin(1) >= -1e-6
    w, rep, px, py = w[inside], rep[inside], px[inside], py[inside]
    tri_b, tri_t = b_idx[rep], t_idx[rep]
    depth = (w * vertices_cam[..., 2][:, faces][tri_b, tri_t]).sum(1)
    pix = tri_b * (H * W) + (H - 1 - py) * W + px
    # z-buffer: nearest (largest z) wins; the key packs quantised depth above the triangle id.
    zq = ((depth.double().clamp(-_DEPTH_RANGE, _DEPTH_RANGE) + _DEPTH_RANGE) * (_DEPTH_LEVELS / (2 * _DEPTH_RANGE))).long()
    zbuf = torch.full((B * H * W,), -1, dtype=torch.long, device=dev)
    zbuf.scatter_reduce_(0, pix, (zq << _ID_BITS) | tri_t, reduce="amax")
    win = zbuf[pix] == ((zq << _ID_BITS) | tri_t)
    win_pix, win_t = pix[win], tri_t[win]
    face_id[win_pix] = win_t
    bary = w[win].clamp_min(0)
    bary = bary / bary.sum(1, keepdim=True)
    return {"face_id": face_id.reshape(B, H, W), "batch": win_pix // (H * W), "pixel": win_pix % (H * W),
            "face": win_t, "bary": bary}


def interpolate(attr: torch.Tensor, faces: torch.Tensor, raster: dict) -> torch.Tensor:
    """Per-vertex ``attr [B, V, C]`` (or shared ``[V, C]``) -> per-pixel ``[B, C, H, W]`` (0 on background)."""
    B, H, W = raster["face_id"].shape
    bi, pi = raster["batch"], raster["pixel"]
    corner = faces[raster["face"]]  # [M, 3]
    vals = attr[corner] if attr.dim() == 2 else attr[bi[:, None], corner]  # [M, 3, C]
    out = torch.zeros(B, H * W, attr.shape[-1], dtype=attr.dtype, device=attr.device)
    out[bi, pi] = torch.einsum("mkc,mk->mc", vals, raster["bary"].to(attr.dtype))
    return out.reshape(B, H, W, -1).permute(0, 3, 1, 2)


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
    normal = torch.nn.functional.normalize(pix[:, :3], dim=1, eps=1e-12) * mask
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
        out = torch.nn.functional.normalize(out, dim=1, eps=1e-12)
    return out


__all__ = ["pose_matrix", "to_camera", "vertex_normals", "rasterize", "interpolate", "render_face", "grid_to_uv_map", "MAX_WINDOW"]

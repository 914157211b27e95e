"""In-network rendering layers of Shu et al. (CVPR 2017), Sec. 3.1-3.3 and supplement A.

Conventions, fixed here once for the whole suite:

* Normals are unit vectors in the **camera frame**: +x to the right of the image,
  +y up (towards image row 0), +z towards the camera.  Tensors are channels first,
  ``normal[:, 0] = n_x``, ``normal[:, 1] = n_y``, ``normal[:, 2] = n_z``.
* Lighting is order-2 spherical harmonics, 9 coefficients per colour channel, in the
  paper's order ``L1..L9`` (Eq. 4): L1 constant; L2, L3, L4 the linear terms in
  y, z, x; L5 xy, L6 yz, L7 (3z^2 - 1), L8 xz, L9 x^2 - y^2.  ``sh`` tensors are
  ``[B, C, 9]`` with C = 1 (gray) or 3 (RGB).
* Shading is irradiance: a unit directional light along ``d`` projected with
  :func:`sh_from_directions` gives shading close to ``max(0, n . d)``.
"""

from __future__ import annotations

import torch

# Eq. 5 of the paper (Ramamoorthi & Hanrahan 2001): the only place these constants live.
C1, C2, C3, C4, C5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708
SH_NAMES = ("L1", "L2", "L3", "L4", "L5", "L6", "L7", "L8", "L9")
SH_ORDER_OF = (0, 1, 1, 1, 2, 2, 2, 2, 2)  # SH band of each coefficient
# Real SH basis values Y_lm(d) in the same order, used to project a light onto L1..L9.
_Y00, _Y1, _Y2, _Y20, _Y22 = 0.282095, 0.488603, 1.092548, 0.315392, 0.546274


def sh_basis(normal: torch.Tensor, dim: int = 1) -> torch.Tensor:
    """dS/dL_k for k = 1..9 (supplement A): shading = sum_k basis_k * L_k.

    ``normal`` holds x, y, z along ``dim``; the result holds the 9 basis values there.
    """
    nx, ny, nz = normal.unbind(dim)
    return torch.stack(
        (
            torch.full_like(nx, C4),
            2 * C2 * ny,
            2 * C2 * nz,
            2 * C2 * nx,
            2 * C1 * nx * ny,
            2 * C1 * ny * nz,
            C3 * nz * nz - C5,
            2 * C1 * nx * nz,
            C1 * (nx * nx - ny * ny),
        ),
        dim,
    )


def unit(v: torch.Tensor, dim: int = 1, eps: float = 1e-12) -> torch.Tensor:
    """Unit vectors along ``dim`` (``F.normalize`` semantics, zero stays zero), as ``v * rsqrt(sum v^2)``:
    elementwise over channel planes, many times faster on the CPU than ``F.normalize``'s strided norm."""
    return v * torch.rsqrt((v * v).sum(dim, keepdim=True).clamp_min(eps * eps))


def sh_matrix(sh: torch.Tensor) -> torch.Tensor:
    """The symmetric 4x4 matrix K of Eq. 5, ``[..., 9] -> [..., 4, 4]``."""
    L1, L2, L3, L4, L5, L6, L7, L8, L9 = sh.unbind(-1)
    rows = (
        (C1 * L9, C1 * L5, C1 * L8, C2 * L4),
        (C1 * L5, -C1 * L9, C1 * L6, C2 * L2),
        (C1 * L8, C1 * L6, C3 * L7, C2 * L3),
        (C2 * L4, C2 * L2, C2 * L3, C4 * L1 - C5 * L7),
    )
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def sh_shading_reference(normal: torch.Tensor, sh: torch.Tensor) -> torch.Tensor:
    """Eq. 4 written plainly, S = [n;1]^T K [n;1], differentiated by autograd (for tests)."""
    n1 = torch.cat([normal, torch.ones_like(normal[:, :1])], 1)  # [B,4,H,W]
    return torch.einsum("bihw,bcij,bjhw->bchw", n1, sh_matrix(sh), n1)


class _SHShading(torch.autograd.Function):
    """Shading layer with the supplement's analytic backward (in torch.func's form, so that ``vmap`` can batch it
    over stacked models: its ops batch as they are)."""

    generate_vmap_rule = True

    @staticmethod
    def forward(normal, sh):
        return torch.einsum("bck,bkhw->bchw", sh, sh_basis(normal, 1))  # Eq. 4

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        normal, sh = ctx.saved_tensors
        grad_normal = grad_sh = None
        if ctx.needs_input_grad[1]:  # dS/dL_k = basis_k
            grad_sh = torch.einsum("bchw,bkhw->bck", grad, sh_basis(normal, 1))
        if ctx.needs_input_grad[0]:  # supplement A: dS/dn_x = 2(c1 L9 nx + c1 L5 ny + c1 L8 nz + c2 L4), ...
            G = torch.einsum("bchw,bck->bkhw", grad, sh)  # linear in L: contract the channels first
            _, G2, G3, G4, G5, G6, G7, G8, G9 = G.unbind(1)
            nx, ny, nz = normal.unbind(1)
            grad_normal = 2 * torch.stack(
                (
                    C1 * (G9 * nx + G5 * ny + G8 * nz) + C2 * G4,
                    C1 * (G5 * nx - G9 * ny + G6 * nz) + C2 * G2,
                    C1 * (G8 * nx + G6 * ny) + C3 * G7 * nz + C2 * G3,
                ),
                1,
            )
        return grad_normal, grad_sh


def sh_shading(normal: torch.Tensor, sh: torch.Tensor) -> torch.Tensor:
    """Shading layer f_shading (Eqs. 3-5): ``normal [B,3,H,W]``, ``sh [B,C,9]`` -> ``[B,C,H,W]``."""
    if normal.dim() != 4 or normal.shape[1] != 3:
        raise ValueError(f"normal must be [B,3,H,W], got {tuple(normal.shape)}")
    if sh.dim() != 3 or sh.shape[-1] != 9 or sh.shape[0] != normal.shape[0]:
        raise ValueError(f"sh must be [B,C,9] with B={normal.shape[0]}, got {tuple(sh.shape)}")
    dtype = torch.promote_types(normal.dtype, torch.float32)  # at least float32, also under mixed precision
    with torch.autocast(normal.device.type, enabled=False):
        return _SHShading.apply(normal.to(dtype), sh.to(dtype))


def image_formation(albedo: torch.Tensor, shading: torch.Tensor) -> torch.Tensor:
    """Eq. 2: I_fg = A (.) S.  A gray shading ``[B,1,H,W]`` broadcasts over RGB albedo."""
    return albedo * shading


def composite(matte: torch.Tensor, foreground: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Eq. 6 (Sec. 3.3): I_o = M (.) I_fg + (1 - M) (.) I_bg."""
    return matte * foreground + (1 - matte) * background


def sh_from_directions(
    direction: torch.Tensor, intensity: torch.Tensor, ambient: torch.Tensor | float = 0.0
) -> torch.Tensor:
    """Project distant lights onto L1..L9 so that shading ~ ambient + sum_k I_k max(0, n . d_k).

    ``direction [..., K, 3]`` (normalised here), ``intensity [..., K, C]``,
    ``ambient`` broadcastable to ``[..., C]``.  Returns ``[..., C, 9]``.
    """
    d = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z = d.unbind(-1)
    Y = torch.stack(
        (
            torch.full_like(x, _Y00),
            _Y1 * y,
            _Y1 * z,
            _Y1 * x,
            _Y2 * x * y,
            _Y2 * y * z,
            _Y20 * (3 * z * z - 1),
            _Y2 * x * z,
            _Y22 * (x * x - y * y),
        ),
        -1,
    )  # [..., K, 9]
    sh = torch.einsum("...kc,...kj->...cj", intensity.to(Y.dtype), Y)
    ambient = torch.as_tensor(ambient, dtype=sh.dtype, device=sh.device)
    return sh + torch.nn.functional.pad((ambient / C4).unsqueeze(-1), (0, 8))


# ----------------------------------------------------------------------------- L-hat
class IllConditionedFit(ValueError):
    """Raised by :func:`fit_sh` when the lighting fit is not determined by the data."""


def _normal_equations(normal, mask, dtype):
    """A^T W A of the masked SH design, the pixel weights and the basis, in ``dtype``."""
    basis = sh_basis(normal.to(dtype), 1).flatten(2)  # [B,9,P]
    w = mask.to(dtype).flatten(1)  # [B,P]
    AtA = torch.bmm(basis * w[:, None], basis.transpose(1, 2))
    return AtA, w, basis


def design_condition(normal: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Condition number of the least-squares normal matrix A^T A of L-hat, per image ``[B]``."""
    AtA, _, _ = _normal_equations(normal, mask.reshape(normal.shape[0], 1, *normal.shape[2:]), torch.float64)
    ev = torch.linalg.eigvalsh(AtA)
    return (ev[:, -1] / ev[:, 0].clamp_min(1e-300)).to(normal.dtype)


def over_albedo(image, mask, albedo):
    """The shading a least-squares light fits where an albedo map is given: ``image / albedo``, and ``mask``
    ``[B,1,H,W]`` without the pixels where any channel's albedo is under 1e-3 (no shading can be read there)."""
    return image / albedo.clamp_min(1e-3), mask * (albedo > 1e-3).all(1, keepdim=True)


def fit_sh(
    image,
    normal,
    mask,
    albedo=None,
    *,
    min_pixels: int = 16,
    max_cond: float = 1e7,
    on_ill_conditioned: str = "regularize",
):
    """The paper's L-hat (Sec. 4.2): least-squares SH light per channel over masked pixels.

    Solves ``image ~ sh_shading(normal, L)`` with a constant albedo whose scale is absorbed
    into L (or ``image / albedo ~ shading`` when an ``albedo`` map is given; pixels with
    albedo below 1e-3 are dropped).  Shapes: ``image [B,C,H,W]``, ``normal [B,3,H,W]``,
    ``mask [B,1,H,W]`` (or ``[B,H,W]``, values in [0,1] act as weights).

    Returns ``(sh [B,C,9], residual [B,C])``: the light and the RMS residual over the mask.

    Failure modes, documented and tested:

    * fewer than ``min_pixels`` masked pixels in an image: :class:`ValueError`;
    * NaN or Inf among the masked pixels: :class:`ValueError`;
    * an ill-conditioned design (normals in a narrow cone, so A^T A has condition number
      above ``max_cond``): with ``on_ill_conditioned="regularize"`` (default) a Tikhonov
      ridge ``delta * I`` is added with the smallest ``delta`` that brings the condition
      number down to ``max_cond``; the answer is then the minimum-norm-leaning fit, finite
      and stable, but the unobserved coefficients shrink towards zero.  With
      ``"raise"`` an :class:`IllConditionedFit` names the offending images.
    """
    B, C = image.shape[:2]
    dtype = torch.float64  # float32 pixel sums made the fit depend on batch padding (cond(A^T A) ~ 1e4)
    mask = mask.reshape(B, 1, *image.shape[2:]).to(dtype)
    target = image.to(dtype)
    if albedo is not None:
        target, mask = over_albedo(target, mask, albedo.to(dtype))
    counts = (mask.flatten(1) > 0).sum(1)
    _check_counts(counts, min_pixels)
    y = target.flatten(2)  # [B,C,P]
    inside = mask.flatten(1) > 0
    if not torch.isfinite(y).all(1)[inside].all():
        raise ValueError("fit_sh: image has NaN or Inf inside the mask")
    y = torch.where(inside[:, None], y, 0.0)
    AtA, w, basis = _normal_equations(normal, mask, dtype)
    Aty = torch.bmm(basis * w[:, None], y.transpose(1, 2)).double()  # [B,9,C]
    sh = solve_normal_equations(AtA, Aty, max_cond, on_ill_conditioned)
    pred = torch.bmm(sh.to(dtype), basis)  # [B,C,P]
    residual = ((pred - y).pow(2) * w[:, None]).sum(2) / w.sum(1, keepdim=True)
    return sh.to(image.dtype), residual.sqrt().to(image.dtype)


def _check_counts(counts: torch.Tensor, min_pixels: int) -> None:
    """L-hat needs ``min_pixels`` masked pixels in every image (``counts [B]``)."""
    if (counts < min_pixels).any():
        bad = torch.nonzero(counts < min_pixels).flatten().tolist()
        raise ValueError(f"fit_sh needs at least {min_pixels} masked pixels; images {bad} have {counts[bad].tolist()}")


def fit_sh_packed(
    image: torch.Tensor,
    normal: torch.Tensor,
    mask: torch.Tensor,
    albedo: torch.Tensor | None = None,
    min_pixels: int = 16,
    chunk: int = 128,
) -> torch.Tensor:
    """:func:`fit_sh` on the masked pixels only: the same least squares (a constant albedo, or the
    image over ``albedo`` by the same rule, :func:`over_albedo`), as its sums over pixels need
    nothing else.

    Each image's masked pixels are packed into pieces of ``chunk`` (the last one padded with
    zero weight); one batched float64 product gives every piece's sums of products of the
    image and the :func:`eq5_planes` of its normals, and each image sums its own pieces in order,
    so an image's L-hat does not depend on its batch (float32 sums would, and the solve amplifies
    their rounding to ~1e-3 in L-hat).  The SH basis is linear in those planes (Eq. 5), basis =
    T planes, so the normal equations are T (sums) T^T and T (sums with the image)."""
    B, C = image.shape[:2]
    HW = image[0, 0].numel()
    if albedo is not None:
        image, mask = over_albedo(image, mask.reshape(B, 1, *image.shape[2:]), albedo)
    w = mask.reshape(B * HW)
    sel = (w > 0).nonzero().squeeze(1)  # [M] flat b * HW + p, sorted
    counts = torch.bincount(torch.div(sel, HW, rounding_mode="floor"), minlength=B)
    _check_counts(counts, min_pixels)
    pieces = (counts + chunk - 1) // chunk
    owner = torch.repeat_interleave(pieces)  # [n] image of each piece
    dev = image.device
    rank = (torch.arange(owner.numel(), device=dev) - (torch.cumsum(pieces, 0) - pieces).index_select(0, owner))[
        :, None
    ] * chunk
    rank = rank + torch.arange(chunk, device=dev)  # [n, chunk]: which masked pixel of its image
    valid = rank < counts.index_select(0, owner)[:, None]
    start = (torch.cumsum(counts, 0) - counts).index_select(0, owner)[:, None]
    at = sel.index_select(0, (start + rank).clamp_max_(sel.numel() - 1).view(-1)).view(-1, chunk)  # b * HW + p
    weight = w.index_select(0, at.view(-1)).view(-1, chunk).mul_(valid)
    at = (at + (owner * (2 * HW))[:, None])[:, None] + torch.arange(3, device=dev)[
        :, None
    ] * HW  # [n, 3, chunk]: b * 3HW + c * HW + p

    def packed(x):  # x [B, 3, H, W] at the packed pixels, 0 on the padding -> [n, 3, chunk]
        return x.reshape(-1).index_select(0, at.view(-1)).view(at.shape).mul_(valid[:, None])

    y = packed(image)
    if not torch.isfinite(y).all():
        raise ValueError("fit_sh: image has NaN or Inf inside the mask")
    X = eq5_planes(packed(normal), valid, extra=C, dtype=torch.float64)  # [n, 10 + C, chunk]
    X[:, 10:].copy_(y)
    soft = not torch.equal(weight, valid.to(weight.dtype))  # a binary mask: X's rows already carry it
    G = torch.bmm(X[:, :10] * weight.double()[:, None] if soft else X[:, :10], X.transpose(1, 2))  # [n, 10, 10 + C]
    G = torch.zeros(B, 10, 10 + C, dtype=torch.float64, device=dev).index_add_(0, owner, G)
    T = eq5_coefficients(torch.eye(9, dtype=torch.float64, device=dev))  # [9, 10]: basis = T planes
    return solve_normal_equations(T @ G[:, :10, :10] @ T.t(), T @ G[:, :10, 10:]).float()


_QUADRATIC = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the products n_i n_j (i <= j) of Eq. 5


def eq5_planes(normal: torch.Tensor, one: torch.Tensor, extra: int = 0, dtype=None) -> torch.Tensor:
    """The 10 distinct entries of [n;1][n;1]^T (Eq. 5) as planes ``[B, 10 + extra, P]`` from ``normal [B, 3, P]``:
    n_x, n_y, n_z, ``one [B, P]`` (the constant: a binary mask, with normals 0 off it), then n_i n_j
    in ``_QUADRATIC`` order; ``extra`` planes are left for the caller."""
    B, _, P = normal.shape
    planes = torch.empty(B, 10 + extra, P, dtype=dtype or normal.dtype, device=normal.device)
    n = planes[:, :3]
    n.copy_(normal)
    planes[:, 3].copy_(one)
    for k, (i, j) in enumerate(_QUADRATIC):
        torch.mul(n[:, i], n[:, j], out=planes[:, 4 + k])
    return planes


def eq5_coefficients(sh: torch.Tensor) -> torch.Tensor:
    """``sh [..., 9]`` -> ``[..., 10]``: the shading is these coefficients dotted with :func:`eq5_planes`
    (S = [n;1]^T K [n;1], Eq. 5, with K = :func:`sh_matrix`, symmetric)."""
    K = sh_matrix(sh)
    quadratic = torch.stack([K[..., i, j] * (1 if i == j else 2) for i, j in _QUADRATIC], -1)
    return torch.cat([2 * K[..., :3, 3], K[..., 3:, 3], quadratic], -1)  # n (twice the off-diagonal), 1, n_i n_j


def solve_normal_equations(
    AtA: torch.Tensor, Aty: torch.Tensor, max_cond: float = 1e7, on_ill_conditioned: str = "regularize"
) -> torch.Tensor:
    """L-hat from the normal equations of :func:`fit_sh`: ``AtA [B,9,9]``, ``Aty [B,9,C]`` -> ``sh [B,C,9]``
    (float64), with the ridge (or :class:`IllConditionedFit`) that :func:`fit_sh` documents."""
    ev, V = torch.linalg.eigh(AtA.double())
    cond = ev[:, -1] / ev[:, 0].clamp_min(1e-300)
    ill = cond > max_cond
    if ill.any() and on_ill_conditioned == "raise":
        raise IllConditionedFit(
            f"fit_sh: design condition numbers {cond[ill].tolist()} exceed {max_cond:g} "
            f"for images {torch.nonzero(ill).flatten().tolist()} (normals span too narrow a cone)"
        )
    delta = torch.where(ill, ev[:, -1] / max_cond - ev[:, 0], torch.zeros_like(cond)).clamp_min(0)
    inv = 1.0 / (ev + delta[:, None]).clamp_min(1e-300)
    return torch.einsum("bkj,bj,blj,blc->bck", V, inv, V, Aty.double())  # (A^T A + delta I)^-1 A^T y


def sample_sphere(n: int, generator: torch.Generator | None = None, dtype=torch.float64) -> torch.Tensor:
    """``n`` unit vectors uniform on the sphere, ``[n, 3]`` (tests and SH projections)."""
    v = torch.randn(n, 3, generator=generator, dtype=dtype)
    return v / v.norm(dim=1, keepdim=True)


def rotate_sh(sh: torch.Tensor, R: torch.Tensor, n_samples: int = 512) -> torch.Tensor:
    """The light ``sh`` turned by rotation ``R`` (``[3,3]``), by projecting the rotated shading.

    Order-2 irradiance is closed under rotation, so the least-squares projection of
    ``S(R^T m, L)`` over sphere samples ``m`` is exact up to float error.
    """
    m = sample_sphere(n_samples, torch.Generator().manual_seed(0), torch.float64)
    m = m.T.reshape(1, 3, n_samples, 1)
    shading = sh_shading(
        (R.double().T @ m.reshape(3, -1)).reshape(1, 3, n_samples, 1).expand(sh.shape[0], -1, -1, -1), sh.double()
    )
    fitted, _ = fit_sh(shading, m.expand(sh.shape[0], -1, -1, -1), torch.ones(sh.shape[0], 1, n_samples, 1))
    return fitted.to(sh.dtype)


__all__ = [
    "C1",
    "C2",
    "C3",
    "C4",
    "C5",
    "SH_NAMES",
    "SH_ORDER_OF",
    "unit",
    "sh_basis",
    "sh_matrix",
    "sh_shading",
    "sh_shading_reference",
    "image_formation",
    "composite",
    "sh_from_directions",
    "fit_sh",
    "fit_sh_packed",
    "eq5_planes",
    "eq5_coefficients",
    "design_condition",
    "IllConditionedFit",
    "solve_normal_equations",
    "sample_sphere",
    "rotate_sh",
]


SHADING_EPS = 0.05  # shading below this (about 5% of a frontal unit light) is "small"


def check_finite(name: str, x: torch.Tensor) -> None:
    if not torch.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or Inf")


def detailed_albedo(
    image: torch.Tensor, shading: torch.Tensor, fallback: torch.Tensor | None = None, eps: float = SHADING_EPS
) -> torch.Tensor:
    """``A = I / S`` (Eq. 2) where ``S >= eps``; ``fallback`` elsewhere.

    ``image [B,3,H,W]``, ``shading [B,1 or 3,H,W]``.  Without a ``fallback`` the small-shading
    pixels get the mean detailed albedo of the well-lit pixels of the same image and channel
    (0 when there are none).  Always finite for finite inputs.
    """
    check_finite("image", image)
    check_finite("shading", shading)
    shading = shading.expand_as(image)
    ok = shading >= eps
    A = image / torch.where(ok, shading, torch.ones_like(shading))
    if fallback is None:
        n = ok.flatten(2).sum(2).clamp_min(1)
        fallback = (torch.where(ok, A, 0).flatten(2).sum(2) / n)[..., None, None].expand_as(A)
    else:
        check_finite("fallback albedo", fallback)
        fallback = fallback.expand_as(A)
    return torch.where(ok, A, fallback)

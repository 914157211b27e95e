"""The rendering layers against the paper's formulas, closed forms and invariances."""

import math

import pytest
import torch

from disent.render import (
    C1,
    C2,
    C3,
    C4,
    C5,
    IllConditionedFit,
    composite,
    design_condition,
    fit_sh,
    image_formation,
    rotate_sh,
    sample_sphere,
    sh_basis,
    sh_from_directions,
    sh_shading,
    sh_shading_reference,
)


def random_normals(B, H, W, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(B, 3, H, W, generator=g, dtype=dtype), dim=1)


def hemisphere_normals(B, H, W, dtype=torch.float64, seed=0):
    n = random_normals(B, H, W, dtype, seed)
    return torch.cat([n[:, :2], n[:, 2:].abs()], 1)


@pytest.mark.parametrize("C", [1, 3])
def test_custom_backward_gradcheck(C):
    normal = random_normals(2, 3, 4).requires_grad_()
    sh = torch.randn(2, C, 9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(sh_shading, (normal, sh))


def test_custom_backward_matches_plain_formula():
    normal = random_normals(3, 5, 5).requires_grad_()
    sh = torch.randn(3, 3, 9, dtype=torch.float64, requires_grad=True)
    w = torch.randn(3, 3, 5, 5, dtype=torch.float64)
    s1 = sh_shading(normal, sh)
    g1 = torch.autograd.grad((s1 * w).sum(), (normal, sh))
    s2 = sh_shading_reference(normal, sh)
    g2 = torch.autograd.grad((s2 * w).sum(), (normal, sh))
    torch.testing.assert_close(s1, s2, rtol=0, atol=1e-12)
    for a, b in zip(g1, g2):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


def test_float32_matches_float64():
    n64 = random_normals(2, 8, 8)
    sh64 = torch.randn(2, 3, 9, dtype=torch.float64)
    s32 = sh_shading(n64.float(), sh64.float())
    assert s32.dtype == torch.float32
    torch.testing.assert_close(s32.double(), sh_shading(n64, sh64), rtol=1e-5, atol=1e-5)


def test_ambient_light_gives_constant_shading():
    sh = torch.zeros(1, 1, 9, dtype=torch.float64)
    sh[..., 0] = 0.7
    s = sh_shading(random_normals(1, 6, 6), sh)
    torch.testing.assert_close(s, torch.full_like(s, C4 * 0.7))


@pytest.mark.parametrize("k,axis", [(1, 1), (2, 2), (3, 0)])  # L2 ~ y, L3 ~ z, L4 ~ x
def test_first_order_coefficients_are_linear(k, axis):
    n = random_normals(1, 6, 6)
    sh = torch.zeros(1, 1, 9, dtype=torch.float64)
    sh[..., k] = 1.3
    torch.testing.assert_close(sh_shading(n, sh)[:, 0], 2 * C2 * 1.3 * n[:, axis])


def test_second_order_terms_match_eq5():
    n = random_normals(1, 4, 4)
    nx, ny, nz = n[0]
    expected = {
        4: 2 * C1 * nx * ny,
        5: 2 * C1 * ny * nz,
        6: C3 * nz**2 - C5,
        7: 2 * C1 * nx * nz,
        8: C1 * (nx**2 - ny**2),
    }
    for k, e in expected.items():
        sh = torch.zeros(1, 1, 9, dtype=torch.float64)
        sh[..., k] = 1.0
        torch.testing.assert_close(sh_shading(n, sh)[0, 0], e)


def test_basis_is_gradient_of_shading_wrt_light():
    n = random_normals(1, 3, 3)
    sh = torch.randn(1, 1, 9, dtype=torch.float64, requires_grad=True)
    sh_shading(n, sh).sum().backward()
    torch.testing.assert_close(sh.grad[0, 0], sh_basis(n, 1).sum((2, 3))[0])


def random_rotation(seed):
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    return q if torch.det(q) > 0 else -q


@pytest.mark.parametrize("seed, mirror", [(0, False), (1, False), (2, False), (3, True)])
def test_rotation_invariance(seed, mirror):
    """Rotating (or mirroring) normals and light together leaves shading unchanged: order-2 SH cannot pin the
    normals' frame (what ``disent.eval.metrics.aligned_normal_error`` forgives)."""
    R = random_rotation(seed)
    if mirror:
        R = R @ torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
    n = random_normals(2, 5, 5, seed=seed + 10)
    sh = torch.randn(2, 3, 9, dtype=torch.float64)
    n_rot = torch.einsum("ij,bjhw->bihw", R, n)
    torch.testing.assert_close(sh_shading(n_rot, rotate_sh(sh, R)), sh_shading(n, sh), rtol=1e-9, atol=1e-9)
    assert not torch.allclose(sh_shading(n_rot, sh), sh_shading(n, sh), atol=1e-3)  # the check can fail


def test_directional_light_is_order2_clamped_cosine():
    """A unit light along d gives the order-2 Legendre truncation of max(0, t), t = n.d:
    1/4 + t/2 + (5/16) P2(t) (Ramamoorthi & Hanrahan 2001), exactly."""
    d = torch.tensor([[0.3, 0.5, 0.8]], dtype=torch.float64)
    sh = sh_from_directions(d[None], torch.full((1, 1, 1), 2.0, dtype=torch.float64))  # intensity 2
    n = sample_sphere(4000, torch.Generator().manual_seed(0)).T.reshape(1, 3, 4000, 1)
    t = n[0, :, :, 0].T @ (d[0] / d[0].norm())
    truncated = 0.25 + 0.5 * t + 5 / 16 * (3 * t**2 - 1) / 2
    torch.testing.assert_close(sh_shading(n, sh)[0, 0, :, 0], 2 * truncated, rtol=1e-5, atol=1e-5)
    assert (truncated - t.clamp_min(0)).abs().max() < 0.13  # and it is close to the clamped cosine
    amb = sh_from_directions(d[None], torch.zeros(1, 1, 1, dtype=torch.float64), ambient=0.4)
    torch.testing.assert_close(sh_shading(n, amb), torch.full_like(sh_shading(n, amb), 0.4))


def test_fit_sh_recovers_light_exactly():
    n = hemisphere_normals(4, 16, 16)
    sh = torch.randn(4, 3, 9, dtype=torch.float64)
    mask = torch.ones(4, 1, 16, 16, dtype=torch.float64)
    fit, res = fit_sh(sh_shading(n, sh), n, mask)
    torch.testing.assert_close(fit, sh, rtol=1e-9, atol=1e-9)
    assert res.max() < 1e-10


def test_fit_sh_with_albedo_and_float32():
    g = torch.Generator().manual_seed(0)
    n = hemisphere_normals(2, 16, 16, dtype=torch.float32)
    sh = torch.randn(2, 3, 9, generator=g)
    albedo = 0.2 + 0.6 * torch.rand(2, 3, 16, 16, generator=g)
    fit, _ = fit_sh(image_formation(albedo, sh_shading(n, sh)), n, torch.ones(2, 1, 16, 16), albedo=albedo)
    torch.testing.assert_close(fit, sh, rtol=1e-5, atol=1e-5)  # float32 input rounding only (sums are float64)


def test_fit_sh_ignores_pixels_outside_mask():
    n = hemisphere_normals(1, 16, 16)
    sh = torch.randn(1, 1, 9, dtype=torch.float64)
    img = sh_shading(n, sh)
    mask = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    mask[..., 2:14, 2:14] = 1
    img = torch.where(mask > 0, img, torch.full_like(img, float("nan")))  # garbage outside is ignored
    fit, _ = fit_sh(img, n, mask)
    torch.testing.assert_close(fit, sh, rtol=1e-8, atol=1e-8)


def test_fit_sh_degrades_smoothly_with_noise():
    n = hemisphere_normals(8, 32, 32)
    sh = torch.randn(8, 1, 9, dtype=torch.float64)
    clean = sh_shading(n, sh)
    mask = torch.ones(8, 1, 32, 32, dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    noise = torch.randn(clean.shape, generator=g, dtype=torch.float64)
    errors = []
    for sigma in [1e-4, 1e-3, 1e-2, 1e-1]:
        fit, res = fit_sh(clean + sigma * noise, n, mask)
        errors.append((fit - sh).norm(dim=-1).mean().item())
        assert abs(res.mean().item() - sigma) < 0.1 * sigma  # residual RMS tracks the noise level
    ratios = [b / a for a, b in zip(errors, errors[1:])]
    assert all(5 < r < 20 for r in ratios), ratios  # error linear in noise: x10 per decade


def test_fit_sh_too_few_pixels_raises():
    n = hemisphere_normals(2, 8, 8)
    mask = torch.zeros(2, 1, 8, 8, dtype=torch.float64)
    mask[0] = 1
    mask[1, :, 0, :5] = 1
    with pytest.raises(ValueError, match=r"images \[1\] have \[5\]"):
        fit_sh(torch.rand(2, 3, 8, 8, dtype=torch.float64), n, mask)


def test_fit_sh_narrow_cone_is_regularized_or_raises():
    """Normals within ~2 degrees of +z: the design is nearly rank 3."""
    g = torch.Generator().manual_seed(0)
    n = torch.cat(
        [
            0.03 * torch.randn(1, 2, 16, 16, generator=g, dtype=torch.float64),
            torch.ones(1, 1, 16, 16, dtype=torch.float64),
        ],
        1,
    )
    n = torch.nn.functional.normalize(n, dim=1)
    mask = torch.ones(1, 1, 16, 16, dtype=torch.float64)
    assert design_condition(n, mask).item() > 1e7
    sh = torch.randn(1, 3, 9, dtype=torch.float64)
    img = sh_shading(n, sh) + 1e-3 * torch.randn(1, 3, 16, 16, generator=g, dtype=torch.float64)
    with pytest.raises(IllConditionedFit, match="narrow"):
        fit_sh(img, n, mask, on_ill_conditioned="raise")
    fit, res = fit_sh(img, n, mask)
    assert torch.isfinite(fit).all()
    assert fit.norm() < 10 * sh.norm()  # bounded, not an exploding garbage fit
    assert res.max() < 5e-3  # still explains the pixels it saw
    fit_plain, _ = fit_sh(img, n, mask, max_cond=math.inf)
    assert fit_plain.norm() > fit.norm()  # without the ridge the unobserved directions blow up


def test_fit_sh_rejects_nan_inside_mask():
    n = hemisphere_normals(1, 8, 8)
    img = torch.rand(1, 3, 8, 8, dtype=torch.float64)
    img[0, 1, 3, 3] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        fit_sh(img, n, torch.ones(1, 1, 8, 8, dtype=torch.float64))


def test_well_conditioned_design_has_small_condition_number():
    n = hemisphere_normals(1, 32, 32)
    assert design_condition(n, torch.ones(1, 1, 32, 32)).item() < 1e4  # SH basis scales differ: ~600


def test_formation_and_composite_identities():
    g = torch.Generator().manual_seed(0)
    A, S = torch.rand(2, 3, 4, 4, generator=g), torch.rand(2, 1, 4, 4, generator=g)
    fg, bg = torch.rand(2, 3, 4, 4, generator=g), torch.rand(2, 3, 4, 4, generator=g)
    torch.testing.assert_close(image_formation(A, S), A * S.expand(-1, 3, -1, -1))
    torch.testing.assert_close(composite(torch.ones(2, 1, 4, 4), fg, bg), fg)
    torch.testing.assert_close(composite(torch.zeros(2, 1, 4, 4), fg, bg), bg)
    m = torch.full((2, 1, 4, 4), 0.25)
    torch.testing.assert_close(composite(m, fg, bg), 0.25 * fg + 0.75 * bg)


def test_shapes_are_validated():
    with pytest.raises(ValueError, match=r"\[B,3,H,W\]"):
        sh_shading(torch.zeros(1, 2, 4, 4), torch.zeros(1, 3, 9))
    with pytest.raises(ValueError, match=r"\[B,C,9\]"):
        sh_shading(torch.zeros(1, 3, 4, 4), torch.zeros(1, 3, 4))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    n = random_normals(2, 8, 8, torch.float32)
    sh = torch.randn(2, 3, 9)
    torch.testing.assert_close(sh_shading(n.cuda(), sh.cuda()).cpu(), sh_shading(n, sh), rtol=1e-5, atol=1e-5)

"""Closed-form checks of disent.eval.metrics."""

import math

import pytest
import torch

from disent.eval import angular_error_deg, normal_angular_error, reconstruction_metrics, scale_invariant_mse, sh_error


def _rot_x(deg):
    a = math.radians(deg)
    return torch.tensor([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]], dtype=torch.float64)


def _normals(B=2, H=8, W=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = torch.randn(B, 3, H, W, generator=g, dtype=torch.float64)
    return n / n.norm(dim=1, keepdim=True)


@pytest.mark.parametrize("deg", [0.0, 10.0, 37.5, 90.0, 180.0])
def test_rotation_gives_its_angle(deg):
    # rotating about x turns a normal in the y-z plane by exactly deg
    n = torch.zeros(1, 3, 4, 5, dtype=torch.float64)
    n[:, 2] = 1.0
    r = torch.einsum("ij,bjhw->bihw", _rot_x(deg), n)
    assert torch.allclose(angular_error_deg(r, n), torch.full((1, 4, 5), deg, dtype=torch.float64), atol=1e-5)


def test_angle_ignores_length_and_is_symmetric():
    a, b = _normals(seed=1), _normals(seed=2)
    e = angular_error_deg(a, b)
    assert torch.allclose(e, angular_error_deg(3.0 * a, 0.5 * b))
    assert torch.allclose(e, angular_error_deg(b, a))
    assert torch.allclose(angular_error_deg(-a, b), 180.0 - e, atol=1e-6)


def test_normal_stats_on_known_mix():
    # half the masked pixels turned by 10 deg, a quarter by 22, a quarter by 40; unmasked pixels by 90
    n = torch.zeros(1, 3, 4, 4, dtype=torch.float64)
    n[:, 2] = 1
    degs = torch.tensor([10.0] * 6 + [22.0] * 3 + [40.0] * 3 + [90.0] * 4, dtype=torch.float64).reshape(4, 4)
    a = torch.deg2rad(degs)
    pred = torch.stack([torch.zeros_like(a), torch.sin(a), torch.cos(a)])[None]
    mask = (degs < 90).double()[None, None]
    s = normal_angular_error(pred, n, mask)
    assert s["mean"] == pytest.approx((6 * 10 + 3 * 22 + 3 * 40) / 12, abs=1e-5)
    assert s["median"] == pytest.approx(10.0, abs=1e-5)  # torch's lower median of 12 values
    assert s["under_20"] == pytest.approx(0.5)
    assert s["under_25"] == pytest.approx(0.75)
    assert s["under_30"] == pytest.approx(0.75)


def test_psnr_of_known_mse():
    t = torch.full((2, 3, 16, 16), 0.5)
    p = t + 0.1 * torch.where(torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0)) > 0.5, 1.0, -1.0)
    r = reconstruction_metrics(p, t)
    assert r["mse"] == pytest.approx(0.01, rel=1e-5)
    assert r["psnr"] == pytest.approx(20.0, abs=1e-4)  # 10 log10(1 / 0.01)
    same = reconstruction_metrics(t, t)
    assert same["mse"] == 0 and math.isinf(same["psnr"]) and same["ssim"] == pytest.approx(1.0)


def test_masked_reconstruction_ignores_outside():
    g = torch.Generator().manual_seed(3)
    t = torch.rand(1, 3, 16, 16, generator=g)
    p = t.clone()
    p[..., :, 8:] = torch.rand(1, 3, 16, 8, generator=g)  # ruin the right half
    mask = torch.zeros(1, 1, 16, 16)
    mask[..., :, :8] = 1
    r = reconstruction_metrics(p, t, mask)
    assert r["mse"] == 0 and math.isinf(r["psnr"])
    full = reconstruction_metrics(p, t)
    assert full["mse"] > 0 and full["ssim"] < 1
    # SSIM windows straddling the boundary see the ruined half, so masked SSIM is < 1 but above the full one
    assert full["ssim"] < r["ssim"] < 1


def test_scaled_albedo_has_zero_si_mse():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 8, 8, generator=g, dtype=torch.float64)
    scale = torch.tensor([0.3, 2.0, 5.0], dtype=torch.float64).reshape(1, 3, 1, 1)  # per-channel scale
    mask = torch.ones(2, 1, 8, 8)
    assert scale_invariant_mse(a * scale, a, mask) == pytest.approx(0.0, abs=1e-20)
    # a non-scale change is not forgiven, and matches the closed form for a constant prediction
    c = torch.ones_like(a)
    s = a.sum((2, 3), keepdim=True) / 64  # optimal scale of a constant 1 is the mean
    expected = ((s - a) ** 2).mean((1, 2, 3))
    assert torch.allclose(scale_invariant_mse(c, a, mask, reduction="none"), expected)


def test_sh_error_alignment():
    g = torch.Generator().manual_seed(0)
    L = torch.randn(4, 3, 9, generator=g, dtype=torch.float64)
    assert sh_error(2.5 * L, L) == pytest.approx(0.0, abs=1e-20)
    # the per-coefficient shares sum to the error; a wrong DC term lands in the DC share only
    wrong = L.clone()
    wrong[:, :, 0] += 1.0
    shares = sh_error(wrong, L, reduction="coefficients")
    assert len(shares) == 9 and sum(shares) == pytest.approx(sh_error(wrong, L))
    assert shares[0] > 10 * max(shares[1:])
    # per-channel scales are forgiven only with per_channel=True
    Lc = L * torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64).reshape(1, 3, 1)
    assert sh_error(Lc, L, per_channel=True) == pytest.approx(0.0, abs=1e-20)
    assert sh_error(Lc, L) > 1e-3
    # zero prediction: scale 0, relative error 1; a prediction orthogonal to the truth also scores 1
    assert sh_error(torch.zeros_like(L), L) == pytest.approx(1.0)
    e = torch.zeros(1, 3, 9, dtype=torch.float64)
    e[0, 0, 0], L1 = 1.0, torch.zeros(1, 3, 9, dtype=torch.float64)
    L1[0, 1, 4] = 2.0
    assert sh_error(e, L1) == pytest.approx(1.0)
    # a known residual: pred = truth + orthogonal part; optimal scale 1/(1+|o|^2/|t|^2) closed form
    t = torch.zeros(1, 1, 9, dtype=torch.float64)
    t[0, 0, 0] = 1.0
    p = t.clone()
    p[0, 0, 1] = 1.0  # s = 1/2, residual (-1/2, 1/2): squared norm 1/2
    assert sh_error(p, t) == pytest.approx(0.5)


def test_bad_input_is_rejected():
    n = _normals()
    with pytest.raises(ValueError):
        angular_error_deg(n, n[:, :2])
    with pytest.raises(ValueError):
        normal_angular_error(n, n, torch.zeros(2, 1, 8, 8))
    with pytest.raises(ValueError):
        reconstruction_metrics(n, n, torch.ones(2, 1, 4, 4))
    with pytest.raises(ValueError):
        sh_error(torch.zeros(1, 3, 4), torch.zeros(1, 3, 4))


def test_scale_invariant_mse_global_scale_does_not_forgive_per_image_colour():
    """per_image=False allows one scale per channel for the whole batch: a per-channel gain common to all
    images is forgiven, a different colour per image (skin tone left to the light) is not."""
    g = torch.Generator().manual_seed(0)
    target = torch.rand(4, 3, 8, 8, generator=g) + 0.1
    mask = torch.ones(4, 1, 8, 8)
    common = target * torch.tensor([0.5, 2.0, 3.0])[None, :, None, None]
    per_image = target * (torch.rand(4, 3, 1, 1, generator=g) + 0.5)
    assert scale_invariant_mse(common, target, mask, per_image=False) < 1e-12  # float32 inputs: rounding only
    assert scale_invariant_mse(per_image, target, mask) < 1e-12
    assert scale_invariant_mse(per_image, target, mask, per_image=False) > 1e-3


def test_scale_invariant_mse_one_scale_for_rgb_does_not_forgive_a_colourless_albedo():
    """per_channel=False shares one scale among the channels: a gray-scaled copy of the target is forgiven, the
    degenerate split without BWS (the albedo whitened, the skin's colour left to the shading) is not, though a
    scale per channel forgives it exactly; and the shading that takes the colour is not forgiven either."""
    g = torch.Generator().manual_seed(0)
    albedo = (
        torch.rand(4, 3, 8, 8, generator=g, dtype=torch.float64) * 0.3
        + torch.tensor([0.8, 0.5, 0.4])[None, :, None, None]
    )  # skin-coloured
    shading = torch.rand(4, 1, 8, 8, generator=g, dtype=torch.float64) + 0.5  # white
    mask = torch.ones(4, 1, 8, 8)
    colour = albedo.mean((2, 3), keepdim=True)  # each face's skin colour
    whitened, tinted = albedo / colour, shading * colour  # the same image: whitened * tinted == albedo * shading
    assert torch.allclose(whitened * tinted, albedo * shading)
    gray_scaled = albedo * torch.tensor([0.5, 2.0, 3.0, 0.7], dtype=torch.float64)[:, None, None, None]
    assert scale_invariant_mse(gray_scaled, albedo, mask, per_channel=False) < 1e-20
    assert scale_invariant_mse(whitened, albedo, mask) < 1e-20
    assert scale_invariant_mse(whitened, albedo, mask, per_channel=False) > 1e-2
    assert scale_invariant_mse(tinted, shading.expand(-1, 3, -1, -1), mask, per_channel=False) > 1e-2


def test_masked_blur_keeps_constants_and_removes_the_finest_pattern():
    """Inside any mask a constant is its own blur (the blur is normalised by the blurred mask), and a one-pixel
    checkerboard is all detail: a Gaussian of sigma 2 px passes ~exp(-pi^2 sigma^2 / 2) of it per axis (its
    3-sigma truncation lets ~1e-3 per axis through)."""
    from disent.eval.metrics import masked_blur

    mask = torch.zeros(1, 1, 16, 16, dtype=torch.float64)
    mask[..., 3:12, 5:14] = 1
    const = torch.full((1, 2, 16, 16), 0.7, dtype=torch.float64)
    inside = mask.bool().expand_as(const)
    assert torch.allclose(masked_blur(const, mask, 2.0)[inside], const[inside])
    y, x = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="ij")
    checker = ((-1.0) ** (x + y)).double()[None, None]
    full = torch.ones(1, 1, 32, 32, dtype=torch.float64)
    centre = masked_blur(checker, full, 2.0)[..., 8:24, 8:24]  # away from the border, where the blur is whole
    assert centre.abs().max() < 1e-5


def test_scale_invariant_mse_bands_add_up_to_the_total():
    """coarse + fine + 2 <coarse, fine> is scale_invariant_mse; a smooth error lies in the coarse band, a
    checkerboard error in the fine band."""
    from disent.eval.metrics import masked_blur, scale_invariant_mse_bands

    g = torch.Generator().manual_seed(0)
    target = torch.rand(3, 3, 24, 24, generator=g, dtype=torch.float64) + 0.5
    mask = torch.zeros(3, 1, 24, 24)
    mask[..., 4:20, 2:22] = 1
    pred = target + 0.3 * torch.rand(3, 3, 24, 24, generator=g, dtype=torch.float64)
    bands = scale_invariant_mse_bands(pred, target, mask)
    w = mask.double()
    e = pred * (w * pred * target).sum((2, 3), keepdim=True) / (w * pred * pred).sum((2, 3), keepdim=True) - target
    c = masked_blur(e, w, 2.0)
    cross = ((w * c * (e - c)).sum((1, 2, 3)) / (w.sum((1, 2, 3)) * 3)).mean().item()
    assert bands["coarse"] + bands["fine"] + 2 * cross == pytest.approx(scale_invariant_mse(pred, target, mask))
    y, x = torch.meshgrid(torch.arange(24), torch.arange(24), indexing="ij")
    ramp = (1 + 0.02 * x + 0.01 * y).double()[None, None].expand(3, 3, -1, -1)  # smooth, not a rescaling
    checker = (1 + 0.1 * (-1.0) ** (x + y)).double()[None, None].expand(3, 3, -1, -1)
    smooth, fine = (scale_invariant_mse_bands(target * f, target, mask) for f in (ramp, checker))
    assert smooth["coarse"] > 5 * smooth["fine"] and fine["fine"] > 5 * fine["coarse"]


def test_normal_spread_is_zero_for_a_flat_map_and_blind_to_a_global_rotation():
    from disent.eval.metrics import normal_spread

    theta = math.radians(30.0)
    pair = torch.tensor([[math.sin(theta), 0.0, math.cos(theta)], [-math.sin(theta), 0.0, math.cos(theta)]])
    normal = pair.T.reshape(1, 3, 1, 2)  # two pixels, 30 deg either side of +z: each is 30 deg from their mean
    mask = torch.ones(1, 1, 1, 2)
    assert normal_spread(normal, mask) == pytest.approx(30.0, abs=1e-6)
    flat = torch.tensor([0.3, -0.2, 0.9]).view(1, 3, 1, 1).expand(2, 3, 5, 5)
    assert normal_spread(flat, torch.ones(2, 1, 5, 5)) == pytest.approx(0.0, abs=1e-4)
    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(2, 3, 6, 6, generator=g), dim=1)
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    rotated = torch.einsum("ij,bjhw->bihw", q.float(), n)
    m = (torch.rand(2, 1, 6, 6, generator=g) > 0.3).float()
    assert normal_spread(rotated, m) == pytest.approx(normal_spread(n, m), abs=1e-4)
    with pytest.raises(ValueError, match="no pixel"):
        normal_spread(n, torch.zeros(2, 1, 6, 6))


@pytest.mark.parametrize("deg", [0.0, 25.0, 70.0, 150.0])
def test_aligned_normal_error_forgives_one_rotation_or_mirror_of_the_frame_and_names_it(deg):
    from disent.eval.metrics import aligned_normal_error

    n, mask = frontal_normals()
    rotated = torch.einsum("ij,bjhw->bihw", _rot_x(deg), n)
    got = aligned_normal_error(rotated, n, mask)
    assert got["mean"] == pytest.approx(0.0, abs=1e-4)
    assert got["angle"] == pytest.approx(deg, abs=1e-4) and got["det"] == 1.0
    assert normal_angular_error(rotated, n, mask)["mean"] > 0.5 * deg  # the plain error sees the rotation
    mirrored = rotated * torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64).view(1, 3, 1, 1)  # x -> -x
    got = aligned_normal_error(mirrored, n, mask)
    assert got["mean"] == pytest.approx(0.0, abs=1e-4) and got["det"] == -1.0
    # noise that no one frame map explains stays: its aligned error matches its plain error (the best map is ~I)
    noisy = torch.nn.functional.normalize(n + 0.2 * _normals(2, 24, 24, seed=3), dim=1)
    plain, aligned = normal_angular_error(noisy, n, mask)["mean"], aligned_normal_error(noisy, n, mask)
    assert aligned["mean"] == pytest.approx(plain, rel=0.05)
    assert aligned["angle"] < 2.0
    with pytest.raises(ValueError, match="no pixel"):
        aligned_normal_error(n, n, torch.zeros_like(mask))


def frontal_normals(B=2, H=24):
    """Unit normals of a camera-facing cap (n_z >= ~0.5), the share of the sphere a face shows, and its mask."""
    y, x = torch.meshgrid(torch.linspace(-0.8, 0.8, H), torch.linspace(-0.8, 0.8, H), indexing="ij")
    n = torch.stack([x, y, torch.sqrt((1 - x**2 - y**2).clamp_min(0.25))])
    n = torch.nn.functional.normalize(n, dim=0).double()
    return n.expand(B, -1, -1, -1), torch.ones(B, 1, H, H)


def test_sh_error_split_adds_up_and_ignores_scale():
    """shown + hidden is the whole relative coefficient error at the shading-space scale; a prediction that is
    the truth times a per-channel factor scores 0 in both parts."""
    from disent.eval.metrics import sh_error_shown_hidden
    from disent.render import sh_basis

    normal, mask = frontal_normals()
    g = torch.Generator().manual_seed(0)
    true, pred = (torch.randn(2, 3, 9, generator=g, dtype=torch.float64) for _ in range(2))
    split = sh_error_shown_hidden(pred, true, normal, mask)
    Y = sh_basis(normal, 1).flatten(2)  # [B, 9, P]
    G = Y @ Y.transpose(1, 2) / Y.shape[-1]
    s = torch.einsum("nck,nkl,ncl->nc", pred, G, true) / torch.einsum("nck,nkl,ncl->nc", pred, G, pred)
    whole = ((s[..., None] * pred - true) ** 2).sum((1, 2)) / (true**2).sum((1, 2))
    assert split["shown"] + split["hidden"] == pytest.approx(whole.mean().item(), rel=1e-9)
    zero = sh_error_shown_hidden(true * torch.tensor([2.0, 0.5, 3.0], dtype=torch.float64)[:, None], true, normal, mask)
    assert zero["shown"] == pytest.approx(0, abs=1e-20) and zero["hidden"] == pytest.approx(0, abs=1e-20)


def test_sh_error_split_puts_an_invisible_light_in_hidden():
    """Adding to the true light the SH direction the cap's shading barely changes under (G's smallest eigenvector)
    leaves the shown error near 0 and puts the whole added energy (0.5^2 per channel over the truth's 1 per
    channel) in hidden."""
    from disent.eval.metrics import sh_error_shown_hidden
    from disent.render import sh_basis

    normal, mask = frontal_normals(B=1)
    Y = sh_basis(normal, 1).flatten(2)[0]
    values, vectors = torch.linalg.eigh(Y @ Y.T / Y.shape[-1])
    assert values[0] < 0.01 * values[-1]  # a cap hides some SH directions
    true = torch.zeros(1, 3, 9, dtype=torch.float64)
    true[0, :, 0] = 1.0  # ambient light
    split = sh_error_shown_hidden(true + 0.5 * vectors[:, 0], true, normal, mask)
    assert split["shown"] < 1e-3 * split["hidden"]
    assert split["hidden"] == pytest.approx(0.25, rel=0.05)  # the scale, read from shading, stays ~1


def test_completed_sh_keeps_what_the_face_shows_and_takes_what_it_hides_from_the_prior():
    """On a frontal cap: a light wrong only along the hidden directions comes back as the truth when the prior is the
    truth at another scale (the prior is scaled to the light over the shown directions); the shown part is the
    estimator's whatever the prior; the completion scales with the light; on normals over the whole sphere nothing
    is hidden and the light comes back unchanged."""
    from disent.eval.metrics import completed_sh, hidden_directions, sh_gram
    from disent.render import sample_sphere

    normal, mask = frontal_normals(B=2)
    gram = sh_gram(normal, mask)
    vectors, hidden = hidden_directions(gram)
    assert hidden.any() and not hidden.all()
    g = torch.Generator().manual_seed(0)
    true = torch.randn(2, 3, 9, generator=g, dtype=torch.float64)
    in_basis = lambda x: torch.einsum("nck,nkj->ncj", x, vectors)  # noqa: E731
    junk = torch.einsum("ncj,nkj->nck", torch.randn(2, 3, 9, generator=g, dtype=torch.float64) * hidden, vectors)
    wrong = true + 5 * junk  # wrong where the face cannot tell
    assert sh_error(wrong, true) > 0.5
    assert torch.allclose(completed_sh(wrong, 0.3 * true, gram), true, atol=1e-9)
    other = completed_sh(wrong, torch.randn(3, 9, generator=g, dtype=torch.float64), gram)
    assert torch.allclose(in_basis(other) * ~hidden, in_basis(wrong) * ~hidden, atol=1e-9)
    assert torch.allclose(completed_sh(2.5 * wrong, true[0], gram), 2.5 * completed_sh(wrong, true[0], gram))
    sphere = sample_sphere(4096, torch.Generator().manual_seed(1)).T.reshape(1, 3, 64, 64).float()
    whole = sh_gram(sphere.expand(2, -1, -1, -1), torch.ones(2, 1, 64, 64))
    assert not hidden_directions(whole)[1].any()
    assert torch.allclose(completed_sh(wrong, true, whole), wrong, atol=1e-9)


def test_completed_light_metrics_read_each_estimator_on_its_own_normals():
    """The network's light is completed along what its own normals hide, L-hat's along what the pseudo normals
    hide: a network light right where its normals show and wild where they hide scores ~0 once completed by the
    true light, against a raw error above 0.5; L-hat's entry is left out where the data carry no pseudo-GT."""
    from disent.eval.metrics import hidden_directions, sh_gram
    from disent.eval.scoring import completed_light_metrics

    normal, mask = frontal_normals(B=2)
    vectors, hidden = hidden_directions(sh_gram(normal, mask))
    g = torch.Generator().manual_seed(1)
    true = torch.randn(2, 3, 9, generator=g, dtype=torch.float64)
    wild = true + 5 * torch.einsum(
        "ncj,nkj->nck", torch.randn(2, 3, 9, generator=g, dtype=torch.float64) * hidden, vectors
    )
    out = {"sh": wild, "normal": normal, "matte": mask.expand(2, 1, *mask.shape[2:]).double()}
    gt = {"sh": true}
    m = completed_light_metrics(out, gt, true)  # a per-image prior: the truth itself
    assert sh_error(wild, true) > 0.5 and m["sh_error_completed"] < 1e-12 and set(m) == {"sh_error_completed"}
    pseudo = {"sh_pseudo": wild, "normal_pseudo": normal, "mask_pseudo": out["matte"]}
    assert completed_light_metrics(out, {**gt, **pseudo}, true)["pseudo_sh_error_completed"] < 1e-12


def test_pattern_corr_forgives_scale_offset_and_contrast_but_not_the_pattern():
    """Pearson's correlation per image and channel: an affine map of the truth scores 1, its negation -1, noise
    independent of it about 0; a flattened map (less contrast) that a scale-invariant MSE scores better stays at 1."""
    from disent.eval.metrics import pattern_corr

    g = torch.Generator().manual_seed(0)
    target = torch.rand(4, 3, 16, 16, generator=g) + 0.2
    mask = torch.zeros(4, 1, 16, 16)
    mask[:, :, 2:14, 3:13] = 1
    assert pattern_corr(0.3 * target + 0.5, target, mask) == pytest.approx(1.0, abs=1e-5)
    assert pattern_corr(-target, target, mask) == pytest.approx(-1.0, abs=1e-5)
    noise = torch.rand(4, 3, 16, 16, generator=g)
    assert abs(pattern_corr(noise, target, mask)) < 0.1
    flat = target.mean() + 0.5 * (target - target.mean())
    assert scale_invariant_mse(flat, target, mask) > 0 and pattern_corr(flat, target, mask) == pytest.approx(1.0, 1e-5)
    outside = target.clone()
    outside[:, :, 0] = -5  # pixels off the mask do not count
    assert pattern_corr(outside, target, mask) == pytest.approx(1.0, abs=1e-5)
    assert pattern_corr(noise, target, mask, reduction="none").shape == (4,)


def test_mask_iou_closed_forms():
    """Two half-overlapping squares: IoU 1/3; identical masks 1, disjoint 0, both empty 1; pooled over the batch, so
    a face counts by its size; soft masks are cut at the threshold; shapes must match."""
    from disent.eval.metrics import mask_iou

    a, b = torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 8, 8)
    a[..., :4, :4], b[..., 2:6, :4] = 1, 1  # 16 pixels each, 8 shared: 8 / 24
    assert mask_iou(a, b) == pytest.approx(1 / 3) and mask_iou(a, a) == 1 and mask_iou(a, 1 - a) == 0
    assert mask_iou(torch.zeros_like(a), torch.zeros_like(a)) == 1
    big = torch.ones(1, 1, 8, 8)  # identical: 64 of 64; with the first pair: (8 + 64) / (24 + 64)
    assert mask_iou(torch.cat([a, big]), torch.cat([b, big])) == pytest.approx(72 / 88)
    assert mask_iou(0.6 * a, b) == pytest.approx(1 / 3) and mask_iou(0.4 * a, b) == 0
    with pytest.raises(ValueError):
        mask_iou(a, b[..., :4])


def test_shading_contrast_is_the_slope_of_log_shading_on_the_truths():
    """1 for the true light at any scale per image and channel, 0 for a light without direction, between for a
    flatter one; each value is numpy's least-squares slope of the centred log shadings over the mask."""
    import numpy as np

    from disent.eval.metrics import shading_contrast
    from disent.render import sh_shading

    n = _normals(B=2, H=10, W=10, seed=3)
    n[:, 2] = n[:, 2].abs() + 0.5  # facing the camera, so the lights below shade every pixel above 0
    n = n / n.norm(dim=1, keepdim=True)
    mask = torch.zeros(2, 1, 10, 10)
    mask[..., 2:9, 1:8] = 1
    true = torch.zeros(2, 3, 9, dtype=torch.float64)
    true[..., 0] = 1.0
    true[..., 1:4] = torch.tensor([0.3, 0.5, -0.2], dtype=torch.float64)  # y, z, x
    flatter = true.clone()
    flatter[..., 1:4] *= 0.5
    scale = torch.tensor([[2.0, 0.5, 1.0], [3.0, 1.0, 0.2]], dtype=torch.float64)[..., None]
    assert torch.allclose(shading_contrast(true * scale, true, n, mask)["slope"], torch.ones(2, 3, dtype=torch.float64))
    dc_only = true * torch.eye(9, dtype=torch.float64)[0]
    assert torch.allclose(shading_contrast(dc_only, true, n, mask)["slope"], torch.zeros(2, 3, dtype=torch.float64))
    c = shading_contrast(flatter, true, n, mask)["slope"]
    assert ((0.2 < c) & (c < 0.9)).all()
    inside = mask[1, 0].bool().numpy()
    s, t = (sh_shading(n, light)[1, 0].log().numpy()[inside] for light in (flatter, true))
    assert c[1, 0].item() == pytest.approx(np.polyfit(t, s, 1)[0], rel=1e-9)


def test_log_shading_agreement_parts_the_slope_into_pattern_and_magnitude():
    """A shading that is the reference's to the power k, at any scale, has pattern 1 and magnitude k; with a pattern
    of its own the parts are numpy's correlation and ratio of spreads, their product is the slope, and the magnitude
    that leaves the least squared log error is the correlation (an estimate right on average is flatter)."""
    import numpy as np

    from disent.eval.metrics import log_shading_agreement

    g = torch.Generator().manual_seed(0)
    t = torch.rand(2, 3, 8, 8, generator=g, dtype=torch.float64) + 0.2
    mask = torch.zeros(2, 1, 8, 8)
    mask[..., 1:7, 2:8] = 1
    a = log_shading_agreement(3.0 * t.pow(0.6), t, mask)
    assert torch.allclose(a["corr"], torch.ones(2, 3, dtype=torch.float64))
    assert torch.allclose(a["ratio"], torch.full((2, 3), 0.6, dtype=torch.float64))
    assert torch.allclose(a["error"], torch.full((2, 3), 0.16, dtype=torch.float64))  # (1 - 0.6)^2
    assert torch.allclose(a["slope"], a["corr"] * a["ratio"])
    other = t.pow(0.8) * (0.5 * torch.rand(2, 3, 8, 8, generator=g, dtype=torch.float64)).exp()  # its own pattern
    a = log_shading_agreement(other, t, mask)
    inside = mask[0, 0].bool().numpy()
    x, y = (z[0, 1].log().numpy()[inside] for z in (other, t))
    assert a["corr"][0, 1].item() == pytest.approx(np.corrcoef(x, y)[0, 1], rel=1e-9)
    assert a["ratio"][0, 1].item() == pytest.approx(x.std() / y.std(), rel=1e-9)
    assert torch.allclose(a["slope"], a["corr"] * a["ratio"])
    assert torch.allclose(a["error"], 1 - 2 * a["corr"] * a["ratio"] + a["ratio"] ** 2)
    xc, yc = x - x.mean(), y - y.mean()
    assert a["error"][0, 1].item() == pytest.approx(((xc - yc) ** 2).sum() / (yc**2).sum(), rel=1e-9)
    ks = np.linspace(0.05, 2, 400)  # other's log contrast times k: its magnitude k * ratio
    errors = [((k * xc - yc) ** 2).sum() for k in ks]
    best = ks[int(np.argmin(errors))] * a["ratio"][0, 1].item()
    assert best == pytest.approx(a["corr"][0, 1].item(), abs=0.01)

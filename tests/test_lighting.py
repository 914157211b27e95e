"""Lighting posterior and order choice against closed forms, on simple synthetic geometry."""

import json
import math

import numpy as np
import pytest
import torch

from disent.lighting.order import candidates, select_order
from disent.lighting.posterior import (
    LogPosterior,
    TruncatedT,
    gaussian_posterior,
    integrated_time,
    prepare,
    robust_fit,
    sample_posterior,
)
from disent.lighting.texture import TextureModel
from disent.render import sh_from_directions, sh_shading
from disent.runtime import single_core


@pytest.fixture(autouse=True)
def one_core():
    """numpy's BLAS threads spin against other work on a shared machine: one core, as the code targets."""
    with single_core():
        yield


def ellipsoid(H=32, W=32, a=0.8, b=1.0):
    """Normals of the camera-facing half of an ellipsoid and its mask (a face-like shape)."""
    y, x = torch.meshgrid(
        torch.linspace(1, -1, H, dtype=torch.float64), torch.linspace(-1, 1, W, dtype=torch.float64), indexing="ij"
    )
    r2 = (x / a) ** 2 + (y / b) ** 2
    mask = (r2 < 0.95).double()
    n = torch.stack([x / a**2, y / b**2, torch.sqrt((1 - r2).clamp_min(0))], 0)
    return torch.nn.functional.normalize(n, dim=0) * mask, mask[None]


def directional_light(direction, colour=(0.8, 0.7, 0.6), ambient=0.2):
    d = torch.tensor([direction], dtype=torch.float64)
    colour = torch.tensor([colour], dtype=torch.float64)
    return sh_from_directions(d, colour, ambient=ambient * colour[0])  # [3, 9]


def render(normal, sh, noise, seed=0):
    image = sh_shading(normal[None], sh[None])[0]
    g = torch.Generator().manual_seed(seed)
    return image + noise * torch.randn(image.shape, generator=g, dtype=torch.float64)


def test_linear_gaussian_posterior_matches_closed_form():
    """Known noise, no constraint: emcee's mean and covariance are the Gaussian posterior's."""
    normal, mask = ellipsoid(20, 20)
    sigma = 0.05
    image = render(normal, directional_light([0.3, 0.5, 1.0]), sigma)
    data = prepare(image, normal, mask, gray=True)
    assert data.n_channels == 1 and 200 < data.n_pixels < 400
    post = sample_posterior(data, known_sigma=sigma, positivity=False, prior_scale=math.inf, seed=1)
    mu, cov = gaussian_posterior(data, sigma)
    cov = cov[0]
    assert post.diagnostics["converged"]
    ess = np.asarray(post.diagnostics["ess"])
    assert ess.min() > 2000
    samples = post.sh[:, 0]
    # mean: every coefficient within 4.5 Monte-Carlo standard errors
    z = (samples.mean(0) - mu[0]) / np.sqrt(np.diag(cov) / ess)
    assert np.abs(z).max() < 4.5, z
    # covariance: whitened by the closed form it is the identity within Monte-Carlo error
    W = np.linalg.inv(np.linalg.cholesky(cov))
    white = W @ np.cov(samples.T) @ W.T
    tol = 5 * math.sqrt(2 / ess.min())
    assert np.abs(white - np.eye(9)).max() < tol, np.abs(white - np.eye(9)).max()
    # the check has power: a posterior 20 % too wide (noise 1.2 sigma) fails it
    cov_wrong = gaussian_posterior(data, 1.2 * sigma)[1][0]
    Ww = np.linalg.inv(np.linalg.cholesky(cov_wrong))
    assert np.abs(Ww @ np.cov(samples.T) @ Ww.T - np.eye(9)).max() > tol


def textured_albedo(H, W, seed=0):
    g = torch.Generator().manual_seed(seed)
    return 0.3 + 0.6 * torch.rand(3, H, W, generator=g, dtype=torch.float64)


@pytest.mark.parametrize("known_albedo", [False, True])
def test_log_posterior_vectorised_matches_plain_formulas(known_albedo):
    normal, mask = ellipsoid(12, 12)
    albedo = textured_albedo(12, 12) if known_albedo else torch.ones(3, 12, 12, dtype=torch.float64)
    image = albedo * render(normal, directional_light([0, 0, 1]), 0.02)
    data = prepare(image, normal, mask, albedo if known_albedo else None)
    a = albedo.flatten(1)[:, data.index].T.numpy()  # [P, C]
    rng = np.random.default_rng(0)
    for likelihood in ("gaussian", "student_t"):
        lp = LogPosterior(data, 2, likelihood, nu=4.0, prior_scale=2.0, positivity=False)
        mode, _ = robust_fit(lp)
        theta = mode + 0.01 * rng.standard_normal((5, lp.ndim))
        got = lp(theta)
        for w in range(5):
            L, s = theta[w, :27].reshape(3, 9), math.exp(theta[w, 27])
            r = data.y - a * (data.basis @ L.T)  # Eq. 2: image = albedo * shading
            if likelihood == "gaussian":
                ll = (-0.5 * (r / s) ** 2 - math.log(s) - 0.5 * math.log(2 * math.pi)).sum()
            else:
                from scipy.stats import t as student_t

                ll = student_t.logpdf(r, df=4.0, scale=s).sum()
            want = ll - 0.5 * (L**2).sum() / 4.0
            assert got[w] == pytest.approx(want, rel=1e-10, abs=1e-8)


def test_positivity_is_a_hard_constraint():
    normal, mask = ellipsoid(16, 16)
    data = prepare(render(normal, directional_light([1.0, 0.2, 0.3], ambient=0.05), 0.03), normal, mask)
    lp = LogPosterior(data)
    theta = np.zeros((2, lp.ndim))
    theta[:, 0] = [1.0, -1.0]  # ambient only: shading C4 * L1, positive then negative
    theta[:, -1] = math.log(0.03)
    out = lp(theta)
    assert np.isfinite(out[0]) and out[1] == -np.inf
    assert (data.basis @ robust_fit(LogPosterior(data, positivity=False))[0][:27].reshape(3, 9).T).min() < 0
    post = sample_posterior(data, seed=0, max_steps=200, adapt_rounds=1)  # the free fit shades some normals negative
    shading = post.sh @ data.basis.T  # [S, C, P]
    assert shading.min() >= 0 and post.diagnostics["n_samples"] > 0
    # the truncated proposal draws inside the constraint although its centre is outside
    q = TruncatedT(*robust_fit(lp, constrained=False), feasible=lp.feasible)
    x, drawn = q.draw(64, np.random.default_rng(0))
    assert not lp.feasible(q.mean[None])[0]  # the free fit is outside; its truncation is not
    assert drawn.any() and lp.feasible(x[drawn]).all()


def test_integrated_time_matches_emcee():
    import emcee

    rng = np.random.default_rng(0)
    chain = np.zeros((400, 6, 3))
    for t in range(1, 400):  # AR(1) with phi = 0.8: tau = (1 + phi) / (1 - phi) = 9
        chain[t] = 0.8 * chain[t - 1] + rng.standard_normal((6, 3))
    tau = integrated_time(chain)
    np.testing.assert_allclose(tau, emcee.autocorr.integrated_time(chain, tol=0, quiet=True), rtol=1e-10)
    assert np.all((tau > 5) & (tau < 13))


def test_robust_likelihood_resists_highlights():
    """Bright outliers (specular-like) bias the Gaussian posterior; the Student-t one covers the truth."""
    normal, mask = ellipsoid(24, 24)
    sh = directional_light([0.4, 0.3, 1.0])
    image = render(normal, sh, 0.01)
    half = torch.nn.functional.normalize(torch.tensor([0.2, 0.15, 1.0], dtype=torch.float64), dim=0)
    spots = ((normal * half[:, None, None]).sum(0, keepdim=True) > 0.97).double()  # a highlight
    image = image + 0.6 * spots
    data = prepare(image, normal, mask, gray=True)
    truth = sh.mean(0).numpy()
    miss = {}
    for likelihood in ("gaussian", "student_t"):
        post = sample_posterior(data, likelihood=likelihood, seed=0)
        lo, hi = post.interval(0.95)
        miss[likelihood] = int(((truth < lo[0]) | (truth > hi[0])).sum())
    assert miss["student_t"] <= 1 and miss["gaussian"] >= 5, miss


def test_direction_and_shading_uncertainty():
    normal, mask = ellipsoid(24, 24)
    direction = np.array([0.5, 0.4, 0.8])
    data = prepare(render(normal, directional_light(direction.tolist()), 0.02), normal, mask)
    post = sample_posterior(data, seed=0)
    d = post.direction_summary()
    angle = math.degrees(math.acos(np.dot(d["mean_direction"], direction / np.linalg.norm(direction))))
    assert angle < 3.0
    mean, sd = post.shading_map(normal)
    assert mean.shape == sd.shape == (3, 24, 24)
    inside = mask[0].numpy() > 0.5
    truth = sh_shading(normal[None], directional_light(direction.tolist())[None])[0].numpy()
    assert np.abs(mean - truth)[:, inside].max() < 0.05
    assert (sd[:, inside] > 0).all() and sd[:, inside].max() < 0.02  # well under the noise


@pytest.mark.parametrize("true_order", [0, 1, 2])
def test_order_choice_recovers_the_lighting_order(true_order):
    normal, mask = ellipsoid(32, 32)
    rng = np.random.default_rng(true_order)
    right = 0
    for i in range(6):
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 0.3
        sh = directional_light(direction.tolist())
        if true_order == 0:
            sh[:, 1:] = 0
        if true_order == 1:  # a linear light, kept non-negative by a larger ambient
            sh[:, 4:] = 0
            sh[:, 0] *= 2
        data = prepare(render(normal, sh, 0.02, seed=i), normal, mask)
        right += select_order(data)["order"] == true_order
    assert right == 6


def test_gray_light_is_preferred_when_colour_does_not_vary():
    normal, mask = ellipsoid(32, 32)
    gray = directional_light([0.3, 0.3, 1.0])  # one colour for ambient and direct light
    coloured = gray.clone()
    coloured[:, 1:4] *= torch.tensor([[1.0], [0.3], [0.1]], dtype=torch.float64)  # a red key, white fill
    assert select_order(prepare(render(normal, gray, 0.02), normal, mask))["choice"] == "order2_gray"
    assert select_order(prepare(render(normal, coloured, 0.02), normal, mask))["choice"] == "order2_rgb"


def test_bad_input_is_refused():
    normal, mask = ellipsoid(8, 8)
    with pytest.raises(ValueError, match="masked pixels"):
        prepare(torch.rand(3, 8, 8), normal, torch.zeros(1, 8, 8))
    with pytest.raises(ValueError, match=r"\[C,H,W\]"):
        prepare(torch.rand(3, 8, 9), normal, mask)
    image = torch.rand(3, 8, 8)
    image[0, 4, 4] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        prepare(image, normal, mask)
    data = prepare(torch.rand(3, 8, 8), normal, mask)
    with pytest.raises(ValueError, match="likelihood"):
        LogPosterior(data, likelihood="cauchy")
    with pytest.raises(ValueError, match="order"):
        sample_posterior(data, order=3)


def test_known_albedo_recovers_the_light_itself():
    """With the albedo map given, L is the scene's light (not albedo * light): LS and posterior agree."""
    normal, mask = ellipsoid(24, 24)
    sh, albedo = directional_light([0.3, 0.4, 1.0]), textured_albedo(24, 24, seed=1)
    image = albedo * render(normal, sh, 0.0) + 0.01 * torch.randn(
        3, 24, 24, generator=torch.Generator().manual_seed(2), dtype=torch.float64
    )
    data = prepare(image, normal, mask, albedo)
    mu, cov = gaussian_posterior(data, 0.01)
    z = (mu - sh.numpy()) / np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    assert np.abs(z).max() < 4.5  # the truth is inside the closed-form posterior
    constant = gaussian_posterior(prepare(image, normal, mask), 0.01)[0]  # albedo ignored: biased
    assert np.abs(constant - sh.numpy()).max() > 10 * np.sqrt(np.diagonal(cov, axis1=1, axis2=2)).max()


def feature_texture(R=32):
    """A texture model of dark features in UV space: hair (top band), beard (bottom band), eyes, lips."""
    t = torch.linspace(0, 1, R, dtype=torch.float64)
    v, u = torch.meshgrid(t, t, indexing="ij")
    blob = lambda cu, cv, r: torch.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * r * r))
    maps = torch.stack(
        [
            torch.sigmoid((0.3 - v) / 0.04),
            torch.sigmoid((v - 0.75) / 0.04),
            blob(0.33, 0.42, 0.05) + blob(0.67, 0.42, 0.05),
            blob(0.5, 0.7, 0.05),
        ]
    )
    comps = maps[:, None] * torch.tensor([1.0, 0.9, 0.8], dtype=torch.float64)[:, None, None]
    norms = comps.flatten(1).norm(dim=1)
    comps = comps / norms[:, None, None, None]
    return TextureModel(np.full((3, R, R), 0.7), comps.numpy(), 0.2 * norms.numpy() ** 2 / R**2)


def test_texture_model_keeps_the_order_choice_of_a_textured_face():
    """Order-1 light on a textured albedo: the i.i.d. constant-albedo choice explains the
    texture with order-2 terms; fitting the texture model's coefficients recovers order 1."""
    H = 32
    normal, mask = ellipsoid(H, H)
    y, x = torch.meshgrid(
        torch.linspace(0, 1, H, dtype=torch.float64), torch.linspace(0, 1, H, dtype=torch.float64), indexing="ij"
    )
    uv = torch.stack([x, y]) * mask
    model = feature_texture()
    for seed in range(2):
        rng = np.random.default_rng(seed)
        beta = -np.sqrt(model.variance) * (1.5 + rng.random(4))  # darker features than the mean
        albedo = torch.nn.functional.grid_sample(
            torch.from_numpy(model.mean + np.einsum("j,jchw->chw", beta, model.components))[None],
            (2 * uv - 1).permute(1, 2, 0)[None],
            align_corners=True,
        )[0]
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 0.3
        sh = directional_light(direction.tolist())
        sh[:, 4:], sh[:, 0] = 0, 2 * sh[:, 0]  # order 1, kept non-negative by a larger ambient
        data = prepare(albedo * render(normal, sh, 0.0) + render(normal, 0 * sh, 0.02, seed), normal, mask)
        texture = (model.at_pixels(uv, data.index), model.variance)
        assert select_order(data)["order"] == 2  # the misfit the texture model removes
        assert select_order(data, texture=texture)["order"] == 1


def test_batched_texture_light_is_the_order_choice_fit_and_beats_the_constant_albedo():
    """texture_light (batched torch, loss.recon_L_target=sh_texture) gives order.score's order-2 RGB light with the
    texture model, image by image, whatever the batch (masks of different sizes pad differently); on a face whose
    albedo the texture model spans, that light lies closer to the true light than L-hat's constant albedo puts it."""
    from disent.eval.metrics import light_shading_si_mse
    from disent.lighting.order import score
    from disent.lighting.texture import texture_light
    from disent.render import fit_sh

    H = 32
    model = feature_texture()
    y, x = torch.meshgrid(
        torch.linspace(0, 1, H, dtype=torch.float64), torch.linspace(0, 1, H, dtype=torch.float64), indexing="ij"
    )
    images, normals, masks, uvs, lights = [], [], [], [], []
    for seed, (a, b) in enumerate([(0.8, 1.0), (0.6, 0.9), (0.9, 0.7)]):
        normal, mask = ellipsoid(H, H, a, b)
        uv = torch.stack([x, y]) * mask
        rng = np.random.default_rng(seed)
        beta = -np.sqrt(model.variance) * (1 + rng.random(4))
        albedo = torch.nn.functional.grid_sample(
            torch.from_numpy(model.mean + np.einsum("j,jchw->chw", beta, model.components))[None],
            (2 * uv - 1).permute(1, 2, 0)[None],
            align_corners=True,
        )[0]
        sh = directional_light([rng.normal(), rng.normal(), 1.0])
        images.append(albedo * render(normal, sh, 0.0) + render(normal, 0 * sh, 0.01, seed))
        normals.append(normal), masks.append(mask), uvs.append(uv), lights.append(sh)
    image, normal, mask, uv, true = (torch.stack(v) for v in (images, normals, masks, uvs, lights))
    batched = texture_light(image, normal, mask, uv, model=model)
    for i in range(3):
        data = prepare(image[i], normal[i], mask[i])
        reference = score(data, 2, texture=(model.at_pixels(uv[i], data.index), model.variance))["light"]
        torch.testing.assert_close(batched[i], torch.tensor(reference, dtype=torch.float64), rtol=0, atol=1e-9)
        alone = texture_light(image[i : i + 1], normal[i : i + 1], mask[i : i + 1], uv[i : i + 1], model=model)[0]
        torch.testing.assert_close(alone, batched[i], rtol=0, atol=1e-9)
    lhat = fit_sh(image, normal, mask)[0]

    def error(sh):  # per image: its shading through the normals against the truth's, scale-invariant (as the report)
        return light_shading_si_mse(sh, true, normal, mask, reduction="none")

    assert (error(batched) < 0.6 * error(lhat)).all(), (error(batched), error(lhat))


def test_blurred_texture_model_is_the_gaussian_blur_of_each_map():
    """A linear ramp is unchanged by a Gaussian blur away from the border; a single bright texel spreads into the
    normalised Gaussian of the stated std (sigma in uv units, R - 1 texels per unit)."""
    R, sigma = 33, 0.0625  # 2 texels
    t = np.linspace(0, 1, R)
    ramp = np.broadcast_to(t[None, None, :], (1, 3, R, R)).copy()
    dot = np.zeros((1, 3, R, R))
    dot[0, :, 16, 16] = 1.0
    blurred = TextureModel(ramp[0], np.concatenate([ramp, dot]), np.ones(2)).blurred(sigma)
    np.testing.assert_allclose(blurred.mean[:, 8:-8, 8:-8], ramp[0, :, 8:-8, 8:-8], atol=1e-12)
    d = np.arange(R) - 16
    gauss = np.exp(-(d[:, None] ** 2 + d[None] ** 2) / (2 * (sigma * (R - 1)) ** 2))
    np.testing.assert_allclose(blurred.components[1, 0], gauss / gauss.sum(), atol=2e-4)


def textured_scene(W_true, seed=0, H=32):
    """``(data, uv)``: an ellipsoid under an order-2 light whose albedo is :func:`feature_texture` seen through
    ``uv`` mapped by the affine ``W_true`` (what a misregistered pseudo uv would leave), with ``uv`` itself."""
    from disent.lighting.texture import affine

    normal, mask = ellipsoid(H, H)
    y, x = torch.meshgrid(
        torch.linspace(0, 1, H, dtype=torch.float64), torch.linspace(0, 1, H, dtype=torch.float64), indexing="ij"
    )
    uv = torch.stack([x, y])
    model = feature_texture()
    beta = -np.sqrt(model.variance) * 2.0
    albedo = torch.nn.functional.grid_sample(
        torch.from_numpy(model.mean + np.einsum("j,jchw->chw", beta, model.components))[None],
        (2 * affine(uv, W_true) - 1).permute(1, 2, 0)[None],
        align_corners=True,
    )[0]
    sh = directional_light([0.4, 0.3, 1.0])
    data = prepare(albedo * render(normal, sh, 0.0) + render(normal, 0 * sh, 0.005, seed), normal, mask)
    return data, uv, model


@pytest.mark.parametrize("misregistered", [True, False])
def test_register_recovers_an_affine_misregistration(misregistered):
    """The texture reaches the image through ``[u, v, 1] W_true``; registering the model to the image from the
    unregistered uv recovers W_true: the uv error at the pixels falls below a fifth of what it was, and a scene
    already registered stays so (under 0.2 texels)."""
    from disent.lighting.texture import AFFINE_IDENTITY, affine, register

    W_true = AFFINE_IDENTITY + (np.array([[0.04, 0.0], [0.0, -0.03], [0.03, -0.02]]) if misregistered else 0)
    data, uv, model = textured_scene(W_true)
    prior = (np.zeros((3, 2)), np.full((3, 2), 0.05))
    truth = affine(uv, W_true).flatten(1)[:, data.index]

    def rms_texels(uv_map):
        return float(((uv_map.flatten(1)[:, data.index] - truth) ** 2).mean().sqrt()) * (uv.shape[-1] - 1)

    found = rms_texels(register(data, uv, model, prior))
    if misregistered:
        assert rms_texels(uv) > 0.8 and found < rms_texels(uv) / 5
    else:
        assert found < 0.2


def test_cli_writes_intervals_and_diagnostics(tmp_path):
    import json
    import subprocess
    import sys

    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "disent.lighting", "index=3", "max_steps=300", "figures=false", f"out={out}"]
    study = tmp_path / "study"  # an order study whose row best on val for the known albedo on true normals has the
    study.mkdir()  # residual process: the CLI's order choice takes that noise model, with the study's fit
    rows = {"val/known/normal": 0.9, "val/known/normal+residual_process": 1.0, "val/texture/normal+geometry_noise": 1}
    (study / "order.json").write_text(json.dumps({k: {"evidence": {"accuracy": v}} for k, v in rows.items()}))
    (study / "residual_process.json").write_text(json.dumps({"normal": {"rho": 1000.0, "ell": 1.0}}))
    cmd.append(f"order_study={study}")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads((out / "posterior.json").read_text())
    assert result["name"] == "test_00003" and result["order"] == 2 and result["known_albedo"]
    lo, hi = np.asarray(result["ci95"][0]), np.asarray(result["ci95"][1])
    lo68, hi68 = np.asarray(result["ci68"][0]), np.asarray(result["ci68"][1])
    assert lo.shape == (3, 9) and np.all(lo <= lo68) and np.all(lo68 < hi68) and np.all(hi68 <= hi)
    d = result["diagnostics"]
    assert d["n_steps"] <= 300 and 0 < d["acceptance_fraction"] <= 1 and d["tau_max"] > 0 and d["ess_min"] > 0
    assert result["order_choice"]["choice"] in result["order_choice"]["scores"]
    assert result["order_choice"]["noise_model"] == "residual_process"
    assert result["order_choice"]["residual"] == [1000, 1]
    assert 0 <= result["true_inside95"] <= 1  # the truth is known on SynthFaces


def test_chosen_noise_model_reads_the_study(tmp_path):
    """``auto`` takes the noise model of the study's row best on val for that albedo and geometry (only that geometry's
    rows, not those of a geometry whose name it begins), i.i.d. without one; a named model takes its constants from
    the study; an unknown model, or a residual process the study has no fit for, is refused by name."""
    from disent.lighting.experiments import chosen_noise_model, geometry_noise

    rows = {
        "val/texture/normal_pseudo+residual_process": 0.6,
        "val/texture/normal_pseudo+geometry_noise": 0.5,
        "val/texture/normal_pseudo_registered+geometry_noise": 0.9,  # another geometry
        "test/texture/normal_pseudo+geometry_noise": 1.0,  # test does not choose
    }
    (tmp_path / "order.json").write_text(json.dumps({k: {"evidence": {"accuracy": v}} for k, v in rows.items()}))
    (tmp_path / "residual_process.json").write_text(json.dumps({"normal_pseudo": {"rho": 10.0, "ell": 1.0}}))
    assert chosen_noise_model("texture", "normal_pseudo", tmp_path) == ("residual_process", {"residual": (10.0, 1.0)})
    assert chosen_noise_model("known", "normal_pseudo", tmp_path) == ("iid", {})
    assert chosen_noise_model("texture", "normal_pseudo", tmp_path / "none") == ("iid", {})
    assert chosen_noise_model("texture", "normal_pseudo", tmp_path, "geometry_noise") == (
        "geometry_noise",
        geometry_noise("normal_pseudo"),
    )
    with pytest.raises(ValueError, match="unknown noise model 'gaussian'"):
        chosen_noise_model("texture", "normal_pseudo", tmp_path, "gaussian")
    with pytest.raises(ValueError, match="no residual fit 'normal_pseudo\\+geometry_noise'"):
        chosen_noise_model("texture", "normal_pseudo", tmp_path, "geometry_noise+residual_process")


def test_noise_parts_name_each_part_of_a_noise_model():
    """The noise models' names, parsed in one place: which of the geometry noise and the residual process each has,
    and a residual fit keyed by the geometry noise beside it."""
    from disent.lighting.experiments import NOISE_MODELS, fit_key, noise_parts

    assert {m: noise_parts(m) for m in ("iid", *NOISE_MODELS)} == {
        "iid": (False, False, False),
        "geometry_noise": (True, False, False),
        "residual_process": (False, True, False),
        "geometry_noise+residual_process": (True, True, False),
        "residual_process+student_t": (False, True, True),
    }
    assert fit_key("normal_pseudo", "residual_process+student_t") == "normal_pseudo"  # the Gaussian fit's rho, ell
    assert fit_key("normal_pseudo", "residual_process") == "normal_pseudo"
    assert fit_key("normal_pseudo", "geometry_noise+residual_process") == "normal_pseudo+geometry_noise"
    with pytest.raises(ValueError, match=r"unknown noise model 'residual_process\+geometry_noise'"):
        noise_parts("residual_process+geometry_noise")


def test_cli_order_choice_on_pseudo_geometry_uses_the_chosen_geometry(monkeypatch):
    """Without a known albedo on pseudo normals, the CLI's order choice scores the texture model on
    ``order_geometry`` (here the registered uv and eroded mask): the pixels it sees are that geometry's,
    not the posterior's whole pseudo mask."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.lighting.__main__ as cli
    from disent.data import SynthFaces
    from disent.lighting.experiments import GEOMETRY, coarse_fit_made_true, item_data

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf" / "lighting.yaml")
    cfg.data = {"resolution": 64}
    cfg.normals, cfg.known_albedo, cfg.max_steps, cfg.texture_components = "normal_pseudo", False, 200, 4
    seen = {}

    def spy(data, **kwargs):
        seen["index"], seen["texture"] = data.index, kwargs["texture"]
        return {"choice": "order0", "order": 0, "gray": False, "scores": {}, "criterion": "evidence"}

    monkeypatch.setattr(cli, "select_order", spy)
    item = SynthFaces("test", resolution=64, size=1)[0]
    assert cfg.order_geometry in GEOMETRY
    cfg.order_geometry = "normal_pseudo_registered"  # one that needs nothing beyond the item
    result, _, data = cli.posterior_of(cfg, "x", item)
    assert result["order_choice"]["geometry"] == cfg.order_geometry
    eroded = item_data(item, 0.0, 0, known_albedo=False, normals=cfg.order_geometry)
    assert np.array_equal(seen["index"], eroded.index) and len(seen["index"]) < len(data.index)
    assert seen["texture"][0].shape == (5, len(eroded.index), 3)  # the mean and 4 components at those pixels
    cfg.order_geometry = "network_implicit"  # the shipped implicit model's normals, matte and uv of the image
    result, _, _ = cli.posterior_of(cfg, "x", item)
    assert result["order_choice"]["geometry"] == "network_implicit" and len(seen["index"]) != len(eroded.index)
    cfg.order_geometry = "oracle_placement"  # needs a SynthFaces scene's parameters, which an item alone lacks
    with pytest.raises(ValueError, match="needs one"):
        cli.posterior_of(cfg, "x", item)
    ds = SynthFaces("test", resolution=64, size=1)  # given the scene, the coarse fit is drawn again at the truth
    result, _, _ = cli.posterior_of(cfg, "x", item, ds, 0)
    moved = item_data(coarse_fit_made_true(ds, 0, item, ("placement",)), 0.0, normals="oracle_placement")
    assert result["order_choice"]["geometry"] == "oracle_placement" and np.array_equal(seen["index"], moved.index)
    assert not np.array_equal(moved.index, eroded.index)
    cfg.order_geometry = "network_explict"  # misspelt: named, with the choices
    with pytest.raises(ValueError, match="unknown geometry 'network_explict'; choose from normal, normal_pseudo"):
        cli.posterior_of(cfg, "x", item)


def test_single_core_sets_and_restores_torch_and_blas_threads():
    from disent.runtime import _openblas

    outer = torch.get_num_threads()
    torch.set_num_threads(2)
    blas = _openblas()
    for _, set_ in blas:
        set_(2)
    try:
        with single_core():
            assert torch.get_num_threads() == 1 and all(get() == 1 for get, _ in blas)
        assert torch.get_num_threads() == 2 and all(get() == 2 for get, _ in blas)
    finally:
        torch.set_num_threads(outer)
        for _, set_ in blas:
            set_(1)


def test_cli_adds_noise_to_renders_only_and_writes_a_run_folder(monkeypatch, tmp_path):
    """``noise: null``: 0.01 on a SynthFaces render, nothing on a photo (``image=``); the default output is
    a run folder under outputs/, not the repository's reports/."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.lighting.__main__ as cli
    from disent.data import SynthFaces

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf" / "lighting.yaml")
    out = OmegaConf.to_container(cfg, resolve=False)["out"]  # ${now:...}: resolved by Hydra at run time
    assert out.startswith("outputs/lighting/") and cfg.noise is None and "cache_dir" in cfg
    cfg.data = {"resolution": 64}
    seen = []

    class Stop(Exception):
        pass

    def spy(image, noise, seed):
        seen.append(noise)
        raise Stop

    monkeypatch.setattr(cli, "noisy", spy)
    item = SynthFaces("test", resolution=64, size=1)[0]
    for image, expected in ((None, 0.01), ("face.jpg", 0.0)):
        cfg.image = image
        with pytest.raises(Stop):
            cli.posterior_of(cfg, "x", item)
        assert seen[-1] == expected
    cfg.noise = 0.05  # asked for: added to a photo too
    with pytest.raises(Stop):
        cli.posterior_of(cfg, "x", item)
    assert seen[-1] == 0.05


def test_sh_basis_gradient_matches_finite_differences():
    from disent.lighting.order import sh_basis_gradient
    from disent.render import sh_basis

    rng = np.random.default_rng(0)
    n = rng.normal(size=(20, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g = sh_basis_gradient(n)
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        fd = (sh_basis(torch.from_numpy(n + e), 1) - sh_basis(torch.from_numpy(n - e), 1)).numpy() / (2 * h)
        np.testing.assert_allclose(g[:, :, j], fd, atol=1e-8)


def test_geometry_variance_closed_form():
    """An ambient light does not see the normals (no added variance); a light along x at a frontal pixel
    moves it by a 2 C2 L_x (delta n)_x, so the variance is (normal_sigma a 2 C2 L_x)^2 in that channel."""
    from disent.lighting.order import geometry_variance
    from disent.render import C2

    normal = torch.zeros(3, 2, 2, dtype=torch.float64)
    normal[2] = 1.0
    data = prepare(torch.full((3, 2, 2), 0.5, dtype=torch.float64), normal, torch.ones(1, 2, 2), min_pixels=1)
    ambient = np.zeros((3, 9))
    ambient[:, 0] = 1.0
    assert np.all(geometry_variance(data, ambient, 0.2) == 0)
    along_x = np.zeros((3, 4))
    along_x[:, 3] = [0.5, 1.0, 2.0]  # per channel
    v = geometry_variance(data, along_x, 0.2)  # [P, C]
    np.testing.assert_allclose(v, (0.2 * 2 * C2 * np.array([0.5, 1.0, 2.0]))[None] ** 2 * np.ones((4, 3)))
    tilted = data.basis.copy()  # at a normal along x the x-gradient is radial: no tangent part, no variance
    from disent.render import sh_basis

    tilted[:] = sh_basis(torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64).T, 0).T.numpy()
    from dataclasses import replace

    assert np.allclose(geometry_variance(replace(data, basis=tilted), along_x, 0.2), 0)


def test_geometry_noise_keeps_the_order_when_normals_are_bent():
    """A band-1 scene fitted on bent normals (a smooth 0.2 rad error, as the pseudo-GT's): the i.i.d. model
    reads the structured misfit as band 2 more often than the model that expects the geometry error."""
    normal, mask = ellipsoid(32, 32)
    H, W = normal.shape[1:]
    y, x = torch.meshgrid(
        torch.linspace(-1, 1, H, dtype=torch.float64), torch.linspace(-1, 1, W, dtype=torch.float64), indexing="ij"
    )
    rng = np.random.default_rng(0)
    picks = {0.0: 0, 0.16: 0}
    for i in range(6):
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 0.3
        sh = directional_light(direction.tolist())
        sh[:, 4:] = 0
        sh[:, 0] *= 2
        image = render(normal, sh, 0.01, seed=i)
        a, b = rng.normal(scale=0.2, size=2)
        bent = normal + mask * torch.stack([a * torch.sin(2 * y + i), b * torch.cos(2 * x - i), torch.zeros_like(x)])
        bent = torch.nn.functional.normalize(bent, dim=0) * mask
        data = prepare(image, bent, mask)
        for sigma in picks:
            picks[sigma] += select_order(data, normal_sigma=sigma)["order"] == 1
    assert picks[0.16] > picks[0.0], picks


def test_whitener_closed_form():
    """``whiten`` solves with the Cholesky factor of R = (I + rho K) / (1 + rho) (K(p, q) = exp(-|p - q| / ell)): the
    whitened squared norm is the Mahalanobis norm, ``inverse`` applies R^-1 and ``log_det`` is log det R."""
    from disent.lighting.order import Whitener

    normal, mask = ellipsoid(12, 12)
    data = prepare(render(normal, directional_light([0.2, 0.3, 1.0]), 0.01), normal, mask)
    r, c = np.divmod(data.index, 12)
    dist = np.sqrt((r[:, None] - r[None]) ** 2 + (c[:, None] - c[None]) ** 2)
    cov = (np.eye(len(dist)) + 5.0 * np.exp(-dist / 2.0)) / 6.0
    whiten = Whitener(data, 5.0, 2.0)
    x = np.random.default_rng(0).normal(size=(data.n_pixels, 3))
    assert np.allclose((whiten(x) ** 2).sum(0), np.einsum("pc,pc->c", x, np.linalg.solve(cov, x)))
    assert np.allclose(whiten.inverse(x), np.linalg.solve(cov, x))
    assert whiten.log_det == pytest.approx(np.linalg.slogdet(cov)[1])


def test_residual_process_of_zero_strength_is_the_iid_model():
    from disent.lighting.order import score

    normal, mask = ellipsoid(20, 20)
    data = prepare(render(normal, directional_light([0.4, -0.2, 1.0]), 0.02), normal, mask)
    for order, gray in ((0, False), (1, True), (2, False)):
        iid, zero = score(data, order, gray), score(data, order, gray, residual=(0.0, 1.0))
        assert zero["log_evidence"] == pytest.approx(iid["log_evidence"]) and zero["bic"] == pytest.approx(iid["bic"])
    # select_order factors the residual process once for all candidates: the same scores as one by one
    chosen = select_order(data, residual=(5.0, 2.0))["scores"]
    for name, order, gray in candidates(data.n_channels):
        alone = score(data, order, gray, residual=(5.0, 2.0))
        assert chosen[name]["log_evidence"] == pytest.approx(alone["log_evidence"], rel=1e-9)


def test_geometry_noise_beside_the_residual_process():
    """Both noise models together: with rho 0 it is the geometry noise alone; its log-likelihood is the Gaussian
    density of the residual under the covariance V^1/2 R V^1/2 written out in full, at the sigma that maximises it."""
    from scipy.stats import multivariate_normal

    from disent.lighting.order import geometry_variance, score

    normal, mask = ellipsoid(12, 12)
    data = prepare(render(normal, directional_light([0.4, -0.2, 1.0]), 0.02), normal, mask)
    for order, gray in ((1, True), (2, False)):
        alone, beside = (
            score(data, order, gray, normal_sigma=0.1),
            score(data, order, gray, normal_sigma=0.1, residual=(0.0, 1.0)),
        )
        assert beside["log_evidence"] == pytest.approx(alone["log_evidence"], rel=1e-6)
    rho, ell, normal_sigma = 3.0, 2.0, 0.03  # a geometry noise of the order of the image noise
    both = score(data, 1, normal_sigma=normal_sigma, residual=(rho, ell))
    light = np.array(both["light"])
    r = data.y - data.basis[:, :4] @ light.T  # [P, C], the constant albedo absorbed into the light
    extra = geometry_variance(data, light, normal_sigma)
    rows, cols = np.divmod(data.index, data.shape[1])
    dist = np.hypot(rows[:, None] - rows[None], cols[:, None] - cols[None])
    R = (np.eye(len(dist)) + rho * np.exp(-dist / ell)) / (1 + rho)

    def loglik(s2):  # channels independent, each N(0, V^1/2 R V^1/2)
        v = np.sqrt(s2 + extra)
        return sum(multivariate_normal(cov=v[:, c, None] * R * v[None, :, c]).logpdf(r[:, c]) for c in range(3))

    s2 = np.exp(np.linspace(np.log(1e-6), np.log(1e-2), 401))
    values = [loglik(x) for x in s2]
    assert both["loglik"] == pytest.approx(max(values), abs=1e-3 * abs(max(values)))
    assert both["loglik"] >= max(values) - 1e-6  # the profiled sigma is at least as good as the grid's best


def test_residual_process_keeps_the_order_under_correlated_albedo_misfit():
    """Scenes of SH band 0, 1 and 2 whose albedo carries a spatially correlated misfit (an exponential-kernel
    field, as the texture model leaves): the i.i.d. model reads the misfit as extra SH bands; the model that
    expects a correlated residual finds each band in most scenes, band 2 included."""
    normal, mask = ellipsoid(24, 24)
    H, W = normal.shape[1:]
    r, c = np.divmod(np.arange(H * W), W)
    K = np.exp(-np.sqrt((r[:, None] - r[None]) ** 2 + (c[:, None] - c[None]) ** 2) / 3.0)
    root = np.linalg.cholesky(K + 1e-9 * np.eye(H * W))
    rng = np.random.default_rng(0)
    right = {None: [0, 0, 0], (30.0, 3.0): [0, 0, 0]}
    for band in range(3):
        for i in range(6):
            direction = rng.normal(size=3)
            direction[2] = abs(direction[2]) + 0.3
            sh = directional_light(direction.tolist())
            sh[:, (1, 4, 9)[band] :] = 0
            field = torch.from_numpy((root @ rng.normal(size=(H * W, 1))).reshape(1, H, W))
            albedo = (0.6 + 0.08 * field).expand(3, H, W)
            noise = 0.01 * torch.randn(3, H, W, generator=torch.Generator().manual_seed(i), dtype=torch.float64)
            data = prepare(albedo * render(normal, sh, 0.0) + noise, normal, mask)
            for residual in right:
                right[residual][band] += select_order(data, residual=residual)["order"] == band
    iid, correlated = right[None], right[(30.0, 3.0)]
    assert sum(iid[:2]) < sum(correlated[:2]) and all(n > 3 for n in correlated), right


def test_residual_process_maximum_likelihood_finds_the_generating_constants():
    """Residuals drawn from the process with rho 3, ell 2 (and i.i.d. ones) on an ellipse's pixels: the grid's
    maximum likelihood is the generating point (rho 0 for the i.i.d. draws).  (A large rho leaves little white
    noise to tell 30 from 300 apart: the likelihood flattens there, as in the fit on SynthFaces.)"""
    from disent.lighting.experiments import max_likelihood_residual

    normal, mask = ellipsoid(20, 20)
    data = prepare(render(normal, directional_light([0.2, 0.3, 1.0]), 0.01), normal, mask)
    r, c = np.divmod(data.index, 20)
    dist = np.sqrt((r[:, None] - r[None]) ** 2 + (c[:, None] - c[None]) ** 2)
    root = np.linalg.cholesky(np.eye(len(dist)) + 3.0 * np.exp(-dist / 2.0))
    rng = np.random.default_rng(0)
    grid = {"rho": (0.0, 3.0, 30.0, 300.0), "ell": (0.5, 2.0, 8.0)}
    correlated = [(data, 0.01 * root @ rng.normal(size=(data.n_pixels, 3)), None) for _ in range(4)]
    fit = max_likelihood_residual(correlated, grid)
    assert (fit["rho"], fit["ell"]) == (3.0, 2.0) and len(fit["log_likelihood"]) == 12
    iid = [(data, 0.01 * rng.normal(size=(data.n_pixels, 3)), None) for _ in range(4)]
    assert max_likelihood_residual(iid, grid)["rho"] == 0.0


def test_eroded_takes_a_batch_of_masks():
    from disent.lighting.experiments import eroded

    m = torch.zeros(2, 1, 8, 8)
    m[0, 0, 2:7, 1:6] = 1  # 5 x 5: 3 x 3 left
    m[1, 0, 1:4, 1:4] = 1  # 3 x 3: its centre left
    e = eroded(m, 1)
    assert e.shape == m.shape and e[0].sum() == 9 and e[1].sum() == 1
    assert torch.equal(e[0], eroded(m[0], 1)) and eroded(m[0, 0], 1).shape == (1, 8, 8)


def test_lhat_sources_is_exact_with_every_input_made_true():
    """SynthFaces renders the face as albedo (.) S(n, L): least squares on the image over the true albedo, through
    the true normals, on the true face, returns the true light; the paper's L-hat does not."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import LHAT_SOURCES, ORACLE_MIXES, SHARPENING, lhat_sources

    r = lhat_sources(SynthFaces("test", size=6), SynthFaces("train", size=32), n=6, networks=("explicit",))
    rows = r["rows"]
    # the oracle doses lie between L-hat and the truth, nearer the truth the larger the share
    doses = [rows["lhat"]["light_on_face"]] + [rows[f"oracle_mix_{m}"]["light_on_face"] for m in ORACLE_MIXES]
    assert doses == sorted(doses, reverse=True) and doses[-1] < 0.2 * doses[0]
    assert r["n"] == 6 and rows["true_pixels_normals_albedo"]["light_on_face"] < 1e-9
    assert rows["true_pixels_normals_albedo"]["beats_lhat"] == 1
    assert rows["true_pixels_normals_albedo"]["contrast"] == pytest.approx(1, abs=1e-6)  # the truth's own contrast
    assert rows["lhat"]["light_on_face"] > 1e-3 and rows["lhat"]["beats_lhat"] == 0
    doses = {f"oracle_mix_{m}" for m in ORACLE_MIXES}
    assert set(rows) == set(LHAT_SOURCES) | doses | {
        "texture_model",
        "texture_model_lhat_scale",
        "network_explicit",
        "network_explicit_refit",
        "network_explicit_texture",
        "floor",
    }
    # the texture model's light at L-hat's scale per face and channel: the same shape, so the same scale-invariant error
    tex, tex_at_lhat = rows["texture_model"], rows["texture_model_lhat_scale"]
    assert tex_at_lhat["light_on_face"] == pytest.approx(tex["light_on_face"], rel=1e-6)
    assert tex_at_lhat["skin_tone_corr"] != pytest.approx(tex["skin_tone_corr"], abs=1e-3)
    assert all(len(row["inputs"]) == 3 and 0 <= row["shown"] for row in rows.values())
    # contrast = pattern x magnitude face by face; the medians need not multiply exactly
    truth = rows["true_pixels_normals_albedo"]
    assert truth["pattern_corr"] == pytest.approx(1, abs=1e-6) and truth["contrast_ratio"] == pytest.approx(1, abs=1e-6)
    assert abs(truth["log_error"]) < 1e-9 < rows["lhat"]["log_error"]
    assert all(-1 <= row["pattern_corr"] <= 1 and row["contrast_ratio"] > 0 for row in rows.values())
    net = rows["network_explicit"]
    assert net["calibration"] > 0 and list(net["sharpened_albedo"]) == list(SHARPENING)
    assert "calibration" not in rows["lhat"]
    assert rows["network_explicit_texture"]["inputs"] == ("network", "texture_model", "eroded_matte")
    assert all(-1 <= row[f"skin_{k}_corr"] <= 1 for row in rows.values() for k in ("tone", "brightness"))


def test_sharpened_albedo_is_exact_at_the_true_shading_alone():
    """SynthFaces' image is albedo (.) shading: over the true shading (k = 1) the detailed albedo is the truth up to
    scale; a more or a less contrasty shading leaves its contrast in the albedo."""
    from disent.data import SynthFaces, get_batch
    from disent.lighting.experiments import sharpened_albedo
    from disent.regions import decomposed_region

    g = get_batch(SynthFaces("test", size=3), range(3))
    e = sharpened_albedo(g["image"], g["shading"], g["albedo"], decomposed_region(g), ks=(0.8, 1.0, 1.25))
    assert e[1.0] < 1e-6 < min(e[0.8], e[1.25])


def test_eroded_pseudo_mask_drops_exactly_the_edge_ring():
    from disent.lighting.experiments import GEOMETRY, eroded, item_data

    m = torch.zeros(1, 8, 8)
    m[0, 2:7, 1:6] = 1  # a 5 x 5 square
    e = eroded(m, 1)[0]
    assert e.sum() == 9 and e[3:6, 2:5].all()  # the 3 x 3 inside it
    assert eroded(m, 2)[0].sum() == 1 and eroded(m, 3)[0].sum() == 0
    big = torch.zeros(1, 12, 12)
    big[0, 2:10, 2:10] = 1  # 8 x 8: the fit keeps the inner 6 x 6 on the eroded geometry
    item = {
        "image": torch.rand(3, 12, 12),
        "normal_pseudo": torch.nn.functional.normalize(torch.rand(3, 12, 12) + 0.5, dim=0),
        "mask_pseudo": big,
    }
    assert GEOMETRY["normal_pseudo_eroded"].erosion == 1 and GEOMETRY["normal_pseudo"].erosion == 0
    full = item_data(item, 0.0, known_albedo=False, normals="normal_pseudo")
    cut = item_data(item, 0.0, known_albedo=False, normals="normal_pseudo_eroded")
    assert full.n_pixels == 64 and cut.n_pixels == 36
    assert set(cut.index.tolist()) == {r * 12 + c for r in range(3, 9) for c in range(3, 9)}


def test_registration_brings_the_pseudo_uv_towards_the_true_uv():
    """On SynthFaces val scenes (lights cut to orders 0-2), the registered geometry scores the eroded pseudo
    geometry's pixels, and its uv lies nearer the true uv there than the pseudo uv does (rms over 6 scenes)."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import item_data, light_of_order, uv_of

    ds, before, after = SynthFaces("val", 64, 0), [], []
    for i in range(6):
        item = ds.sample(i, sh=light_of_order(ds[i]["sh"], i % 3))
        data = item_data(item, 0.02, i, known_albedo=False, normals="normal_pseudo_registered")
        eroded_data = item_data(item, 0.02, i, known_albedo=False, normals="normal_pseudo_eroded")
        assert np.array_equal(data.index, eroded_data.index) and np.array_equal(data.basis, eroded_data.basis)
        truth = item["uv"].double().flatten(1)[:, data.index]
        for uv, errors in ((item["uv_pseudo"], before), (uv_of(item, data, "normal_pseudo_registered"), after)):
            errors.append(((uv.double().flatten(1)[:, data.index] - truth) ** 2).mean())
    assert np.sqrt(np.mean(after)) < 0.8 * np.sqrt(np.mean(before))


def test_registration_of_the_implicit_networks_own_uv_under_its_own_prior():
    """The implicit model's uv, registered under the prior of its own affine errors on train scenes (a systematic
    scale the pseudo uv's prior lacks), lies nearer the true uv in most val scenes and in the median."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import item_data, light_of_order, scene_geometry, uv_of
    from disent.lighting.texture import registration_prior

    own, pseudo = registration_prior(64, network="implicit"), registration_prior(64)
    assert not np.allclose(own[0], pseudo[0], atol=0.01)
    ds, before, after, normals = SynthFaces("val", 64, 0), [], [], "network_implicit_registered"
    for i in range(6):
        item = scene_geometry(ds, i, ds.sample(i, sh=light_of_order(ds[i]["sh"], i % 3)), normals, 0.02, i)
        data = item_data(item, 0.02, i, known_albedo=False, normals=normals)
        truth = item["uv"].double().flatten(1)[:, data.index]
        for uv, errors in ((item["uv_net"], before), (uv_of(item, data, normals), after)):
            errors.append(float(((uv.double().flatten(1)[:, data.index] - truth) ** 2).mean()))
    assert np.median(after) < 0.9 * np.median(before) and sum(a < b for a, b in zip(after, before)) >= 4


def test_oracle_geometries_swap_in_exactly_one_true_layer():
    """The order study's oracle rows: ``oracle_uv`` is the eroded pseudo geometry with the texture model reached
    through the true uv; ``oracle_normals`` is it with the true normals (same pixels, the pseudo uv)."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_data
    from disent.lighting.texture import texture_for

    item = SynthFaces("val", 64, 0)[0]
    pseudo, tex_pseudo = order_data(item, 0.02, 1, "texture", "normal_pseudo_eroded", n_components=4)
    for normals, uv_key, same_normals in (("oracle_uv", "uv", True), ("oracle_normals", "uv_pseudo", False)):
        data, tex = order_data(item, 0.02, 1, "texture", normals, n_components=4)
        assert np.array_equal(data.index, pseudo.index) and np.array_equal(data.y, pseudo.y)
        assert np.array_equal(data.basis, pseudo.basis) == same_normals
        np.testing.assert_array_equal(tex[0], texture_for(data, item[uv_key], 4)[0])
        assert np.array_equal(tex[0], tex_pseudo[0]) == (uv_key == "uv_pseudo")


def test_coarse_fit_made_true_renders_the_pseudo_maps_again():
    """Nothing made true renders the item's own pseudo maps; the true placement and shape together bring the
    pseudo normals towards the true ones, and each part alone changes the maps (the oracle rows' geometry)."""
    from disent.data import SynthFaces
    from disent.eval.metrics import normal_angular_error
    from disent.lighting.experiments import coarse_fit_made_true

    ds = SynthFaces("val", 64, 0)
    errors = {(): [], ("placement", "shape"): []}
    for i in range(4):
        item = ds[i]
        same = coarse_fit_made_true(ds, i, item, ())
        for k in ("normal_pseudo", "mask_pseudo", "uv_pseudo"):
            torch.testing.assert_close(same[k], item[k].float(), atol=2e-3, rtol=0)  # the dataset stores half floats
        for parts in (("placement",), ("shape",)):
            moved = coarse_fit_made_true(ds, i, item, parts)
            assert not torch.allclose(moved["normal_pseudo"], same["normal_pseudo"], atol=1e-2)
        for parts in errors:
            maps = coarse_fit_made_true(ds, i, item, parts)
            both = (maps["mask_pseudo"] > 0.5) & (item["matte"] > 0.5)
            errors[parts].append(
                normal_angular_error(maps["normal_pseudo"][None], item["normal"][None], both[None])["mean"]
            )
    assert np.mean(errors[("placement", "shape")]) < 0.8 * np.mean(errors[()]), errors


def test_band2_share_closed_form():
    """Band 2's energy over bands 0 and 1: none for a light of order 1, and sums of squares per band otherwise."""
    from disent.lighting.order import band2_share

    light = np.zeros((3, 9))
    light[:, 0], light[:, 2] = 1.0, 0.5
    assert band2_share(light) == 0.0
    light[0, 4], light[2, 8] = 0.6, 0.8  # band 2: 0.36 + 0.64 = 1; bands 0-1: 3 x (1 + 0.25)
    assert band2_share(light) == pytest.approx(1.0 / 3.75)


def test_network_geometry_reads_the_shipped_models_maps_of_the_noisy_image():
    """The network rows' geometry: the shipped model's normals and matte (and the implicit model's uv) of the very
    noisy image the fit sees, eroded like the pseudo rows; on val scenes the network's normals lie nearer the truth
    than the pseudo-GT's (claim 1, scene by scene), which is why the rows exist. The oracle row reads the explicit
    network's maps with the scene's true uv."""
    from disent.data import SynthFaces
    from disent.eval.metrics import normal_angular_error
    from disent.lighting.experiments import GEOMETRY, eroded, item_data, network_maps, noisy, scene_geometry, uv_of
    from disent.models import load_run

    ds, errors = SynthFaces("val", 64, 0), {"net": [], "pseudo": []}
    for i in range(4):
        item = ds[i]
        for normals in ("network_explicit", "network_implicit"):
            geo = scene_geometry(ds, i, item, normals, 0.02, 3)
            with torch.no_grad():
                out = load_run(GEOMETRY[normals].network)[0](noisy(item["image"], 0.02, 3).float().clamp(0, 1)[None])
            torch.testing.assert_close(geo["normal_net"], out["normal"][0].double())
            torch.testing.assert_close(geo["matte_net"], out["matte"][0])
            assert ("uv_net" in geo) == (normals == "network_implicit")
            torch.testing.assert_close(geo["normal_net"].norm(dim=0), torch.ones(64, 64, dtype=torch.float64))
            data = item_data(geo, 0.02, 3, known_albedo=False, normals=normals)
            keep = eroded(geo["matte_net"], 1).flatten() > 0.5
            assert set(data.index.tolist()) == set(torch.nonzero(keep).flatten().tolist())
            if normals == "network_implicit":
                assert uv_of(geo, data, normals) is geo["uv_net"]  # its own uv, not registered
        maps = network_maps("explicit", noisy(item["image"], 0.02, 3))
        oracle = scene_geometry(ds, i, item, "oracle_uv_network", 0.02, 3)  # the explicit network's maps, the true uv
        torch.testing.assert_close(oracle["normal_net"], maps["normal_net"])
        data = item_data(oracle, 0.02, 3, known_albedo=False, normals="oracle_uv_network")
        assert uv_of(oracle, data, "oracle_uv_network") is item["uv"]
        both = (maps["matte_net"] > 0.5) & (item["matte"] > 0.5) & (item["mask_pseudo"] > 0.5)
        errors["net"].append(normal_angular_error(maps["normal_net"][None].float(), item["normal"][None], both[None]))
        errors["pseudo"].append(normal_angular_error(item["normal_pseudo"][None], item["normal"][None], both[None]))
    assert np.mean([e["mean"] for e in errors["net"]]) < np.mean([e["mean"] for e in errors["pseudo"]]), errors


def test_texture_pixels_lie_where_the_uv_is_defined():
    """The texture model reaches only pixels where the geometry's uv is defined: the pseudo uv (0 off the coarse
    fit's mask) on the explicit network's matte keeps the pixels inside the pseudo mask, the true uv on the pseudo
    mask those inside the matte; where the uv covers the mask already (the pseudo rows) nothing changes."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import GEOMETRY, UV_DEFINED, item_data, scene_geometry

    ds = SynthFaces("val", 64, 0)
    for normals in ("network_explicit", "oracle_uv", "normal_pseudo_registered"):
        item = scene_geometry(ds, 4, ds[4], normals, 0.02, 3)
        every, textured = (item_data(item, 0.02, 3, known_albedo=False, normals=normals, texture=t) for t in (0, 1))
        defined = (item[UV_DEFINED[GEOMETRY[normals].uv]] > 0.5).flatten()
        assert set(textured.index.tolist()) == {p for p in every.index.tolist() if defined[p]}
        assert (item[GEOMETRY[normals].uv].flatten(1)[:, textured.index] > 0).any(0).all()  # no uv of 0 left
        if normals == "network_explicit":  # this face's coarse fit covers less than the network's matte
            assert len(textured.index) < len(every.index)
        if normals == "normal_pseudo_registered":
            assert len(textured.index) == len(every.index)


def test_order_study_computes_only_the_named_rows_and_keeps_the_rest(tmp_path, monkeypatch):
    """``order_study(only=..., keep=...)``: the named rows are computed, every other row (and its residual fit) is
    copied from the earlier study, a computed row reads with the earlier study's fit of its geometry where it has
    one, and an unknown row name is refused with the list of rows."""
    import json

    from disent.lighting import experiments

    calls = []
    monkeypatch.setattr(
        experiments, "order_confusion", lambda ds, *a, **k: calls.append((ds.split, a[3], k)) or {"new": ds.split}
    )
    monkeypatch.setattr(
        experiments,
        "fit_residual_process",
        lambda ds, n, normals, normal_sigma: {"rho": 3.0, "ell": 2.0 + normal_sigma},
    )
    rows = (
        ("known", "normal"),
        ("texture", "network_explicit", "residual_process"),
        ("texture", "network_explicit", "geometry_noise+residual_process"),
    )
    earlier = {f"{s}/known/normal": {"old": s} for s in ("val", "test")} | {"val/texture/network_explicit": {"x": 1}}
    (tmp_path / "order.json").write_text(json.dumps(earlier))
    (tmp_path / "residual_process.json").write_text(json.dumps({"normal_pseudo": {"rho": 10.0, "ell": 1.0}}))
    out = tmp_path / "out"
    new = ["texture/network_explicit+residual_process", "texture/network_explicit+geometry_noise+residual_process"]
    result = experiments.order_study(out, rows=rows, n_per_order=1, only=new, keep=tmp_path)
    assert list(result) == [
        "val/known/normal",
        *(f"val/{k}" for k in new),
        "test/known/normal",
        *(f"test/{k}" for k in new),
    ]
    assert result["val/known/normal"] == {"old": "val"} and result["test/known/normal"] == {"old": "test"}
    assert [c[:2] for c in calls] == [("val", "network_explicit")] * 2 + [("test", "network_explicit")] * 2
    # each row's noise model: the residual process alone; the geometry noise beside a residual fitted with it
    sigma = experiments.geometry_noise("network_explicit")["normal_sigma"]
    assert calls[0][2]["noise_model"] == {"residual": (3.0, 2.0)}
    assert calls[1][2]["noise_model"] == {"normal_sigma": sigma, "residual": (3.0, 2.0 + sigma)}
    assert json.loads((out / "order.json").read_text()) == result
    fits = json.loads((out / "residual_process.json").read_text())
    assert fits == {
        "normal_pseudo": {"rho": 10.0, "ell": 1.0},
        "network_explicit": {"rho": 3.0, "ell": 2.0},
        "network_explicit+geometry_noise": {"rho": 3.0, "ell": 2.0 + sigma},
    }
    # a row read again on test alone (more scenes): its val entry and every other row are kept, val first
    calls.clear()
    (tmp_path / "order.json").write_text(json.dumps(result))
    again = experiments.order_study(
        tmp_path / "again", ("test",), rows=rows, n_per_order=2, only=new[:1], keep=tmp_path
    )
    assert list(again) == list(result) and calls == [("test", "network_explicit", calls[0][2])]
    assert again[f"val/{new[0]}"] == result[f"val/{new[0]}"] and again[f"test/{new[0]}"] == {"new": "test"}
    # a residual fit the kept study holds is not fitted again: the new row reads with it
    (tmp_path / "residual_process.json").write_text(json.dumps({"network_explicit": {"rho": 30.0, "ell": 1.0}}))
    monkeypatch.setattr(experiments, "fit_residual_process", lambda *a, **k: pytest.fail("refitted a kept fit"))
    calls.clear()
    experiments.order_study(tmp_path / "kept", ("val",), rows=rows, n_per_order=1, only=new[:1], keep=tmp_path)
    assert calls == [("val", "network_explicit", {"noise_model": {"residual": (30.0, 1.0)}})]
    with pytest.raises(ValueError, match="unknown order-study rows.*known/normal"):
        experiments.order_study(out, rows=rows, only=["texture/nothing"], keep=tmp_path)


def test_geometry_noise_reads_each_geometrys_own_measured_error():
    """The geometry-noise model's ``normal_sigma``: the pseudo-GT's constant for the pseudo rows; for a network row,
    the std whose isotropic tangent Gaussian has the shipped model's measured mean normal error as its mean angle."""
    from disent.lighting.experiments import GEOMETRY_NOISE, geometry_noise
    from disent.models.shipped import manifest

    assert geometry_noise("normal_pseudo_registered") == GEOMETRY_NOISE
    for name in ("explicit", "implicit"):
        sigma = geometry_noise(f"network_{name}")["normal_sigma"]
        assert np.degrees(sigma * np.sqrt(np.pi / 2)) == pytest.approx(manifest()[name]["metrics"]["normal_mean"])
        rng = np.random.default_rng(0)  # the mean angle of such a Gaussian, sampled: the closed form holds
        angles = np.arctan(np.hypot(*(sigma * rng.normal(size=(2, 200_000)))))
        assert np.degrees(angles.mean()) == pytest.approx(manifest()[name]["metrics"]["normal_mean"], rel=0.03)


def test_cli_order_task_passes_the_rows_to_compute_and_the_study_to_keep(tmp_path, monkeypatch):
    """``task=order order_rows=[...] order_keep=DIR``: the order study computes those rows only and keeps DIR's;
    ``order_splits``, ``order_n``: on those splits only, with that many scenes per order."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.lighting.__main__ as cli

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf" / "lighting.yaml")
    cfg.data = {"resolution": 64, "seed": 0}
    cfg.task, cfg.out, cfg.order_keep = "order", str(tmp_path / "out"), str(tmp_path)
    cfg.order_rows = ["texture/network_implicit+geometry_noise"]
    seen = []
    monkeypatch.setattr(cli, "order_report", lambda *a, **k: seen.append((a, k)))
    cli.run(cfg)
    ((args, kwargs),) = seen
    defaults = {"splits": None, "n_per_order": 20, "geometry": cfg.order_geometry}
    assert args[1:] == ("test", 64, 0) and kwargs == {"only": cfg.order_rows, "keep": str(tmp_path)} | defaults
    cfg.order_rows, cfg.order_keep = None, None  # the whole study
    cli.run(cfg)
    assert seen[1][1] == {"only": None, "keep": None} | defaults
    cfg.order_splits, cfg.order_n = ["test"], 40
    cli.run(cfg)
    assert seen[2][1] == {"only": None, "keep": None, "splits": ["test"], "n_per_order": 40} | {
        "geometry": cfg.order_geometry
    }


def test_placement_objective_prefers_the_scenes_own_placement():
    """With the coarse fit's shape made true and its placement off by two prior widths in yaw, pitch and shift, the
    objective of the placement refinement (the image under the texture model and an order-2 light, and the prior)
    is lower at the scene's own placement than at the coarse fit's: the image tells where the face is."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import placed, placement_objective, placement_of, placement_width, with_coarse_fit

    ds = SynthFaces("train", 64, 0)
    offset = np.array([2.0, -2.0, 0.0, 0.0, 2.0, -2.0])  # in prior widths
    for i in range(2):
        p = ds.params([i])
        p["pseudo_alpha"], p["pseudo_expression"] = p["alpha"][:, : p["pseudo_alpha"].shape[1]], p["expression"]
        true = placement_of(p, "")
        p = placed(p, true + offset * placement_width(true))
        objective, placement = placement_objective(p, with_coarse_fit(ds.sample(i), p), 0.02, i)
        np.testing.assert_allclose(placement_of(placement(-offset)), true, atol=1e-5)
        assert objective(-offset) < objective(np.zeros(6)) - 50, (objective(-offset), objective(np.zeros(6)))


def test_a_photos_coarse_fit_is_drawn_again_and_its_placement_refined(monkeypatch):
    """A photo's landmark fit (its pseudo-GT ``params``) drawn again as SynthFaces' coarse-fit scene reproduces the
    photo's own pseudo-GT maps, so the placed geometry needs no SynthFaces scene: the CLI's order choice on a photo
    runs on it. The photo here: a SynthFaces render through the pipeline with its exact landmarks (no dlib)."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.data.photos.pseudo_gt as pg
    import disent.lighting.__main__ as cli
    from disent.data import SynthFaces
    from disent.lighting.experiments import coarse_fit_of, with_coarse_fit

    ds, settings = SynthFaces("test", 64, size=1), pg.PseudoGTSettings()
    landmarks = pg.face_model_fitter(settings).synth_landmarks(ds.params([0]), 64)[0]
    rgb = (ds[0]["image"].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    arrays = pg.pseudo_gt_from_landmarks(rgb, landmarks, settings)
    item = {k: torch.as_tensor(v).float() for k, v in arrays.items()} | {
        "image": torch.from_numpy(pg.crop_pixels(arrays["image"]))
    }
    drawn = with_coarse_fit(item, coarse_fit_of(None, None, item))
    for key in ("normal_pseudo", "mask_pseudo", "uv_pseudo"):  # stored as float16
        np.testing.assert_allclose(drawn[key].numpy(), item[key].numpy(), atol=2e-3, err_msg=key)
    with pytest.raises(ValueError, match="neither a SynthFaces scene nor a photo's landmark fit"):
        coarse_fit_of(None, None, {k: v for k, v in item.items() if k != "params"})

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf" / "lighting.yaml")
    cfg.data, cfg.image = {"resolution": 64}, "face.jpg"
    cfg.known_albedo, cfg.max_steps, cfg.texture_components = False, 200, 4
    cfg.order_geometry = "normal_pseudo_placed"
    seen = {}

    def spy(data, **kwargs):
        seen["index"] = data.index
        return {"choice": "order0", "order": 0, "gray": False, "scores": {}, "criterion": "evidence"}

    monkeypatch.setattr(cli, "select_order", spy)
    result, _, _ = cli.posterior_of(cfg, "x", item)
    assert result["order_choice"]["geometry"] == "normal_pseudo_placed" and len(seen["index"]) > 100


def test_order_accuracy_figure_draws_every_row_with_its_wilson_interval(tmp_path, monkeypatch):
    """The forest plot of the order study: each split's rows at their accuracy, the interval Wilson's over the
    row's scenes (one at accuracy 1 has its upper end at 1, not above), a row read on val alone kept."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from disent.lighting.experiments import plot_order_accuracy, wilson_interval

    def row(confusion):
        return {"evidence": {"confusion": confusion, "accuracy": np.trace(confusion) / np.sum(confusion)}}

    study = {
        "val/known/normal": row(np.diag([20, 20, 20]).tolist()),
        "val/texture/normal_pseudo": row([[10, 5, 5], [0, 10, 10], [0, 0, 20]]),
        "test/known/normal": row([[15, 5, 0], [0, 15, 5], [0, 0, 20]]),
    }
    drawn, real = [], plt.Axes.errorbar
    monkeypatch.setattr(
        plt.Axes,
        "errorbar",
        lambda ax, x, y, xerr, **k: drawn.append((k["label"], x, y, xerr)) or real(ax, x, y, xerr, **k),
    )
    plot_order_accuracy(study, tmp_path / "a.png")
    assert (tmp_path / "a.png").stat().st_size > 1000
    (_, x_val, y_val, err_val), (_, x_test, y_test, err_test) = drawn
    assert [label for label, *_ in drawn] == ["val", "test"] and len(x_val) == 2 and len(x_test) == 1
    assert x_val[0] == 1.0 and err_val[1][0] == 0.0 and err_val[0][0] == pytest.approx(1 - wilson_interval(1.0, 60)[0])
    lo, hi = wilson_interval(50 / 60, 60)
    assert x_test[0] == pytest.approx(50 / 60) and err_test[:, 0] == pytest.approx([50 / 60 - lo, hi - 50 / 60])
    assert y_test[0] == pytest.approx(y_val[0] + 0.34)  # the same row, test drawn just below val


def test_order_confusion_keeps_each_scenes_outcome_and_they_add_up_to_its_matrices():
    """Each scene's record (true order, the order each criterion chose, yaw, pixels) adds up to the confusion
    matrices, so where the choice fails can be read scene by scene."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_confusion

    ds = SynthFaces("val", 64, 0)
    out = order_confusion(ds, 2, albedo="known", normals="normal")
    scenes = out["scenes"]
    for crit in ("evidence", "bic"):
        counts = np.zeros((3, 3), int)
        np.add.at(counts, (scenes["true_order"], scenes[crit]), 1)
        assert counts.tolist() == out[crit]["confusion"]
    assert scenes["index"] == [0, 1] * 3 and scenes["true_order"] == [0, 0, 1, 1, 2, 2]
    np.testing.assert_allclose(scenes["yaw"][:2], ds.params([0, 1])["pose"][:, 0].numpy(), atol=0.01)
    assert all(n > 100 for n in scenes["pixels"])
    import scipy

    assert out["settings"]["seed"] == 0 and out["settings"]["machine"]["scipy"] == scipy.__version__


def test_student_t_evidence_tends_to_the_gaussian_as_nu_grows():
    """The Student-t noise model at nu = 1e8 is the Gaussian one: the same log evidence for every candidate, with the
    texture model and the residual process (the reweighted fit, its texture step and the Laplace terms agree)."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_data
    from disent.lighting.order import Whitener, score

    data, texture = order_data(SynthFaces("val", 64, 0)[0], 0.02, 0, "texture", "normal")
    noise = {"texture": texture, "residual": (3.0, 1.0), "whitener": Whitener(data, 3.0, 1.0)}
    for order, gray in ((0, False), (1, True), (2, False)):
        gauss = score(data, order, gray, **noise)["log_evidence"]
        t = score(data, order, gray, **noise, nu=1e8)["log_evidence"]
        assert abs(t - gauss) < 0.05, (order, gauss, t)


def test_student_t_light_resists_outlying_pixels():
    """With 3 % of the pixels made brighter by 0.3 (specks the model cannot explain), the order-2 light fitted under
    Student-t noise (nu = 10) stays near the true light, while the Gaussian fit is pulled far off by them."""
    from dataclasses import replace

    from disent.data import SynthFaces
    from disent.lighting.experiments import order_data
    from disent.lighting.order import score

    item = SynthFaces("val", 64, 0)[0]
    data, _ = order_data(item, 0.01, 0, "known", "normal")
    rng = np.random.default_rng(0)
    y = data.y.copy()
    y[rng.random(len(y)) < 0.03] += 0.3
    data = replace(data, y=y)
    truth = item["sh"].double().numpy()
    error = {nu: np.abs(np.asarray(score(data, 2, nu=nu)["light"]) - truth).max() for nu in (None, 10.0)}
    assert error[10.0] < 0.3 * error[None], error


def test_fitted_image_of_the_right_order_leaves_only_the_noise():
    """With true normals and the known albedo, the order-2 candidate's fitted image (albedo times its light through
    the normals) leaves a residual at the added noise's level; order 0 (ambient only) leaves far more."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_data
    from disent.lighting.order import fitted, score

    item = SynthFaces("val", 64, 0)[0]
    data, _ = order_data(item, 0.01, 0, "known", "normal")
    rms = {o: np.sqrt(((data.y - fitted(data, score(data, o))) ** 2).mean()) for o in (0, 2)}
    assert 0.007 < rms[2] < 0.013, rms
    assert rms[0] > 3 * rms[2], rms


def test_order_failures_refit_the_scenes_the_study_got_wrong(tmp_path):
    """The failure figure refits the first scene of each kind of error of a row, as the study fitted it: the choice
    it reads again is the record's, each kind of error appears once, and where the chosen order is larger than the
    truth its log evidence is above the true order's best (else the smaller model would have been chosen); the
    misfit's parts of the face (order_failure_regions) cover every wrong scene's fitted pixels once."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_confusion, order_failure_regions, plot_order_failures

    ds = SynthFaces("val", 64, 0)
    row = order_confusion(ds, 3, albedo="texture", normals="normal_pseudo")
    records = row["scenes"]
    wrong = {(t, e) for t, e in zip(records["true_order"], records["evidence"]) if t != e}
    assert wrong, "the i.i.d. noise model on pseudo geometry errs on some of these scenes"
    study = {"order": {"val/texture/normal_pseudo": row}, "residual_process": {}}
    out = plot_order_failures(ds, study, "texture/normal_pseudo", tmp_path / "f.png", n_scenes=9)
    assert (tmp_path / "f.png").stat().st_size > 1000
    assert {(s["true_order"], s["chosen"]) for s in out["scenes"]} == wrong and len(out["scenes"]) == len(wrong)
    for s in out["scenes"]:
        k = next(
            k
            for k, (i, t) in enumerate(zip(records["index"], records["true_order"]))
            if (i, t) == (s["index"], s["true_order"])
        )
        assert records["evidence"][k] == s["chosen"]
        if s["chosen"] > s["true_order"]:
            assert s["evidence_gain"] > 0, s
    assert (
        plot_order_failures(ds, {"order": {}, "residual_process": {}}, "texture/normal_pseudo", tmp_path / "g.png")
        == {}
    )
    # where the misfit lies, over every wrong scene: the parts split the fitted pixels (no pixel twice, none left out)
    regions = order_failure_regions(ds, study, "texture/normal_pseudo", "val")
    for kind, part in regions["kinds"].items():
        ks = [k for k, (t, e) in enumerate(zip(records["true_order"], records["evidence"])) if f"{t}->{e}" == kind]
        assert part["scenes"] == len(ks) and part["pixels_fitted"] == sum(records["pixels"][k] for k in ks)
        assert sum(part["pixel_share"].values()) == pytest.approx(1.0)
        assert sum(part["reduction_share"].values()) == pytest.approx(1.0)
        assert set(part["pixel_share"]) == {"silhouette", "eyes and brows", "nose", "mouth", "rest"}
    assert {f"{t}->{e}" for t, e in wrong} == set(regions["kinds"])


def test_order_report_writes_its_figures_and_where_the_failures_misfit(tmp_path):
    """``task=order`` end to end on one cheap row (two faces a true order): the study, its accuracy figure, the
    registration figure, and for the order geometry's row the failure figure and, per split, the misfit by part
    of the face over exactly the scenes its records get wrong."""
    from disent.lighting.experiments import order_report

    study = order_report(tmp_path, "test", only=["texture/normal_pseudo"], n_per_order=2, geometry="normal_pseudo")
    assert set(study) == {"val/texture/normal_pseudo", "test/texture/normal_pseudo"}
    for name in ("order.json", "order_accuracy.png", "registration.png"):
        assert (tmp_path / name).stat().st_size > 100, name
    regions = json.loads((tmp_path / "order_failure_regions.json").read_text())
    assert set(regions) == {"val", "test"}
    for split, entry in regions.items():
        rec = study[f"{split}/texture/normal_pseudo"]["scenes"]
        wrong = sum(t != e for t, e in zip(rec["true_order"], rec["evidence"]))
        assert sum(kind["scenes"] for kind in entry.get("kinds", {}).values()) == wrong


def test_face_regions_lie_where_the_face_model_puts_its_parts():
    """The parts of the face read from a near-frontal face's true uv: eyes and brows above the nose above the mouth
    (image rows grow downwards), the eyes on both sides of the nose, no pixel in two parts, none off the face."""
    from disent.data import SynthFaces
    from disent.data.synth.face_model import face_regions

    item = SynthFaces("val", 64, 0)[0]  # yaw 1.8 deg
    regions = {
        k: v.numpy() & (item["matte"][0].numpy() > 0.5) for k, v in face_regions(item["uv"].permute(1, 2, 0)).items()
    }
    rows = {k: np.nonzero(v)[0].mean() for k, v in regions.items()}
    assert rows["eyes and brows"] < rows["nose"] < rows["mouth"], rows
    cols = np.nonzero(regions["eyes and brows"])[1]
    nose = np.nonzero(regions["nose"])[1].mean()
    assert (cols < nose).sum() > 10 and (cols > nose).sum() > 10
    assert sum(v.astype(int) for v in regions.values()).max() == 1
    off_face = face_regions(torch.tensor([[0.0, 0.5], [1.0, 0.5]]))  # the ends of the uv map: the sides of the head
    assert not any(v.any() for v in off_face.values())


def test_order_choice_speed_times_each_geometry_it_is_given():
    """A smoke run of the order choice's timing (no timing asserted): one positive time per geometry."""
    from disent.data import SynthFaces
    from disent.lighting.experiments import order_choice_speed

    times = order_choice_speed(SynthFaces("test", 64, size=1), 1, ("normal_pseudo_registered",))
    assert list(times) == ["normal_pseudo_registered"] and times["normal_pseudo_registered"] > 0


def test_texture_model_asked_by_threads_at_once_is_built_once(tmp_path, monkeypatch):
    """The prefetch workers of an ``sh_texture`` run ask for the texture model together on a machine without its disk
    cache: one thread builds and writes it, the others wait and load the same model."""
    from concurrent.futures import ThreadPoolExecutor

    from disent.lighting import texture

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    builds = []
    real_write = texture.atomic_write
    monkeypatch.setattr(texture, "atomic_write", lambda *a: (builds.append(1), real_write(*a)))
    texture.texture_model.cache_clear()
    try:
        with ThreadPoolExecutor(4) as pool:
            models = list(pool.map(lambda _: texture.texture_model(64, 5, 32), range(4)))
    finally:
        texture.texture_model.cache_clear()
    assert builds == [1]
    for m in models[1:]:
        np.testing.assert_array_equal(m.components, models[0].components)


def test_eroded_lhat_does_not_see_m_hats_rim():
    """loss.recon_L_target=sh_pseudo_eroded: L-hat fitted on M-hat eroded 1 px is blind to what M-hat's rim shows
    (paint it over and the light stays), where the paper's L-hat on all of M-hat moves."""
    from disent.data import SynthFaces, get_batch
    from disent.data.synth.scenes import fit_sh_packed
    from disent.lighting.experiments import EDGE, eroded, eroded_lhat

    g = get_batch(SynthFaces("test", size=4), range(4))
    rim = (g["mask_pseudo"] > 0.5) & (eroded(g["mask_pseudo"], EDGE) < 0.5)
    painted = {**g, "image": torch.where(rim, torch.tensor([0.9, 0.1, 0.1])[None, :, None, None], g["image"])}
    assert rim.any(dim=(1, 2, 3)).all()
    torch.testing.assert_close(eroded_lhat(painted), eroded_lhat(g), rtol=1e-6, atol=1e-7)
    lhat = [fit_sh_packed(b["image"], b["normal_pseudo"], b["mask_pseudo"]) for b in (g, painted)]
    assert (lhat[0] - lhat[1]).abs().max() > 1e-2
    torch.testing.assert_close(lhat[0].float(), g["sh_pseudo"], rtol=1e-4, atol=1e-5)  # the batch's own L-hat

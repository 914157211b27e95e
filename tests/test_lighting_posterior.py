"""The emcee posterior of L-hat (disent.lighting.posterior): its closed forms, calibration and speed."""

import json
import math

import numpy as np
import pytest
import torch

from disent.lighting.posterior import (
    LogPosterior,
    TruncatedT,
    gaussian_posterior,
    integrated_time,
    prepare,
    robust_fit,
    sample_posterior,
)
from disent.render import sh_shading
from tests.lighting_fakes import (
    directional_light,
    ellipsoid,
    render,
    textured_albedo,
)


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


def test_cli_writes_intervals_and_diagnostics(tmp_path):
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


def test_cli_order_choice_on_pseudo_geometry_uses_the_chosen_geometry(monkeypatch):
    """Without a known albedo on pseudo normals, the CLI's order choice scores the texture model on
    ``order_geometry`` (here the registered uv and eroded mask): the pixels it sees are that geometry's,
    not the posterior's whole pseudo mask."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.lighting.__main__ as cli
    from disent.data import SynthFaces
    from disent.lighting.geometry import GEOMETRY, coarse_fit_made_true, item_data

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


def test_lhat_sources_is_exact_with_every_input_made_true():
    """SynthFaces renders the face as albedo (.) S(n, L): least squares on the image over the true albedo, through
    the true normals, on the true face, returns the true light; the paper's L-hat does not."""
    from disent.data import SynthFaces
    from disent.lighting.sources import LHAT_SOURCES, ORACLE_MIXES, SHARPENING, lhat_sources

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


def test_a_photos_coarse_fit_is_drawn_again_and_its_placement_refined(monkeypatch):
    """A photo's landmark fit (its pseudo-GT ``params``) drawn again as SynthFaces' coarse-fit scene reproduces the
    photo's own pseudo-GT maps, so the placed geometry needs no SynthFaces scene: the CLI's order choice on a photo
    runs on it. The photo here: a SynthFaces render through the pipeline with its exact landmarks (no dlib)."""
    from pathlib import Path

    from omegaconf import OmegaConf

    import disent.data.photos.pseudo_gt as pg
    import disent.lighting.__main__ as cli
    from disent.data import SynthFaces
    from disent.lighting.geometry import coarse_fit_of, with_coarse_fit

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

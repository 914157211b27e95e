"""The lighting model order (disent.lighting.order): the evidence and BIC choose no more than a scene needs."""

import json

import numpy as np
import pytest
import torch

from disent.lighting.order import candidates, select_order
from disent.lighting.posterior import (
    prepare,
)
from tests.lighting_fakes import (
    directional_light,
    ellipsoid,
    feature_texture,
    render,
)


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


def test_chosen_noise_model_reads_the_study(tmp_path):
    """``auto`` takes the noise model of the study's row best on val for that albedo and geometry (only that geometry's
    rows, not those of a geometry whose name it begins), i.i.d. without one; a named model takes its constants from
    the study; an unknown model, or a residual process the study has no fit for, is refused by name."""
    from disent.lighting.order_study import chosen_noise_model, geometry_noise

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


def test_band2_share_closed_form():
    """Band 2's energy over bands 0 and 1: none for a light of order 1, and sums of squares per band otherwise."""
    from disent.lighting.order import band2_share

    light = np.zeros((3, 9))
    light[:, 0], light[:, 2] = 1.0, 0.5
    assert band2_share(light) == 0.0
    light[0, 4], light[2, 8] = 0.6, 0.8  # band 2: 0.36 + 0.64 = 1; bands 0-1: 3 x (1 + 0.25)
    assert band2_share(light) == pytest.approx(1.0 / 3.75)


def test_order_study_computes_only_the_named_rows_and_keeps_the_rest(tmp_path, monkeypatch):
    """``order_study(only=..., keep=...)``: the named rows are computed, every other row (and its residual fit) is
    copied from the earlier study, a computed row reads with the earlier study's fit of its geometry where it has
    one, and an unknown row name is refused with the list of rows."""
    import json

    from disent.lighting import order_study as experiments  # the study whose rows it runs

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


def test_order_accuracy_figure_draws_every_row_with_its_wilson_interval(tmp_path, monkeypatch):
    """The forest plot of the order study: each split's rows at their accuracy, the interval Wilson's over the
    row's scenes (one at accuracy 1 has its upper end at 1, not above), a row read on val alone kept."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from disent.lighting.order_study import plot_order_accuracy, wilson_interval

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
    from disent.lighting.order_study import order_confusion

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
    from disent.lighting.order import Whitener, score
    from disent.lighting.order_study import order_data

    data, texture = order_data(SynthFaces("val", 64, 0)[0], 0.02, 0, "texture", "normal")
    noise = {"texture": texture, "residual": (3.0, 1.0), "whitener": Whitener(data, 3.0, 1.0)}
    for order, gray in ((0, False), (1, True), (2, False)):
        gauss = score(data, order, gray, **noise)["log_evidence"]
        t = score(data, order, gray, **noise, nu=1e8)["log_evidence"]
        assert abs(t - gauss) < 0.05, (order, gauss, t)


def test_order_failures_refit_the_scenes_the_study_got_wrong(tmp_path):
    """The failure figure refits the first scene of each kind of error of a row, as the study fitted it: the choice
    it reads again is the record's, each kind of error appears once, and where the chosen order is larger than the
    truth its log evidence is above the true order's best (else the smaller model would have been chosen); the
    misfit's parts of the face (order_failure_regions) cover every wrong scene's fitted pixels once."""
    from disent.data import SynthFaces
    from disent.lighting.order_study import order_confusion, order_failure_regions, plot_order_failures

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


def test_the_lighting_tables_load_from_their_data_file_and_name_only_known_rows(tmp_path):
    """disent/lighting/tables.yaml: each order row names an albedo, a geometry of the table and a known noise
    model; ``edge`` reads as EDGE px in the erosion and the label; a row naming a missing field stops the load."""
    from disent.lighting.geometry import ALBEDO, EDGE, GEOMETRY, TABLES, Geometry, load_tables
    from disent.lighting.order_study import NOISE_MODELS, ORDER_ROWS

    assert all(isinstance(g, Geometry) and isinstance(g.made_true, tuple) for g in GEOMETRY.values())
    assert GEOMETRY["normal_pseudo_eroded"].erosion == EDGE and GEOMETRY["normal"].erosion == 0
    assert f"eroded {EDGE} px" in GEOMETRY["normal_pseudo_eroded"].label and "{edge}" not in str(GEOMETRY)
    assert GEOMETRY["oracle_shape"].made_true == ("shape",) and GEOMETRY["network_implicit"].network == "implicit"
    for albedo, geometry, *noise in ORDER_ROWS:
        assert albedo in ALBEDO and geometry in GEOMETRY and all(n in NOISE_MODELS for n in noise)
    broken = tmp_path / "tables.yaml"
    broken.write_text(TABLES.read_text().replace("    normals: normal\n", "    normal: normal\n", 1))
    with pytest.raises(TypeError):
        load_tables(broken)

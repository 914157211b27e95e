"""The lighting experiments (disent.lighting.experiments): geometries, L-hat's sources, the order study."""

import numpy as np
import pytest
import torch

from disent.lighting.posterior import (
    prepare,
)
from disent.runtime import single_core
from tests.lighting_fakes import directional_light, ellipsoid, render


def test_noise_parts_name_each_part_of_a_noise_model():
    """The noise models' names, parsed in one place: which of the geometry noise and the residual process each has,
    and a residual fit keyed by the geometry noise beside it."""
    from disent.lighting.order_study import NOISE_MODELS, fit_key, noise_parts

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


def test_residual_process_maximum_likelihood_finds_the_generating_constants():
    """Residuals drawn from the process with rho 3, ell 2 (and i.i.d. ones) on an ellipse's pixels: the grid's
    maximum likelihood is the generating point (rho 0 for the i.i.d. draws).  (A large rho leaves little white
    noise to tell 30 from 300 apart: the likelihood flattens there, as in the fit on SynthFaces.)"""
    from disent.lighting.order_study import max_likelihood_residual

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
    from disent.lighting.targets import eroded

    m = torch.zeros(2, 1, 8, 8)
    m[0, 0, 2:7, 1:6] = 1  # 5 x 5: 3 x 3 left
    m[1, 0, 1:4, 1:4] = 1  # 3 x 3: its centre left
    e = eroded(m, 1)
    assert e.shape == m.shape and e[0].sum() == 9 and e[1].sum() == 1
    assert torch.equal(e[0], eroded(m[0], 1)) and eroded(m[0, 0], 1).shape == (1, 8, 8)


def test_sharpened_albedo_is_exact_at_the_true_shading_alone():
    """SynthFaces' image is albedo (.) shading: over the true shading (k = 1) the detailed albedo is the truth up to
    scale; a more or a less contrasty shading leaves its contrast in the albedo."""
    from disent.data import SynthFaces, get_batch
    from disent.lighting.sources import sharpened_albedo
    from disent.regions import decomposed_region

    g = get_batch(SynthFaces("test", size=3), range(3))
    e = sharpened_albedo(g["image"], g["shading"], g["albedo"], decomposed_region(g), ks=(0.8, 1.0, 1.25))
    assert e[1.0] < 1e-6 < min(e[0.8], e[1.25])


def test_eroded_pseudo_mask_drops_exactly_the_edge_ring():
    from disent.lighting.geometry import GEOMETRY, item_data
    from disent.lighting.targets import eroded

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


def test_coarse_fit_made_true_renders_the_pseudo_maps_again():
    """Nothing made true renders the item's own pseudo maps; the true placement and shape together bring the
    pseudo normals towards the true ones, and each part alone changes the maps (the oracle rows' geometry)."""
    from disent.data import SynthFaces
    from disent.eval.metrics import normal_angular_error
    from disent.lighting.geometry import coarse_fit_made_true

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


def test_student_t_light_resists_outlying_pixels():
    """With 3 % of the pixels made brighter by 0.3 (specks the model cannot explain), the order-2 light fitted under
    Student-t noise (nu = 10) stays near the true light, while the Gaussian fit is pulled far off by them."""
    from dataclasses import replace

    from disent.data import SynthFaces
    from disent.lighting.order import score
    from disent.lighting.order_study import order_data

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
    from disent.lighting.order import fitted, score
    from disent.lighting.order_study import order_data

    item = SynthFaces("val", 64, 0)[0]
    data, _ = order_data(item, 0.01, 0, "known", "normal")
    rms = {o: np.sqrt(((data.y - fitted(data, score(data, o))) ** 2).mean()) for o in (0, 2)}
    assert 0.007 < rms[2] < 0.013, rms
    assert rms[0] > 3 * rms[2], rms


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


def test_eroded_lhat_does_not_see_m_hats_rim():
    """loss.recon_L_target=sh_pseudo_eroded: L-hat fitted on M-hat eroded 1 px is blind to what M-hat's rim shows
    (paint it over and the light stays), where the paper's L-hat on all of M-hat moves."""
    from disent.data import SynthFaces, get_batch
    from disent.lighting.targets import EDGE, eroded, eroded_lhat
    from disent.render import fit_sh_packed

    g = get_batch(SynthFaces("test", size=4), range(4))
    rim = (g["mask_pseudo"] > 0.5) & (eroded(g["mask_pseudo"], EDGE) < 0.5)
    painted = {**g, "image": torch.where(rim, torch.tensor([0.9, 0.1, 0.1])[None, :, None, None], g["image"])}
    assert rim.any(dim=(1, 2, 3)).all()
    torch.testing.assert_close(eroded_lhat(painted), eroded_lhat(g), rtol=1e-6, atol=1e-7)
    lhat = [fit_sh_packed(b["image"], b["normal_pseudo"], b["mask_pseudo"]) for b in (g, painted)]
    assert (lhat[0] - lhat[1]).abs().max() > 1e-2
    torch.testing.assert_close(lhat[0].float(), g["sh_pseudo"], rtol=1e-4, atol=1e-5)  # the batch's own L-hat

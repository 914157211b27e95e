"""Evaluation protocols and stability studies on an analytic stand-in for SynthFaces (tests/eval_fakes.py)."""

import math
import os

import pytest
import torch
from eval_fakes import FakeFaces, OracleModel
from torch.utils.data import default_collate

from disent.eval import protocols
from disent.eval import stability as st
from disent.eval.evaluate import evaluate_model
from disent.eval.protocols import sh_variance, sh_variance_protocol
from disent.eval.scoring import ceiling_share, metrics_from_outputs
from disent.regions import decomposed_region, face_mask


def test_sh_variance_matches_groupwise_var():
    g = torch.Generator().manual_seed(0)
    sh = torch.randn(30, 3, 9, generator=g, dtype=torch.float64)
    cond = torch.arange(30) % 4
    cond[-1] = 7  # a condition with a single image is skipped
    r = sh_variance(sh, cond)
    expected = torch.stack([sh[cond == c].var(0, unbiased=True) for c in range(4)]).mean((0, 1))
    assert torch.allclose(torch.tensor(r["per_coeff"], dtype=torch.float64), expected)
    assert r["mean"] == pytest.approx(expected.mean().item())
    assert r["n_conditions"] == 4 and r["n_images"] == 29
    pooled = sh[:29].var(0).mean()
    assert r["within_share"] == pytest.approx(expected.mean().item() / pooled.item())
    # estimates that depend on the condition only: zero within-condition variance, share 0
    assert sh_variance(sh[cond.clamp_max(3)], cond.clamp_max(3))["within_share"] == pytest.approx(0, abs=1e-12)
    # scaling the estimates scales the variance by s^2 but leaves the relative number alone
    r2 = sh_variance(3 * sh, cond)
    assert r2["mean"] == pytest.approx(9 * r["mean"]) and r2["relative"] == pytest.approx(r["relative"])
    with pytest.raises(ValueError):
        sh_variance(sh, cond[:5])


def test_sh_variance_protocol_orders_estimators():
    res = sh_variance_protocol(FakeFaces("lightbank"))["estimators"]
    assert res["true"]["mean"] == pytest.approx(0, abs=1e-12)  # one light per condition
    assert res["ls_oracle"]["mean"] < 1e-10 and res["ls_oracle"]["sh_error"] < 1e-10  # true normals and albedo
    # a constant albedo absorbs skin tone (variance across identities), bent normals add more
    assert res["ls_true"]["mean"] > 1e3 * res["ls_oracle"]["mean"]
    assert res["ls_pseudo"]["mean"] > res["ls_true"]["mean"]
    assert res["ls_pseudo"]["n_conditions"] == 4


def test_a_rerun_of_the_protocol_keeps_the_rows_it_does_not_measure_again():
    row = lambda v: {"mean": v, "relative": v, "sh_error": v}
    info = lambda model, seed, setting="(defaults)", run="/gone": {
        "model": model,
        "setting": setting,
        "seed": seed,
        "run": f"{run}/{model}_{seed}_{setting}",
    }
    old = {
        "estimators": {"ls_pseudo": row(1.0), "e0": row(0.1), "e1": row(0.2), "old long": row(0.3), "r": row(0.5)},
        "runs": {
            "e0": info("explicit", 0),
            "e1": info("explicit", 1),
            "old long": info("explicit", 0, "long"),
            "r": info("implicit", 0, run="/again"),  # the same folder measured again below
        },
    }
    new = {"estimators": {"ls_pseudo": row(1.0), "explicit s0 again": row(0.4), "again": row(0.6)}, "runs": {}}
    new["runs"]["explicit s0 again"] = info("explicit", 0, run="/elsewhere")
    new["runs"]["again"] = {**info("implicit", 0, run="/again"), "setting": "renamed since"}
    kept = protocols.keep_rows(new, old)
    # r: the same folder, replaced; the other folders are gone and have no record, so their settings of the day
    # cannot be read against today's conf/: e0 is not taken for today's run of the same label, and stays
    assert set(kept["estimators"]) == {"ls_pseudo", "explicit s0 again", "again", "e0", "e1", "old long"}
    assert kept["runs"]["old long"]["setting"] == "long" and kept["estimators"]["e1"] == row(0.2)


def test_a_kept_row_is_named_by_its_setting_today_so_a_changed_default_neither_merges_nor_replaces_it(tmp_path):
    """A row measured before a default changed (E_UV x1, then the default) is labelled "(defaults)" in the old
    JSON; today's "(defaults)" run of the same seed is another setting, so both rows stay, the old one renamed by
    what its record reads today."""
    from disent.runs import find_runs
    from tests.run_fakes import make_run

    x1 = make_run(tmp_path, "x1", "implicit", extra=("loss.weights.UV=1.0",), eval_={"recon_mse": 0.01})
    x10 = make_run(tmp_path, "x10", "implicit", eval_={"recon_mse": 0.01})
    row = lambda v: {"mean": v, "relative": v, "sh_error": v}
    label = "implicit (defaults) seed 0"
    old = {
        "estimators": {label: row(0.1)},
        "runs": {label: {"model": "implicit", "setting": "(defaults)", "seed": 0, "run": str(x1)}},
    }
    new = {"estimators": {label: row(0.2)}, "runs": {label: {**old["runs"][label], "run": str(x10)}}}
    kept = protocols.keep_rows(new, old, {r.id: r for r in find_runs([tmp_path])})
    then = "implicit loss.weights.UV=1.0 seed 0"
    assert kept["estimators"] == {label: row(0.2), then: row(0.1)}
    assert kept["runs"][then]["setting"] == "loss.weights.UV=1.0" and kept["runs"][label]["run"] == str(x10)
    # measured again under today's name (the same folder, or the same model, setting and seed): replaced
    again = {"estimators": {then: row(0.3)}, "runs": {then: {**kept["runs"][then], "run": str(tmp_path / "x1b")}}}
    assert protocols.keep_rows(again, kept, {r.id: r for r in find_runs([tmp_path])})["estimators"][then] == row(0.3)


def test_a_kept_row_of_a_run_gone_is_retyped_from_the_conf_its_json_was_written_against(tmp_path, monkeypatch):
    """No folder, no record: the row's label is read against the conf/ of the revision the JSON names (E_UV was
    another weight then), so it names that weight today; a row's own revision goes before the JSON's; a row no
    revision retypes keeps its label, marked so that a later JSON's revision does not retype it."""
    import shutil

    import disent.runs as runs_mod
    from disent.runs import CONF_DIR, composed_config

    today = composed_config(("model=implicit",))["loss"]["weights"]["UV"]
    then = tmp_path / "conf"
    shutil.copytree(CONF_DIR, then)
    loss = then / "loss" / "default.yaml"
    loss.write_text(loss.read_text().replace(f"  UV: {today}", f"  UV: {today + 5}", 1))
    monkeypatch.setattr(runs_mod, "conf_at", lambda revision: str(then) if revision == "fed4321" else None)
    row = {"mean": 0.1, "relative": 0.1, "sh_error": 0.1}
    gone = {"model": "implicit", "setting": "(defaults)", "seed": 2, "run": str(tmp_path / "gone")}
    old = {"estimators": {"implicit (defaults) seed 2": row}, "runs": {"implicit (defaults) seed 2": gone}}
    new = {"estimators": {}, "runs": {}}
    kept = protocols.keep_rows(new, {**old, "revision": "fed4321"})
    name = f"implicit loss.weights.UV={today + 5} seed 2"
    assert kept["estimators"] == {name: row} and kept["runs"][name]["setting"] == f"loss.weights.UV={today + 5}"
    unknown = protocols.keep_rows(new, old)  # no revision: as labelled then, and marked so
    assert (
        unknown["estimators"] == old["estimators"] and unknown["runs"]["implicit (defaults) seed 2"]["revision"] is None
    )
    again = protocols.keep_rows({**new, "revision": "fed4321"}, {**unknown, "revision": "fed4321"})
    assert again["estimators"] == old["estimators"]  # a later JSON's revision does not retype it
    own = {**old, "runs": {"implicit (defaults) seed 2": {**gone, "revision": "fed4321"}}}
    retyped = protocols.keep_rows(new, own)
    assert retyped["estimators"] == {name: row}  # the row's own revision retypes it
    assert "revision" not in retyped["runs"][name]  # now against today's conf/


def test_sh_variance_split_by_what_faces_show():
    """shown + hidden is the unbiased within-condition variance of the estimates scaled in shading (a share of
    ||true||^2), averaged over the conditions as sh_variance averages; estimates that differ within a condition
    only along each face's hidden SH direction have no shown variance."""
    from disent.eval.metrics import scale_in_shading, sh_gram
    from disent.eval.protocols import sh_variance_shown_hidden

    g = torch.Generator().manual_seed(0)
    ds = FakeFaces("lightbank")
    batch = default_collate([ds[i] for i in [*range(0, len(ds), 3), 1]])  # one condition a face larger
    gram, cond, truth = sh_gram(batch["normal"], face_mask(batch["matte"])), batch["light_id"], batch["sh"].double()
    sh = truth + 0.3 * torch.randn(truth.shape, generator=g, dtype=torch.float64)
    split = sh_variance_shown_hidden(sh, truth, gram, cond)
    x = scale_in_shading(sh, truth, gram)
    whole = []
    for c in cond.unique():
        xc = x[cond == c]
        whole.append((((xc - xc.mean(0)) ** 2).sum((1, 2)) / truth[cond == c].pow(2).sum((1, 2))).sum() / (len(xc) - 1))
    assert len({(cond == c).sum().item() for c in cond.unique()}) > 1  # conditions of unequal size
    assert split["shown"] + split["hidden"] == pytest.approx(sum(whole).item() / len(whole), rel=1e-9)
    assert split["shown"] > 0 and split["hidden"] > 0
    hidden_direction = torch.linalg.eigh(gram)[1][:, None, :, 0]  # [N, 1, 9]: each face's least shown direction
    wobble = truth + 0.3 * torch.randn(len(truth), 1, 1, generator=g, dtype=torch.float64) * hidden_direction
    only_hidden = sh_variance_shown_hidden(wobble, truth, gram, cond)
    assert only_hidden["shown"] < 1e-3 * only_hidden["hidden"]


def test_sh_variance_protocol_scores_the_mean_light_beside_the_estimators():
    """The constant mean light: no raw variance, its error that of a constant; the oracle's shown parts vanish."""
    ds = FakeFaces("lightbank")
    res = sh_variance_protocol(ds, mean_light=ds.bank.mean(0))["estimators"]
    assert res["mean_light"]["mean"] == pytest.approx(0, abs=1e-12) and res["mean_light"]["sh_error"] > 0.01
    assert res["mean_light"]["sh_error_shown"] + res["mean_light"]["sh_error_hidden"] > 0.01
    assert res["ls_oracle"]["variance_shown"] < 1e-10 and res["ls_oracle"]["sh_error_shown"] < 1e-10
    assert (
        res["ls_pseudo"]["variance_shown"] > res["ls_true"]["variance_shown"] > 1e3 * res["ls_oracle"]["variance_shown"]
    )


def test_sh_variance_protocol_needs_fixed_lights():
    with pytest.raises(ValueError, match="lightbank"):
        sh_variance_protocol(FakeFaces("test", size=6))


def test_perfect_model_scores_perfectly():
    ds = FakeFaces("test", size=6)
    m = evaluate_model(OracleModel(ds), ds, limit=6, batch_size=4)
    assert m["recon_mse"] == 0 and math.isinf(m["recon_face_psnr"])
    assert m["normal_mean"] == pytest.approx(0, abs=1e-3) and m["normal_under_20"] == 1.0
    assert m["pseudo_normal_mean"] > 1.0  # the bent pseudo normals are wrong on the same pixels
    assert m["normal_spread"] == pytest.approx(m["true_normal_spread"]) and m["normal_spread"] > 10
    assert m["albedo_si_mse"] < 1e-12 and m["sh_error"] < 1e-12 and m["n_eval"] == 6
    assert m["light_shading_si_mse"] < 1e-12 and m["albedo_detailed_si_mse"] < 1e-10
    assert m["infer_images_per_s"] > 0
    # the oracle's matte is the whole head: scored against the face region it covers, M-hat (the head here) alike
    assert m["matte_iou"] == m["pseudo_matte_iou"] and 0.3 < m["matte_iou"] < 0.95


def test_the_taught_light_is_scored_as_the_networks_own():
    """``light_target``: E_recon-L's target scored exactly as a network's own light would be (``target_*``): a model
    that draws the target as its light scores it so; the true light scores perfectly; nothing without it."""
    ds = FakeFaces("test", size=6)
    assert not any(k.startswith("target_") for k in evaluate_model(OracleModel(ds), ds, limit=6))
    noise = 0.3 * torch.randn(6, 3, 9, generator=torch.Generator().manual_seed(0))

    def bent(gt):  # the true light, its coefficients moved (items in order)
        return gt["sh"] + noise[: len(gt["sh"])]

    class Bent(OracleModel):  # the perfect model but for its light, the bent one
        def forward(self, image):
            out = super().forward(image)
            index = [next(i for i, it in enumerate(self.items) if torch.equal(it["image"], im)) for im in image]
            return {**out, "sh": out["sh"] + noise[index]}

    taught = evaluate_model(OracleModel(ds), ds, limit=6, light_target=bent)
    own = evaluate_model(Bent(ds), ds, limit=6)
    keys = ("light_shading_si_mse", "sh_error_shown", "sh_error_hidden", "light_pattern_corr", "light_log_error")
    for k in keys:
        assert taught[f"target_{k}"] == pytest.approx(own[k])
    assert taught["target_light_shading_si_mse"] > 1e-3 and taught["light_shading_si_mse"] < 1e-12  # its own is true
    true = evaluate_model(OracleModel(ds), ds, limit=6, light_target=lambda gt: gt["sh"])
    assert true["target_light_shading_si_mse"] < 1e-10 and true["target_light_pattern_corr"] == pytest.approx(1)


def test_normal_error_binned_by_the_pseudo_gts_own_error():
    from disent.eval.scoring import PSEUDO_ERROR_BINS, normal_metrics

    g = torch.Generator().manual_seed(0)
    true = torch.nn.functional.normalize(
        torch.randn(4, 3, 16, 16, generator=g) + torch.tensor([0, 0, 2.0])[:, None, None], dim=1
    )
    pseudo = torch.nn.functional.normalize(true + 0.4 * torch.randn(true.shape, generator=g), dim=1)
    gt = {
        "normal": true,
        "normal_pseudo": pseudo,
        "matte": torch.ones(4, 1, 16, 16),
        "mask_pseudo": torch.ones(4, 1, 16, 16),
    }
    bins = list(zip(PSEUDO_ERROR_BINS, PSEUDO_ERROR_BINS[1:]))
    m = normal_metrics(pseudo, gt)  # a network that returns the pseudo-GT scores as it does in every bin
    for lo, hi in bins:
        assert m[f"normal_mean_where_pseudo_{lo}_{hi}"] == pytest.approx(
            m[f"pseudo_normal_mean_where_pseudo_{lo}_{hi}"]
        )
        assert lo <= m[f"pseudo_normal_mean_where_pseudo_{lo}_{hi}"] < hi
    shares = [m[f"share_where_pseudo_{lo}_{hi}"] for lo, hi in bins]
    assert sum(shares) == pytest.approx(1.0)
    pooled = sum(s * m[f"pseudo_normal_mean_where_pseudo_{lo}_{hi}"] for s, (lo, hi) in zip(shares, bins))
    assert pooled == pytest.approx(m["pseudo_normal_mean"], rel=1e-5)  # the bins partition the scored pixels
    exact = normal_metrics(true, gt)
    assert all(exact[f"normal_mean_where_pseudo_{lo}_{hi}"] == pytest.approx(0, abs=0.05) for lo, hi in bins)


def test_detailed_albedo_carries_the_shading_error():
    """Sec. 5.3's detailed albedo, the image over the model's shading: exact with the true shading whatever the decoded
    albedo, blind to the shading's scale, and wrong where the shading is."""
    ds = FakeFaces("test", size=4)
    gt = default_collate([ds[i] for i in range(4)])
    flat = torch.full_like(gt["albedo"], 0.5)  # a decoded albedo that knows nothing
    error = lambda shading: metrics_from_outputs({"albedo": flat, "shading": shading}, gt)["albedo_detailed_si_mse"]
    assert error(gt["shading"]) < 1e-10 and error(2.0 * gt["shading"]) < 1e-10
    assert metrics_from_outputs({"albedo": flat}, gt)["albedo_si_mse"] > 1e-4
    ramp = 1 + torch.linspace(0, 1, gt["shading"].shape[-1])  # shading wrong by a left-right ramp
    assert error(gt["shading"] * ramp) > 1e-3


def test_detailed_albedo_with_one_shading_input_made_true_says_which_holds_it_back():
    """I / S(N, L) with the model's normals under the true light, and the model's light on the true normals: a model
    wrong only in its light is exact in the second and not in the first, and the other way round."""
    from disent.render import sh_shading

    ds = FakeFaces("test", size=4)
    gt = default_collate([ds[i] for i in range(4)])
    flat = torch.full_like(gt["albedo"], 0.5)
    turned = gt["sh"].clone()
    turned[:, :, 3] += 0.4  # the light turned sideways
    tilted = torch.nn.functional.normalize(gt["normal"] + torch.tensor([0.0, 0.5, 0.0])[:, None, None], dim=1)
    tilted = tilted * (gt["normal"].norm(dim=1, keepdim=True) > 0)

    def scores(normal, sh):
        out = {"albedo": flat, "normal": normal, "sh": sh, "shading": sh_shading(normal, sh)}
        m = metrics_from_outputs(out, gt)
        return m["albedo_detailed_true_light_si_mse"], m["albedo_detailed_true_normals_si_mse"]

    assert max(scores(gt["normal"], gt["sh"])) < 1e-10
    light_wrong, normals_wrong = scores(gt["normal"], turned), scores(tilted, gt["sh"])
    assert light_wrong[0] < 1e-10 < 1e-4 < light_wrong[1]
    assert normals_wrong[1] < 1e-10 < 1e-4 < normals_wrong[0]
    assert "albedo_detailed_true_light_si_mse" not in metrics_from_outputs(
        {"albedo": flat, "shading": gt["shading"]}, gt
    )


def test_intrinsic_layers_are_scored_where_the_model_renders_the_face():
    """albedo, shading and normals count on the true face inside the pseudo mask; hair and neck (outside
    M-hat, the model's background layer) only in ``albedo_face_si_mse``."""
    from disent.eval.scoring import metrics_from_outputs
    from disent.regions import decomposed_region

    ds = FakeFaces("test", size=4)
    gt = default_collate([ds[i] for i in range(4)])
    gt["mask_pseudo"][..., : gt["mask_pseudo"].shape[-2] // 2, :] = 0  # M-hat leaves out the top: "hair"
    region = decomposed_region(gt)
    outside = (face_mask(gt["matte"]) - region) > 0
    assert region.sum() > 0 and outside.any()
    albedo = torch.where(outside, torch.rand_like(gt["albedo"]), gt["albedo"] * 1.7)  # exact up to a scale inside
    m = metrics_from_outputs({"albedo": albedo, "normal": gt["normal"]}, gt)
    assert m["albedo_si_mse"] < 1e-12 and m["albedo_global_si_mse"] < 1e-12 and m["normal_mean"] < 1e-3
    assert m["albedo_face_si_mse"] > 1e-3
    # the light on the face: a colour cast (one scale per channel) is forgiven, a wrong direction is not
    tinted = gt["sh"] * torch.tensor([0.8, 1.0, 1.3])[None, :, None]
    turned = gt["sh"].clone()
    turned[:, :, 3] = -turned[:, :, 3] + 0.3  # the x component (left-right) flipped
    m = metrics_from_outputs({"sh": tinted, "normal": gt["normal"]}, gt)
    assert m["light_shading_si_mse"] < 1e-12 < m["sh_error"]
    assert m["light_contrast"] == pytest.approx(1, abs=1e-9)  # the truth's contrast at another colour
    assert m["light_pattern_corr"] == pytest.approx(1, abs=1e-9) and m["light_contrast_ratio"] == pytest.approx(1)
    assert metrics_from_outputs({"sh": turned, "normal": gt["normal"]}, gt)["light_shading_si_mse"] > 1e-4
    flat = gt["sh"].clone()
    flat[:, :, 1:] *= 0.5  # every direction at half strength: a flatter light, the same DC
    m = metrics_from_outputs({"sh": flat, "normal": gt["normal"]}, gt)
    assert m["light_contrast"] < 0.9 and m["light_contrast_ratio"] < 0.9 and m["light_pattern_corr"] > 0.98


def test_conditioning_grows_towards_profile():
    res = st.conditioning_vs_yaw(FakeFaces("test"), yaws=(0, 30, 60, 90), n=3)
    cond = [r["ls_true_cond"]["median"] for r in res["rows"]]
    assert all(b > a for a, b in zip(cond, cond[1:]))  # fewer, narrower normals as the head turns
    assert res["ls_true_blowup_yaw"] == 90  # this cap only degenerates at full profile


def test_shrink_mask_is_nested_and_sized():
    ds = FakeFaces("test", size=4)
    mask = face_mask(default_collate([ds[i] for i in range(4)])["matte"])
    prev = mask
    for f in (0.7, 0.3, 0.1):
        m = st.shrink_mask(mask, f)
        assert (m <= prev).all()  # a subset of the larger crop
        kept = m.flatten(1).sum(1)
        want = (mask.flatten(1).sum(1) * f).ceil()
        assert (kept >= want).all() and (kept <= want + 4).all()  # ties on the distance ring only
        prev = m
    res = st.conditioning_vs_mask(ds, fractions=(1.0, 0.3, 0.1, 0.01), n=4)
    assert "error" in res["rows"][-1]  # too few pixels is reported, not crashed
    cond = [r["ls_true_cond"]["median"] for r in res["rows"][:-1]]
    assert cond[0] < cond[1] < cond[2]


def test_tilt_light_closed_form():
    sh = FakeFaces("lightbank").bank[:2].double()
    assert torch.allclose(st.tilt_light(sh, 0.0), sh, atol=1e-9)
    flipped = st.tilt_light(sh, 1.0)  # 180 degrees about x: y -> -y, z -> -z
    sign = torch.tensor([1, -1, -1, 1, -1, 1, 1, -1, 1], dtype=torch.float64)
    assert torch.allclose(flipped, sh * sign, atol=1e-7)


def test_ood_noise_raises_least_squares_error():
    res = st.ood_curves(FakeFaces, {}, effects=("noise",), severities=(0.0, 1.0), n=6, resolution=16)
    e = res["effects"]["noise"]["ls_true"]["sh_error"]
    assert e[1] > 2 * e[0]


def test_bws_stats_closed_forms():
    ds = FakeFaces("test", size=3)
    gt = default_collate([ds[i] for i in range(3)])
    out = {"shading": torch.full_like(gt["shading"][:, :1], 0.75), "albedo": gt["shading"].clone()}
    s = st.bws_stats(out, gt)
    assert s["shading_mean_rgb"] == pytest.approx([0.75] * 3) and s["shading_cast"] == pytest.approx(0)
    assert s["albedo_shading_corr"] == pytest.approx(1.0)  # albedo that is the shading
    out["albedo"] = 1.0 - gt["shading"]
    assert st.bws_stats(out, gt)["albedo_shading_corr"] == pytest.approx(-1.0)
    m = metrics_from_outputs(out, gt)  # eval.json carries them for every rendering model (the ablation of BWS)
    assert m["albedo_shading_corr"] == pytest.approx(-1.0) and m["shading_cast"] == pytest.approx(0, abs=1e-6)


def test_bws_stats_tell_where_each_skin_went():
    """A shading that takes each face's skin tone (the true shading times the face's mean albedo colour) correlates
    fully with the skin over faces; the same colour given back to a white shading carries none of it."""
    ds = FakeFaces("test", size=12)
    gt = default_collate([ds[i] for i in range(12)])
    face = decomposed_region(gt)  # where the skin is read
    skin = (gt["albedo"] * face).sum((2, 3), keepdim=True) / face.sum((2, 3), keepdim=True)  # [B,3,1,1]
    assert skin.flatten(1).std(0).min() > 0  # the faces' skins differ in every channel
    white = gt["shading"].mean(1, keepdim=True)  # one gray shading per face
    s = st.bws_stats({"shading": white * skin, "albedo": gt["albedo"]}, gt)
    assert s["shading_albedo_tone_corr"] == pytest.approx(1.0)
    white_s = st.bws_stats({"shading": white, "albedo": gt["albedo"]}, gt)
    assert white_s["shading_albedo_tone_corr"] == pytest.approx(0.0, abs=1e-6)  # gray: no chromaticity varies
    luminance = lambda x: x.mean(1, keepdim=True)  # noqa: E731
    face_mean = (white * face).sum((2, 3), keepdim=True) / face.sum((2, 3), keepdim=True)
    brightness_only = white / face_mean * luminance(skin)  # its mean on the face: the skin's luminance
    assert st.bws_stats({"shading": brightness_only, "albedo": gt["albedo"]}, gt)[
        "shading_albedo_brightness_corr"
    ] == pytest.approx(1.0)


def test_albedo_ceiling_share_counts_pinned_values_inside_the_region():
    """Values at or above the ceiling, counted per pixel and channel, only inside the region; the metrics carry
    the model's share and the truth's."""
    albedo = torch.full((2, 3, 4, 4), 0.5)
    albedo[0, 0] = 0.99  # one channel of the first image pinned everywhere
    albedo[1, :, :2] = 1.0  # every channel of the second image's top half
    region = torch.zeros(2, 1, 4, 4)
    region[:, :, :, :2] = 1  # the left half of each image
    assert ceiling_share(albedo, region) == pytest.approx((8 + 3 * 4) / (2 * 3 * 8))
    assert ceiling_share(albedo, torch.zeros_like(region)) == 0.0
    assert ceiling_share(albedo, region, ceiling=1.0) == pytest.approx(12 / 48)  # >= : the exact 1s count
    ds = FakeFaces("test", size=2)
    gt = default_collate([ds[i] for i in range(2)])
    m = metrics_from_outputs({"albedo": torch.ones_like(gt["albedo"])}, gt)
    assert m["albedo_ceiling_share"] == 1.0
    assert m["true_albedo_ceiling_share"] == pytest.approx(ceiling_share(gt["albedo"], decomposed_region(gt)))


def test_metrics_from_outputs_baseline_has_only_recon():
    ds = FakeFaces("test", size=2)
    gt = default_collate([ds[i] for i in range(2)])
    m = metrics_from_outputs({"recon": gt["image"] * 0.5}, gt)
    assert set(m) == {f"{p}_{k}" for p in ("recon", "recon_face") for k in ("mse", "psnr", "ssim")}


def test_plots_write_pngs(tmp_path):
    from disent.eval.protocols import plot_sh_variance

    ds = FakeFaces("test", size=4)
    yaw = st.conditioning_vs_yaw(ds, yaws=(0, 90), n=2)
    mask = st.conditioning_vs_mask(ds, fractions=(1.0, 0.5), n=2)
    st.plot_conditioning(yaw, mask, tmp_path / "c.png")
    st.plot_ood(
        st.ood_curves(FakeFaces, {}, effects=("noise",), severities=(0.0, 1.0), n=2, resolution=16), tmp_path / "o.png"
    )
    gt = default_collate([ds[i] for i in range(2)])
    row = {"bws": True, "batch_size": 20, **st.bws_stats({"shading": gt["shading"], "albedo": gt["albedo"]}, gt)}
    st.plot_bws({"rows": [row, {**row, "bws": False}]}, tmp_path / "b.png")
    plot_sh_variance(sh_variance_protocol(FakeFaces("lightbank")), tmp_path / "v.png")
    assert all((tmp_path / f).stat().st_size > 5000 for f in ("c.png", "o.png", "b.png", "v.png"))


def test_bws_budgets_split_fixed_steps_from_fixed_images():
    rows = [{"batch_size": b, "steps": 400} for b in (1, 5, 25)]
    assert [label for label, _ in st.bws_budgets(rows)] == ["400 steps"]
    rows += [{"batch_size": 1, "steps": 10000}, {"batch_size": 5, "steps": 2000}]
    (steps_label, same_steps), (images_label, same_images) = st.bws_budgets(rows)
    assert (steps_label, images_label) == ("400 steps", "10,000 images")
    assert [(r["batch_size"], r["steps"]) for r in rows if same_steps(r)] == [(1, 400), (5, 400), (25, 400)]
    # batch 25's 400 steps are on both lines: it is where the two budgets meet
    assert [(r["batch_size"], r["steps"]) for r in rows if same_images(r)] == [(25, 400), (1, 10000), (5, 2000)]


def test_sh_variance_of_a_model_and_baseline_skipped():
    ds = FakeFaces("lightbank")

    class NoLight(torch.nn.Module):  # like the baseline: recon only
        def forward(self, image):
            return {"recon": image}

    res = sh_variance_protocol(ds, {"oracle": OracleModel(ds), "baseline": NoLight()})["estimators"]
    assert "baseline" not in res
    assert res["oracle"]["mean"] == pytest.approx(0, abs=1e-12) and res["oracle"]["sh_error"] < 1e-12


def test_trivial_baselines_are_dataset_means():
    """The dataset-mean maps: exact on a data set of one repeated face, per-pixel means on a mix, and
    scored by the same metrics as a network (an oracle beats them; the constant scores as itself)."""
    from disent.eval.trivial import dataset_means, trivial_metrics, trivial_outputs

    one = torch.utils.data.Subset(FakeFaces("train", size=1), [0, 0, 0])
    means = dataset_means(one)
    gt = default_collate([one[0]])
    face = face_mask(gt["matte"])[0] > 0
    torch.testing.assert_close(means["normal"][:, face[0]], gt["normal"][0][:, face[0]])
    torch.testing.assert_close(means["sh"], gt["sh"][0])
    assert trivial_metrics(means, gt)["trivial_normal_mean"] == pytest.approx(0, abs=1e-3)
    assert trivial_metrics(means, gt)["trivial_sh_error"] == pytest.approx(0, abs=1e-10)
    assert trivial_metrics(means, gt)["trivial_matte_iou"] == 1  # one face: the mean region is its region
    torch.testing.assert_close(means["sh_pseudo"], gt["sh_pseudo"][0])  # the mean L-hat, for context
    assert trivial_metrics(means, gt)["trivial_lhat_sh_error"] == pytest.approx(
        metrics_from_outputs({"sh": gt["sh_pseudo"]}, gt)["sh_error"]
    )

    ds = FakeFaces("test", size=12)
    means = dataset_means(ds, n=12)
    batch = default_collate([ds[i] for i in range(12)])
    f = face_mask(batch["matte"])
    expect = (batch["albedo"] * f).sum(0) / f.sum(0)
    covered = f.sum(0)[0] > 0
    torch.testing.assert_close(means["albedo"][:, covered], expect[:, covered])
    assert torch.all(means["normal"][:, ~covered] == torch.tensor([0.0, 0.0, 1.0])[:, None])
    torch.testing.assert_close(means["normal"].norm(dim=0), torch.ones(means["normal"].shape[1:]))
    t = trivial_metrics(means, batch)
    # the fake's visible normals are the same sphere whatever the yaw (only the matte turns): the mean map is exact;
    # its lights vary, so the mean light is not
    assert t["trivial_normal_mean"] < 1e-3 and t["trivial_sh_error"] > 0.01
    oracle = evaluate_model(OracleModel(ds), ds, limit=12, trivial=means)
    assert oracle["trivial_sh_error"] == pytest.approx(t["trivial_sh_error"])
    assert oracle["sh_error"] < 1e-12 < oracle["trivial_sh_error"]
    same = metrics_from_outputs(trivial_outputs(means, 12), batch)  # the constant scored as a model: the same numbers
    assert same["normal_mean"] == pytest.approx(t["trivial_normal_mean"]) and "recon_mse" not in same
    # the mean face region: the share of faces covering each pixel; cut at 0.5 it is the majority region
    f = batch["mask_face"]
    torch.testing.assert_close(means["mask_face"], f.mean(0))
    majority = (f.mean(0, keepdim=True) > 0.5).expand_as(f)
    assert t["trivial_matte_iou"] == pytest.approx(((majority & (f > 0.5)).sum() / (majority | (f > 0.5)).sum()).item())


def test_template_is_the_mean_uv_albedo_placed_by_the_true_uv():
    """The template floor: a face's own UV-space albedo placed through its true uv is its albedo (SynthFaces
    renders it so), so a template built from that face alone scores 0 on it, and not on another identity's."""
    from disent.data import SynthFaces
    from disent.eval.trivial import TEMPLATE_KEYS, dataset_means, trivial_metrics

    ds = SynthFaces("train", 64, 0, size=8)
    assert ds[0]["identity"] != ds[7]["identity"]
    means = dataset_means(torch.utils.data.Subset(ds, [0, 0]))
    assert means["albedo_uv"].shape == ds[0]["albedo_uv"].shape
    own, other = (trivial_metrics(means, default_collate([ds[i]])) for i in (0, 7))
    for key in TEMPLATE_KEYS:
        assert own[f"template_{key}"] < 1e-12 < 1e-4 < other[f"template_{key}"]
    # the mean UV map of one face is its own UV map: exact on it, off on a face of another pose and shape
    assert own["trivial_uv_error"] < 1e-6 < 1e-3 < other["trivial_uv_error"]
    fake = FakeFaces("test", size=2)  # no UV-space albedo: no template
    plain = dataset_means(fake, n=2)
    assert "albedo_uv" not in plain
    assert not any(k.startswith("template_") for k in trivial_metrics(plain, default_collate([fake[0], fake[1]])))


def test_pareto_front_keeps_the_points_nothing_beats_on_both_axes():
    from disent.eval.methods import pareto

    points = [(0.0, 17.0), (1e-3, 10.7), (1e-2, 10.7), (2e-2, 10.5), (0.2, 27.0), (1e-3, 12.0)]
    assert pareto(points, higher_better=False) == [0, 1, 3]  # (1e-2, 10.7) is beaten by (1e-3, 10.7)
    assert pareto([(1.0, 24.0), (2.0, 27.0), (3.0, 26.0)], higher_better=True) == [0, 1]


def test_methods_plane_scores_each_estimator_on_the_same_images(tmp_path):
    """A tiny run of python -m disent.eval.methods (no networks, no posterior): every row carries its time per
    image and its metrics, the constants take no time, and the coarse fit beats the mean normal map."""
    import json

    from disent.eval.methods import main

    main(["--n", "6", "--runs", "--posterior", "0", "--out", str(tmp_path)])
    res = json.loads((tmp_path / "methods.json").read_text())
    rows = res["rows"]
    assert res["n"] == 6 and (tmp_path / "methods.png").exists()
    assert res["load"]["cpus"] == os.cpu_count() and res["load"]["before"] >= 0 and res["load"]["after"] >= 0
    mean, coarse = rows["mean map / mean light"], rows["coarse fit (simulated pseudo-GT)"]
    assert mean["seconds_per_image"] == 0.0 and mean["constant"]
    assert coarse["seconds_per_image"] > 0 and coarse["normal_mean"] < mean["normal_mean"]
    assert rows["L-hat on the coarse fit"]["sh_error"] == pytest.approx(coarse["sh_error"])  # the same L-hat


def test_yaw_effect_turns_every_face_to_the_severity_s_yaw():
    from disent.data import SynthFaces
    from disent.eval import stability as st

    batch = st.ood_batch(SynthFaces, "yaw", 0.5, n=3, resolution=64)
    assert torch.allclose(batch["pose"][:, 0].float(), torch.full((3,), 0.5 * st.MAX_YAW))
    assert torch.allclose(batch["pose"][:, 1:].float(), torch.zeros(3, 2))
    assert "yaw" in st.EFFECTS


def test_scale_effect_shrinks_every_face_and_its_pseudo_fit():
    from disent.data import SynthFaces
    from disent.eval import stability as st

    clean, half = (st.ood_batch(SynthFaces, "scale", s, n=4, resolution=64) for s in (0.0, 0.5))
    k = (1 - 0.5 * st.MAX_SHRINK) ** 2  # areas go with the square of the scale
    for key in ("matte", "mask_pseudo"):
        ratio = (half[key] > 0.5).float().sum((1, 2, 3)) / (clean[key] > 0.5).float().sum((1, 2, 3))
        assert torch.allclose(ratio, torch.full_like(ratio, k), atol=0.08), (key, ratio)
    assert torch.equal(clean["pose"], half["pose"]) and torch.equal(clean["sh"], half["sh"])  # only the scale


def test_stability_studies_without_runs_write_nothing(tmp_path):
    """A study whose sweeps are absent writes no JSON, so publishing its folder cannot replace a published
    study with an empty one."""
    from disent.eval import stability as st

    none = str(tmp_path / "no_runs")
    st.main(
        ["bws", "training", "--bws-roots", none, "--training-roots", none, "--n", "2", "--out", str(tmp_path / "o")]
    )
    assert not (tmp_path / "o" / "bws.json").exists() and not (tmp_path / "o" / "training.json").exists()


def test_first_past_finds_the_first_value_beyond_the_factor_or_not_finite():
    assert st.first_past([0, 1, 2], [1.0, 1.4, 2.0], 1.0, factor=1.5) == 2
    assert st.first_past([0, 1, 2], [1.0, float("nan"), 2.0], 1.0, factor=1.5) == 1
    assert st.first_past([0, 1, 2], [1.0, 5.0, 9.0], 1.0) is None  # the default factor is BLOWUP (10)


def test_sh_variance_groups_put_the_seeds_of_a_setting_in_one_bar():
    from disent.eval.protocols import CHECKS, sh_variance_groups

    row = {"per_coeff": [1.0] * 9, "mean": 1.0, "relative": 0.5}
    est = {"ls_pseudo": row, "explicit a seed 0": row, "explicit a seed 1": row, **{c: row for c in CHECKS}}
    runs = {f"explicit a seed {s}": {"model": "explicit", "setting": "a", "seed": s} for s in (0, 1)}
    groups = sh_variance_groups({"estimators": est, "runs": runs})
    assert {k: len(v) for k, v in groups.items()} == {"ls_pseudo": 1, "explicit a": 2}
    assert set(sh_variance_groups({"estimators": est})) == {"ls_pseudo", "explicit a seed 0", "explicit a seed 1"}


def test_uv_metrics_score_the_uv_map_and_the_uv_space_normals_apart():
    """The implicit model's UV map and its UV-space normals, scored apart: at the true UV the looked-up normals are
    the model's own; a UV map off by (0.03, 0.04) is 0.05 off and moves the model's normals, not the looked-up ones."""
    from disent.data import SynthFaces
    from disent.models.implicit import sample_uv
    from disent.render import unit

    gt = SynthFaces("test", 64, 0).get_batch(range(4))
    g = torch.Generator().manual_seed(0)
    normal_uv = unit(torch.nn.functional.interpolate(torch.randn(4, 3, 4, 4, generator=g), size=64, mode="bilinear"))
    normal_uv[:, 2] = normal_uv[:, 2].abs() + 0.5  # facing the camera, smooth
    normal_uv = unit(normal_uv)

    def metrics(uv):
        out = {"uv": uv, "normal_uv": normal_uv, "normal": unit(sample_uv(normal_uv, uv))}
        return metrics_from_outputs(out, gt)

    exact = metrics(gt["uv"])
    assert exact["uv_error"] == 0 and exact["normal_at_true_uv_mean"] == pytest.approx(exact["normal_mean"], abs=1e-4)
    shifted = metrics(gt["uv"] + torch.tensor([0.03, 0.04])[None, :, None, None])
    assert shifted["uv_error"] == pytest.approx(0.05, rel=1e-5)
    assert shifted["normal_at_true_uv_mean"] == pytest.approx(exact["normal_at_true_uv_mean"], abs=1e-6)
    assert abs(shifted["normal_mean"] - exact["normal_mean"]) > 0.1
    # E_UV's target, scored as the model's UV map is: the distance a model whose UV map were the pseudo one would have
    pseudo = metrics(gt["uv_pseudo"])
    assert exact["pseudo_uv_error"] == pseudo["uv_error"] == pseudo["pseudo_uv_error"] > 0.001
    assert "normal_at_true_uv_mean" not in metrics_from_outputs({"uv": gt["uv"]}, gt)  # no UV-space normals


def test_region_depth_counts_rings_from_the_edge_of_a_square():
    """A 7x7 square's chessboard depth: 1 on its border ring, 2 on the next, 4 at its centre; 0 outside, and the
    image border counts as outside."""
    from disent.eval.metrics import region_depth

    mask = torch.zeros(1, 1, 11, 11)
    mask[..., 2:9, 2:9] = 1
    depth = region_depth(mask, 10)
    assert depth[0, 0, 5, 5] == 4 and depth[0, 0, 2, 2] == 1 and depth[0, 0, 3, 4] == 2 and depth[0, 0, 0, 0] == 0
    assert region_depth(mask, 2).max() == 2  # capped
    assert region_depth(torch.ones(1, 1, 5, 5), 10)[0, 0, 0].tolist() == [1, 1, 1, 1, 1]


def test_matte_edge_metrics_say_where_the_matte_is_soft_and_compare_it_with_m_hat():
    """A matte equal to M-hat has M-hat's mean on the edge band; a matte soft only on the region's outer ring is
    soft on the whole edge band's first ring and nowhere inside."""
    from disent.eval.scoring import matte_edge_metrics

    face = torch.zeros(2, 1, 16, 16)
    face[..., 3:13, 3:13] = 1
    m_hat = face.clone()
    m_hat[0, :, 3] = 0  # M-hat misses one row of the first face's edge
    gt = {"mask_face": face, "mask_pseudo": m_hat}
    same = matte_edge_metrics(m_hat, gt)
    assert same["matte_mean_edge"] == same["pseudo_matte_mean_edge"] < 1
    assert same["matte_soft_inner"] == 0
    soft_ring = face.clone()
    soft_ring[..., 3:13, 3:13][..., [0, -1], :] = 0.5
    soft_ring[..., 3:13, 3:13][..., :, [0, -1]] = 0.5
    m = matte_edge_metrics(soft_ring, gt)
    ring, band = 4 * 9, 4 * 9 + 4 * 7  # pixels of the outer ring and of the 2-px edge band of a 10x10 square
    assert m["matte_soft_edge"] == pytest.approx(ring / band) and m["matte_soft_inner"] == 0
    assert m["matte_mean_edge"] == pytest.approx(1 - 0.5 * ring / band)

"""The report's ablation sections (disent.report.ablations, disent.eval.ablation) on tiny fake runs."""

import math
import re

import pytest

from disent import report
from disent.eval.ablation import ablation_table, to_markdown
from disent.report import ablations, tables, targets
from disent.runs import composed_config, find_runs
from tests.run_fakes import fake_suite, make_run


def test_ablation_table_mean_std(tmp_path):
    fake_suite(tmp_path)
    t = ablation_table(find_runs([tmp_path]))
    rows = {r["variant"]: r for r in t["rows"]}
    assert list(rows)[:2] == ["baseline", "explicit"]
    e = rows["explicit"]
    assert e["recon_mse"]["mean"] == pytest.approx(0.03) and e["recon_mse"]["std"] == pytest.approx(math.sqrt(2) * 0.01)
    assert e["seeds"] == [0, 1]
    assert rows["implicit"]["failed"] == {"diverged": 1, "incomplete": 1}
    md = to_markdown(t)
    steps = composed_config(("+experiment=smoke",))["train"]["max_steps"]
    assert "0.03000 ± 0.01414" in md and f"train.max_steps={steps}" in md and "experiment=smoke" in md


def test_a_seed_run_twice_is_one_seed_not_two(tmp_path):
    """Runs of one setting and seed (trained again at another revision) are replicates: averaged into one value
    per seed, the count says seeds and runs; the same seed number under another setting is another seed."""
    smoke = ("+experiment=smoke",)
    for name, seed, err in (("a0", 0, 10.0), ("b0", 0, 12.0), ("a1", 1, 17.0)):
        make_run(tmp_path, name, "explicit", seed=seed, eval_={"normal_mean": err}, extra=smoke)
    make_run(tmp_path, "i0", "implicit", seed=0, eval_={"normal_mean": 14.0}, extra=smoke)
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    explicit = [runs[k] for k in ("a0", "b0", "a1")]
    st = tables.seed_spread(explicit, "normal_mean")
    assert st["n"] == 2 and st["runs"] == 3 and st["mean"] == pytest.approx(14.0)  # seeds 11 and 17
    assert st["std"] == pytest.approx(math.sqrt(18.0))
    assert tables.spread_text(st) == "14.00 ± 4.24 (n=2; 3 runs)" and tables.seeds_cell(explicit) == "2 (3 runs)"
    pooled = tables.seed_spread([*explicit, runs["i0"]], "normal_mean")  # implicit seed 0 is not explicit's
    assert pooled["n"] == 3 and pooled["mean"] == pytest.approx((11.0 + 17.0 + 14.0) / 3)
    once = tables.seed_spread([runs["a0"], runs["a1"]], "normal_mean")
    assert tables.spread_text(once) == "13.50 ± 4.95 (n=2)" and tables.seeds_cell([runs["a0"], runs["a1"]]) == "2"
    row = {r["variant"]: r for r in ablation_table(explicit)["rows"]}["explicit"]
    assert row["seeds"] == [0, 1] and row["runs"] == 3 and row["normal_mean"]["n"] == 2


def test_ablation_section_keeps_runs_of_other_settings_apart(tmp_path):
    """Runs with another override (here the normalisation) get their own table: never pooled with the defaults."""
    for seed in range(2):
        make_run(tmp_path, f"d{seed}", seed=seed, eval_={"recon_mse": 0.01, "normal_mean": 12.0})
        make_run(
            tmp_path, f"n{seed}", seed=seed, eval_={"recon_mse": 0.03, "normal_mean": 13.0}, extra=["model.norm=none"]
        )
    rep = report.Report(tmp_path)
    report.sec_ablation(rep, find_runs([tmp_path]))
    text = "\n".join(rep.lines)
    assert "### (defaults)" in text and "### `model.norm=none`" in text
    defaults, norm_none = text.split("### `model.norm=none`")
    assert (
        "| explicit | 2/2 | **0.01000 ± 0.00000** |" in defaults.split("### (defaults)")[1] and "0.03" not in defaults
    )
    assert "| explicit | 2/2 | **0.03000 ± 0.00000** |" in norm_none


def test_budget_check_names_each_missed_target(tmp_path):
    from disent.report.ablations import budget_check

    good = {"normal_mean": 12.0, "recon_face_psnr": 26.5, "albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    run = find_runs([make_run(tmp_path, "a", eval_=good).parent])[0]
    assert "meets every target" in budget_check([run])
    bad = {**good, "normal_mean": 13.0, "albedo_si_mse": 0.01}
    run = find_runs([make_run(tmp_path, "b", eval_=bad).parent])
    text = budget_check([r for r in run if r.path.name == "b"])
    assert "normals 13.00 deg" in text and "albedo 0.79" in text and "face PSNR" not in text and "not testable" in text
    assert "no finished full explicit run" in budget_check([])
    near = {**good, "albedo_si_mse": 0.5016 * 0.0127}  # a hair past the target: more digits, never "0.50"
    run = find_runs([make_run(tmp_path, "c", eval_=near).parent])
    assert "albedo 0.502 of the mean map's" in budget_check([r for r in run if r.path.name == "c"])
    oracle = find_runs([make_run(tmp_path, "d", eval_=good, extra=["loss.recon_L_oracle_mix=0.75"]).parent])
    text = budget_check([r for r in oracle if r.path.name == "d"])  # meets them fed the truth: says so
    assert "meets every target" in text and "fed the true light" in text and "not the paper's model" in text
    assert "fed the true light" not in budget_check([r for r in oracle if r.path.name == "a"])
    drawn = ("loss.recon_L_target=sh_network_texture", "loss.recon_L_network=implicit")  # no truth, not the paper's
    runs = find_runs([make_run(tmp_path, "e", eval_=good, extra=drawn).parent])
    text = budget_check([r for r in runs if r.path.name == "e"])
    assert "meets every target" in text and "`loss.recon_L_target=sh_network_texture`; no truth" in text
    assert "paper's L-hat" not in budget_check([r for r in runs if r.path.name == "a"])


def test_ablation_claims_pair_each_ablation_with_the_full_model_and_gate_on_the_budget(tmp_path):
    """Claim 4: an ablation's runs meet the full model's runs of the same setting on the paper's metric; the
    difference is read by the claims' rule, and becomes a verdict only where the full model meets the targets."""
    good = {"normal_mean": 12.0, "recon_face_psnr": 26.5, "albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    for seed in range(3):
        make_run(tmp_path, f"full{seed}", seed=seed, eval_={**good, "normal_mean": 12.0 + 0.1 * seed})
        make_run(
            tmp_path, f"nopn{seed}", ablations=["no_pseudo_normal"], seed=seed, eval_={**good, "normal_mean": 15.0}
        )
    runs = find_runs([tmp_path])
    rep = report.Report(tmp_path)
    ablations.claim_ablations(rep, runs)
    row = next(line for line in rep.lines if "| no_pseudo_normal |" in line)
    assert "| 12.1 ± 0.1 (n=3) | 15 ± 0 (n=3) | **confirmed** | **confirmed** |" in row, row
    assert sum("| no_pseudo_normal |" in line for line in rep.lines) == 1  # one claim on this ablation's metric
    for r in runs:  # the same runs where the full model misses the normal target: measured, but no verdict
        if r.path.name.startswith("full"):
            r.eval["normal_mean"] += 1.0
    rep = report.Report(tmp_path)
    ablations.claim_ablations(rep, runs)
    row = next(line for line in rep.lines if "| no_pseudo_normal |" in line)
    assert row.endswith("| **confirmed** | not testable (targets missed: 1 of 3) |"), row
    rep = report.Report(tmp_path)
    ablations.claim_ablations(rep, [r for r in runs if r.path.name.startswith("full")])
    assert "no finished ablation runs" in "\n".join(rep.lines)


def test_an_ablation_stands_against_every_full_model_it_trains_as(tmp_path):
    """``+ablation=no_bws`` uses neither BWS nor the whitened L-hat, so c is idle for it: its runs stand against the
    full model at c = 0.3 as well as at the default c, and not against a full model that differs from them in a
    setting they use (the smoothness weight)."""
    good = {"normal_mean": 12.0, "recon_face_psnr": 26.5, "albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    for seed in range(3):  # shading casts exact in binary, so each arm's spread prints as 0
        make_run(tmp_path, f"full{seed}", seed=seed, eval_={**good, "shading_cast": 0.125})
        make_run(tmp_path, f"c{seed}", seed=seed, eval_={**good, "shading_cast": 0.25}, extra=("loss.bws_c=0.3",))
        make_run(tmp_path, f"tv{seed}", seed=seed, eval_=good, extra=("loss.weights.smooth_A=0.5",))
        make_run(tmp_path, f"nobws{seed}", ablations=["no_bws"], seed=seed, eval_={**good, "shading_cast": 0.5})
    rep = report.Report(tmp_path)
    ablations.claim_ablations(rep, find_runs([tmp_path]))
    rows = {line.split("|")[1].strip(): line for line in rep.lines if "| shading cast |" in line}
    assert set(rows) == {"`model=explicit`", "`loss.bws_c=0.3 model=explicit`"}, rows
    assert "| 0.25 ± 0 (n=3) | 0.5 ± 0 (n=3) | **confirmed** |" in rows["`loss.bws_c=0.3 model=explicit`"]
    assert "| 0.125 ± 0 (n=3) | 0.5 ± 0 (n=3) | **confirmed** |" in rows["`model=explicit`"]


def test_no_pseudo_light_names_the_light_target_it_takes_away(tmp_path):
    """Without E_recon-L no target guides the light, so the no_pseudo_light runs stand against the full model of
    every E_recon-L target; each row says which target the full model learnt from (L-hat, the true light, a dose
    between them)."""
    good = {"normal_mean": 12.0, "recon_face_psnr": 26.5, "albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    for seed in range(3):
        make_run(tmp_path, f"full{seed}", seed=seed, eval_={**good, "light_shading_si_mse": 0.005, "sh_error": 0.5})
        for name, light, target in (
            ("o", 0.003, "loss.recon_L_target=sh"),
            ("m", 0.004, "loss.recon_L_oracle_mix=0.5"),
        ):
            make_run(
                tmp_path, f"{name}{seed}", seed=seed, eval_={**good, "light_shading_si_mse": light}, extra=(target,)
            )
        make_run(
            tmp_path,
            f"npl{seed}",
            ablations=["no_pseudo_light"],
            seed=seed,
            eval_={**good, "light_shading_si_mse": 0.01, "sh_error": 0.375},
        )
    rep = report.Report(tmp_path)
    ablations.claim_ablations(rep, find_runs([tmp_path]))
    reasons = {
        line.split("|")[1].strip(): line.split("|")[3].strip()
        for line in rep.lines
        if "| no_pseudo_light |" in line and "| light on the face |" in line
    }
    # the SH error: read against the full model scored with it; the other full models were scored before it
    sh = [line for line in rep.lines if "| SH error, every direction |" in line]
    assert len(sh) == 1 and sh[0].startswith("| `model=explicit` |") and "| 0.5 ± 0 (n=3) | 0.375 ± 0 (n=3) |" in sh[0]
    assert "| **refuted** |" in sh[0]  # without E_recon-L lower here: the rule reads it either way
    assert reasons == {
        "`model=explicit`": "L-hat guides the light (Eq. 9)",
        "`loss.recon_L_target=sh model=explicit`": "the true light in L-hat's place guides the light (Eq. 9)",
        "`loss.recon_L_oracle_mix=0.5 model=explicit`": "L-hat moved 0.5 of the way to the true light guides the "
        "light (Eq. 9)",
    }, reasons


def test_skin_table_keeps_settings_apart_and_quotes_the_truth(tmp_path):
    """Where each face's skin goes: one row per setting and model (the gray L-hat target is its own setting), mean
    and spread over seeds, each floor beside its si-MSE and the true shading's correlations in the caption; runs
    scored before the metrics existed are left out."""
    truth = {
        "true_shading_albedo_tone_corr": -0.02,
        "true_shading_albedo_brightness_corr": 0.08,
        "true_albedo_ceiling_share": 0.0012,
    }
    floors = {"trivial_albedo_colour_si_mse": 0.013, "trivial_shading_colour_si_mse": 0.021}

    def skin(tone):
        return {"shading_albedo_tone_corr": tone, "shading_albedo_brightness_corr": 0.8, **truth, **floors}

    skin_metrics = {"albedo_colour_si_mse": 0.008, "shading_colour_si_mse": 0.007}
    for seed in range(2):
        make_run(tmp_path, f"paper{seed}", seed=seed, eval_={**skin(0.7 + 0.1 * seed), **skin_metrics})
        make_run(
            tmp_path, f"gray{seed}", seed=seed, eval_={**skin(0.1), **skin_metrics}, extra=("loss.lhat_gray=true",)
        )
    make_run(tmp_path, "old", seed=2, eval_={"normal_mean": 12.0}, extra=("loss.lhat_gray=true",))
    rep = report.Report(tmp_path)
    ablations.claim_skin(rep, find_runs([tmp_path]))
    rows = {line.split("|")[1].strip(): line for line in rep.lines if line.startswith("| `")}
    assert set(rows) == {"`(defaults)`", "`loss.lhat_gray=true`"}, rows
    assert (
        "| explicit | 0.75 ± 0.0707 (n=2) | 0.8 ± 0 (n=2) | 0.008 ± 0 (n=2) (mean map 0.013) |" in rows["`(defaults)`"]
    )
    assert "| 0.1 ± 0 (n=2) |" in rows["`loss.lhat_gray=true`"]
    assert "(the true shading: -0.02 and 0.08)" in "\n".join(rep.lines)
    assert "(the true albedo's: 0.001)" in "\n".join(rep.lines)
    rep = report.Report(tmp_path / "none")
    ablations.claim_skin(rep, [r for r in find_runs([tmp_path]) if r.path.name == "old"])
    assert "no run scored for where the skin goes" in "\n".join(rep.lines)


def test_skin_albedos_set_one_model_per_setting_beside_the_truth(tmp_path, monkeypatch):
    """The skin table's figure: one checkpointed explicit run per setting (the longest trained), each model's albedo
    on the same test faces; a single setting draws nothing (there is nothing to set it beside)."""
    import torch

    skin = {"shading_albedo_tone_corr": 0.5, "shading_albedo_brightness_corr": 0.5, "steps": 10}
    for name, extra in (("paper", ()), ("low_c", ("loss.bws_c=0.3",)), ("nockpt", ("loss.bws_c=0.5",))):
        d = make_run(tmp_path / "runs", name, eval_=skin, extra=extra)
        (d / "status.json").write_text('{"status": "ok"}')
        if name != "nockpt":
            (d / "checkpoints").mkdir()
            (d / "checkpoints" / "last.pt").write_bytes(b"")

    class Constant(torch.nn.Module):  # an albedo of one grey level, its matte everywhere
        def __init__(self, level):
            super().__init__()
            self.level = level

        def forward(self, image):
            return {"albedo": torch.full_like(image, self.level), "matte": torch.ones_like(image[:, :1])}

    loaded = []

    def models(chosen):
        loaded.append({k: v.path.name for k, v in chosen.items()})
        return {k: Constant(0.2 + 0.1 * i) for i, k in enumerate(chosen)}

    monkeypatch.setattr(ablations, "load_chosen", models)
    runs = find_runs([tmp_path / "runs"])
    rep = report.Report(tmp_path / "out")
    ablations.claim_skin(rep, runs)
    assert loaded == [{"(defaults)": "paper", "loss.bws_c=0.3": "low_c"}]  # the setting without a checkpoint: none
    assert any("![albedo by setting](figures/skin_albedo.png)" in line for line in rep.lines)
    assert (tmp_path / "out" / "figures" / "skin_albedo.png").stat().st_size > 0
    rep = report.Report(tmp_path / "one")
    ablations.claim_skin(rep, [r for r in runs if r.path.name != "low_c"])
    assert len(loaded) == 1 and not any("albedo by setting" in line for line in rep.lines)
    rep = report.Report(tmp_path / "out")  # the checkpoints gone: the committed figure stays, said to be old
    ablations.claim_skin(rep, [r for r in runs if r.path.name != "low_c"])
    assert len(loaded) == 1 and "![albedo by setting](figures/skin_albedo.png)\n" in rep.lines
    assert any(line.startswith(ablations.SKIN_CAPTION + "; drawn by an earlier build") for line in rep.lines)


def test_ablation_runs_whose_normals_failed_are_named_by_how(tmp_path):
    """Flat (spread), another frame (worse than the mean map, nearer than it once the frame is aligned) and astray
    (worse than the mean map either way, or scored before the frame check) each get their list; a run between the
    pseudo-GT and the mean map, or scored before the spread and the floor were measured, is not a failure."""
    good = {"normal_mean": 12.0, "recon_face_psnr": 26.5, "albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    good |= {"normal_spread": 37.0, "true_normal_spread": 39.0, "trivial_normal_mean": 17.0}
    make_run(tmp_path, "full", eval_=good)
    make_run(tmp_path, "kept", ablations=["no_pseudo_normal"], eval_={**good, "normal_mean": 16.0})
    flat = {**good, "normal_spread": 1.5, "normal_mean": 82.0, "albedo_si_mse": 0.03}
    make_run(tmp_path, "flat", ablations=["no_pseudo_normal"], seed=1, eval_=flat)
    turned = {**good, "normal_mean": 64.0, "normal_spread": 31.6}
    frame = {"normal_aligned_mean": 11.0, "normal_aligned_angle": 58.0, "normal_aligned_det": -1.0}
    make_run(tmp_path, "turned", ablations=["no_pseudo_normal"], seed=2, eval_={**turned, **frame})
    make_run(tmp_path, "unchecked", ablations=["no_pseudo_normal"], seed=3, eval_=turned)
    frame_far = {**frame, "normal_aligned_mean": 24.0, "normal_aligned_det": 1.0}
    make_run(tmp_path, "far", ablations=["no_pseudo_normal"], seed=4, eval_={**turned, **frame_far})
    make_run(tmp_path, "old", ablations=["no_bws"], eval_={"normal_mean": 12.0, "recon_face_psnr": 26.5})
    unspread = {k: v for k, v in turned.items() if "spread" not in k}  # scored before the spread was measured
    make_run(tmp_path, "unspread", ablations=["no_pseudo_normal"], seed=5, eval_=unspread)
    rep = report.Report(tmp_path)
    runs = find_runs([tmp_path])
    ablations.claim_ablations(rep, runs)
    lists, current = {}, None
    for line in rep.lines:
        if line.startswith("Runs whose normals"):
            current = lists.setdefault(line.split(" (")[0].split(":")[0], [])
        elif line.startswith("- ") and current is not None:
            current.append(line)
    assert len(lists) == 3, list(lists)
    flat_list, frame_list, astray_list = lists.values()  # in NORMAL_FAILURES' order
    folder = {f"#{r.id}": r.path.name for r in runs}  # a run is named by its variant, seed and id

    def names(lines):
        return [folder[re.search(r"#\w{6}", line).group(0)] for line in lines]

    assert names(flat_list) == ["flat"] and "spread 1.5 deg against 39.0" in flat_list[0]
    assert names(frame_list) == ["turned"] and frame_list[0].startswith("- explicit+no_pseudo_normal s2 #")
    assert "64.0 deg off (the mean map's 17.0); 11.0 deg after a mirror by 58 deg" in frame_list[0]
    assert sorted(names(astray_list)) == ["far", "unchecked", "unspread"]
    by_name = dict(zip(names(astray_list), astray_list))
    assert "spread – deg against –, normals 64.0 deg off" in by_name["unspread"]
    assert (
        "24.0 deg after a rotation by 58 deg" in by_name["far"] and "after the best frame map –" in by_name["unchecked"]
    )
    assert not any(str(tmp_path) in line for line in rep.lines)


def test_target_source_names_the_lighting_row_of_a_settings_e_recon_l_target():
    assert targets.target_source("(defaults)") == targets.target_source("+experiment=long") == "lhat"
    assert targets.target_source("loss.recon_L_target=sh_pseudo_eroded") == "lhat_eroded"
    assert targets.target_source("loss.recon_L_scale=sh_pseudo loss.recon_L_target=sh_texture") == (
        "texture_model_lhat_scale"
    )
    assert targets.target_source("loss.recon_L_oracle_mix=0.25") == "oracle_mix_0.25"
    assert targets.target_source("loss.recon_L_target=sh_network") == "network_explicit"
    assert targets.target_source("loss.recon_L_network=implicit loss.recon_L_target=sh_network") == "network_implicit"
    both = "loss.recon_L_network=implicit loss.recon_L_target=sh_network_texture"
    assert targets.target_source(both) == "network_implicit_texture"
    assert targets.target_source(f"{both} loss.recon_L_network_share=0.6") == "network_implicit_texture"
    assert targets.target_source(f"{both} loss.recon_L_network_share=0.4") is None  # the rows are at 0.6
    where = f"{both} loss.recon_L_network_share=0.4 loss.lhat_gray=true"  # the network and its share come along
    assert ablations.setting_picks(where, "loss.recon_L_target=sh_network_texture") == [
        "loss.recon_L_target=sh_network_texture",
        "loss.recon_L_network=implicit",
        "loss.recon_L_network_share=0.4",
    ]
    truth = "true_pixels_normals_albedo"  # the truth's shape, at whichever scale
    assert targets.target_source("+experiment=long loss.recon_L_target=sh") == truth
    assert targets.target_source("loss.recon_L_oracle_mix=1.0 loss.recon_L_target=sh_texture") == truth
    assert targets.target_source("loss.recon_L_oracle_mix=0.5 loss.recon_L_target=sh_texture") is None  # no such row
    assert targets.target_source("loss.lhat_gray=true") is None  # changes more than the target
    assert targets.target_source("+ablation=no_bws") is None

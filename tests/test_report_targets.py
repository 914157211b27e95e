"""The report's targets page (disent.report.targets) on tiny fake runs."""

import json
import shutil

from disent import report
from disent.publish import write_records
from disent.report import targets
from disent.runs import Run, composed_config, find_runs
from tests.run_fakes import make_run


def test_shipped_weights_are_named_by_every_setting_they_differ_in_from_todays_conf(monkeypatch):
    """Shipped weights trained before a default changed (E_UV x1 at the long rung, then x10): their full setting
    names the old value, as a run's does; in the light-target terms only the rung and the target count."""
    from disent.models import shipped

    cfg = composed_config(("+experiment=long", "model=implicit", "loss.weights.UV=0.5", "loss.recon_L_target=sh"))
    monkeypatch.setattr(shipped, "manifest", lambda folder=None: {"m": {"cfg": cfg, "run": "/gone/m"}})
    assert targets.shipped_setting("m", full=True) == "+experiment=long loss.recon_L_target=sh loss.weights.UV=0.5"
    assert targets.shipped_setting("m") == "+experiment=long loss.recon_L_target=sh"
    cfg = composed_config(("model=implicit",))
    monkeypatch.setattr(shipped, "manifest", lambda folder=None: {"m": {"cfg": cfg, "run": "/gone/m"}})
    assert targets.shipped_setting("m", full=True) == targets.shipped_setting("m") == "(defaults)"


def test_targets_section_reads_each_rung_against_its_own_targets(tmp_path):
    """The glance table: the default rung against the absolute targets, the long rung against the pseudo-GT they
    were supervised by (15 % better), the baseline without intrinsic targets."""
    good = {
        "normal_mean": 12.0,
        "pseudo_normal_mean": 11.5,
        "trivial_normal_mean": 17.0,
        "recon_face_psnr": 26.5,
        "albedo_si_mse": 0.005,
        "trivial_albedo_si_mse": 0.0125,
    }
    for seed in range(2):
        make_run(tmp_path, f"d{seed}", seed=seed, eval_={**good, "albedo_si_mse": 0.008})  # 0.64 of the mean map's
        long = {**good, "normal_mean": 9.8 + seed / 10}
        make_run(tmp_path, f"l{seed}", seed=seed, eval_=long, extra=("+experiment=long",))
        # meets the long rung's own target but not the default rung's albedo, which the ablations' budget check uses
        long = {**good, "normal_mean": 9.5, "albedo_si_mse": 0.008}
        make_run(tmp_path, f"li{seed}", "implicit", seed=seed, eval_=long, extra=("+experiment=long",))
    make_run(tmp_path, "b", "baseline", eval_={"recon_face_psnr": 24.0})
    rep = report.Report(tmp_path)
    report.sec_targets(rep, find_runs([tmp_path]))
    rows = {line.split("|")[1].strip() + line.split("|")[2].strip(): line for line in rep.lines if "| `" in line}
    assert rows["`(defaults)`explicit"].endswith("| 0.64 | albedo 0.64 of the mean map's (<= 0.5) |")
    assert "| 12.00 ± 0.00 (n=2) | 17.00 / 11.50 |" in rows["`(defaults)`explicit"]
    assert rows["`+experiment=long`explicit"].endswith("| normals (<= 9.78) |")  # 9.85 against 0.85 x 11.5
    assert rows["`+experiment=long`implicit"].endswith("| default rung's albedo 0.64 of the mean map's (<= 0.5) |")
    assert rows["`(defaults)`baseline"].endswith("| – | – / – | 24.00 (n=1) | – | – |")
    assert not any("No run of the long rung" in line for line in rep.lines)
    rep = report.Report(tmp_path)
    report.sec_targets(rep, [r for r in find_runs([tmp_path]) if not r.path.name.startswith("l")])
    assert any("No run of the long rung" in line for line in rep.lines)


def test_settings_off_the_ladder_that_meet_every_target_without_truth_are_named(tmp_path):
    """Off the ladder, a setting's runs count where they meet every target of their rung without the truth; the
    ladder itself, oracle lights, ablations, the baseline and settings with a budget of their own are left out."""
    good = {
        "normal_mean": 9.2,
        "pseudo_normal_mean": 11.5,
        "recon_face_psnr": 28.8,
        "albedo_si_mse": 0.0058,
        "trivial_albedo_si_mse": 0.0125,
    }
    target = ("+experiment=long", "loss.recon_L_target=sh_network_texture", "loss.recon_L_network=implicit")
    for seed in range(2):
        make_run(
            tmp_path, f"i{seed}", "implicit", seed=seed, eval_={**good, "normal_mean": 9.1 + seed / 5}, extra=target
        )
        make_run(tmp_path, f"e{seed}", seed=seed, eval_={**good, "albedo_si_mse": 0.0066}, extra=target)  # 0.53
    make_run(tmp_path, "ladder", eval_=good, extra=("+experiment=long",))  # on the ladder: its own table
    make_run(tmp_path, "oracle", eval_=good, extra=("+experiment=long", "loss.recon_L_target=sh"))
    make_run(tmp_path, "ablated", eval_=good, ablations=("no_adv",), extra=target)
    make_run(tmp_path, "own", eval_=good, extra=("+experiment=long", "train.max_steps=5750"))  # no rung
    make_run(tmp_path, "gray", eval_={**good, "normal_mean": 12.6}, extra=("loss.lhat_gray=true",))  # default rung
    lines = targets.without_truth_lines(find_runs([tmp_path]))
    assert lines[0].startswith("Off the ladder: of the 3 other setting(s)") and "1 meet(s) every target" in lines[0]
    assert lines[1:] == [
        f"- `{' '.join(sorted(target))}` (implicit, long rung): normals 9.20 ± 0.14 (n=2) deg, face PSNR "
        "28.80 ± 0.00 (n=2) dB, albedo 0.0058 ± 0.0000 (n=2), 0.464 of the mean map's.",
        "",
    ]
    assert targets.rung_of("+experiment=long loss.lhat_gray=true") == "long"
    assert targets.rung_of("loss.lhat_gray=true") == "default"
    assert targets.rung_of("+experiment=long train.max_steps=5750") is targets.rung_of("+experiment=smoke") is None
    runs = find_runs([tmp_path])
    explicit = [r for r in runs if r.path.name.startswith("e")]
    assert targets.rung_misses("long", explicit) == ["default rung's albedo 0.53 of the mean map's (<= 0.5)"]
    assert targets.rung_misses("default", explicit) == ["albedo 0.53 of the mean map's (<= 0.5)"]
    assert targets.rung_misses(None, explicit) is None
    met = targets.without_truth_lines([r for r in runs if r.path.name.startswith(("e", "gray"))])
    assert met == [met[0]] and met[0].endswith("none meets every target of its rung.\n")
    assert targets.without_truth_lines([r for r in runs if r.path.name == "ladder"]) == []


def test_targets_section_sets_the_albedo_beside_the_placed_mean_texture(tmp_path):
    """The template table: each albedo scoring beside the placed mean texture's and the mean map's, for the settings
    whose runs were scored with the template; runs scored before it get no row."""
    from disent.eval.trivial import TEMPLATE_KEYS

    scored = {}
    for i, key in enumerate(TEMPLATE_KEYS):
        scored |= {key: 0.008 + i, f"template_{key}": 0.0083 + i, f"trivial_{key}": 0.0127 + i}
    for seed in range(2):
        make_run(tmp_path, f"d{seed}", seed=seed, eval_={"normal_mean": 12.0, **scored})
    make_run(tmp_path, "old", model="implicit", eval_={"normal_mean": 12.0, "albedo_si_mse": 0.009})
    rep = report.Report(tmp_path)
    report.sec_targets(rep, find_runs([tmp_path]))
    rows = [line for line in rep.lines if line.startswith("| `(defaults)` | explicit | 0.0080 ± 0.0000 (n=2)")]
    assert rows == [
        "| `(defaults)` | explicit | 0.0080 ± 0.0000 (n=2) / 0.0083 / 0.0127 | "
        "1.0080 ± 0.0000 (n=2) / 1.0083 / 1.0127 | 2.0080 ± 0.0000 (n=2) / 2.0083 / 2.0127 |"
    ], rows
    assert not any(line.startswith("| `(defaults)` | implicit | 0.") for line in rep.lines)


def test_targets_section_sets_the_light_beside_the_constant_light_part_by_part(tmp_path):
    """The light's glance rows: each light error beside the constant light's, and which of them the network beats;
    a light that wins on the face but loses in its hidden coefficients is said to lose there."""
    light = {"light_shading_si_mse": 0.004, "sh_error": 0.5, "sh_error_shown": 0.1, "sh_error_hidden": 1.2}
    floor = {"trivial_light_shading_si_mse": 0.016, "trivial_sh_error": 0.37, "trivial_sh_error_shown": 0.25}
    floor["trivial_sh_error_hidden"] = 0.14
    for seed in range(2):
        make_run(tmp_path, f"d{seed}", seed=seed, eval_={"normal_mean": 12.0, **light, **floor})
    make_run(tmp_path, "old", model="implicit", eval_={"normal_mean": 12.0, "sh_error": 0.5})  # scored before the split
    rep = report.Report(tmp_path)
    report.sec_targets(rep, find_runs([tmp_path]))
    rows = [line for line in rep.lines if line.startswith("| `(defaults)` | explicit | 0.0040")]
    assert rows == [
        "| `(defaults)` | explicit | 0.0040 ± 0.0000 (n=2) / 0.0160 | 0.500 ± 0.000 (n=2) / 0.370 | "
        "0.100 ± 0.000 (n=2) / 0.250 | 1.200 ± 0.000 (n=2) / 0.140 | "
        "light on the face, its shown part; not SH error, its hidden part |"
    ], rows
    assert not any(line.startswith("| `(defaults)` | implicit | 0.") for line in rep.lines)
    assert not any("completed by the mean light" in line for line in rep.lines)  # no run scored with it
    completed = {"sh_error_completed": 0.27, "pseudo_sh_error": 0.83, "pseudo_sh_error_completed": 0.29}
    make_run(tmp_path, "c", seed=5, extra=("loss.bws_c=0.3",), eval_={**light, **floor, **completed})
    rep = report.Report(tmp_path)
    report.sec_targets(rep, find_runs([tmp_path]))
    row = next(line for line in rep.lines if line.startswith("| `loss.bws_c=0.3` | explicit |"))
    assert row == (
        "| `loss.bws_c=0.3` | explicit | 0.270 (n=1) | 0.500 (n=1) | 0.290 / 0.830 | 0.370 | "
        "the constant light, L-hat completed |"
    ), row


def test_matte_table_sets_the_matte_beside_m_hat_and_the_mean_region(tmp_path, monkeypatch):
    """The matte's glance rows: runs scored with ``matte_iou`` by setting and model, and shipped models whose
    manifest has it, each beside M-hat and the mean face region, saying which it beats (higher is better), and where
    it is soft (dashes for runs scored before that)."""
    import disent.models.shipped as shipped

    ev = {"pseudo_matte_iou": 0.86, "trivial_matte_iou": 0.70}
    for seed, iou in enumerate((0.91, 0.93, 0.92)):
        make_run(tmp_path / "runs", f"e{seed}", seed=seed, eval_={**ev, "matte_iou": iou})
    edge = {"matte_soft_edge": 0.98, "matte_soft_inner": 0.06}
    edge |= {"matte_mean_edge": 0.754, "pseudo_matte_mean_edge": 0.756}
    make_run(tmp_path / "runs", "i0", "implicit", eval_={**ev, "matte_iou": 0.80, **edge})
    make_run(tmp_path / "runs", "old", "implicit", seed=1, eval_={"normal_mean": 12.0})  # scored before the matte
    monkeypatch.setattr(
        shipped, "manifest", lambda: {"implicit": {"metrics": {**ev, "matte_iou": 0.5}}, "baseline": {"metrics": {}}}
    )
    lines = targets.matte_lines(find_runs([tmp_path / "runs"]))
    rows = [line for line in lines if line.startswith("| `")]
    assert rows == [
        "| `(defaults)` | explicit | 0.920 ± 0.010 (n=3) | 0.860 | 0.700 | M-hat, the mean region | – / – | – / – |",
        "| `(defaults)` | implicit | 0.800 (n=1) | 0.860 | 0.700 | the mean region | 0.98 / 0.06 | 0.75 / 0.76 |",
        "| `shipped` | implicit | 0.500 (n=1) | 0.860 | 0.700 | neither | – / – | – / – |",
    ]
    monkeypatch.setattr(shipped, "manifest", lambda: {})
    assert targets.matte_lines([]) == []


def test_albedo_cause_table_sets_the_detailed_albedo_with_each_input_made_true_beside_the_mean_map(
    tmp_path, monkeypatch
):
    """What holds the albedo back: per setting and model of the runs scored with it (and shipped models whose manifest
    has it) the network's albedo and the detailed albedo with its own, the true light and the true normals, each
    with its share of the mean map's; runs scored before it add no row."""
    import disent.models.shipped as shipped

    ev = {"trivial_albedo_si_mse": 0.0125, "albedo_si_mse": 0.008, "albedo_detailed_si_mse": 0.009}
    for seed, light in enumerate((0.005, 0.006, 0.007)):
        scored = {"albedo_detailed_true_light_si_mse": light, "albedo_detailed_true_normals_si_mse": 0.0075}
        make_run(tmp_path / "runs", f"e{seed}", seed=seed, eval_={**ev, **scored})
    make_run(tmp_path / "runs", "old", "implicit", eval_=ev)  # scored before the split
    monkeypatch.setattr(shipped, "manifest", lambda: {})
    lines = targets.albedo_cause_lines(find_runs([tmp_path / "runs"]))
    rows = [line for line in lines if line.startswith("| `")]
    assert rows == [
        "| `(defaults)` | explicit | 0.0080 ± 0.0000 (0.64; n=3) | 0.0090 ± 0.0000 (0.72; n=3) | "
        "0.0060 ± 0.0010 (0.48; n=3) | 0.0075 ± 0.0000 (0.60; n=3) | 0.0125 | its N, the true L |"
    ]
    assert targets.albedo_cause_lines([]) == []


def test_light_targets_pair_each_setting_with_its_l_hat_counterpart(tmp_path, monkeypatch):
    """What another E_recon-L target buys (the true light, L-hat with a texture model): a setting trained on one is
    read against the same setting with L-hat (the defaults' when it has no other override), or, at L-hat's per-face
    scale (loss.recon_L_scale), against the target at its own scale; its albedo as a share of the mean map's against
    the target, the light's contrast and its parts where both sides were scored with them, one paragraph per target;
    a setting without its counterpart adds nothing."""
    import disent.models.shipped as shipped

    ev = {"trivial_albedo_si_mse": 0.0125, "light_shading_si_mse": 0.005, "normal_mean": 12.4, "albedo_si_mse": 0.009}
    for seed in (0, 1):
        make_run(tmp_path / "runs", f"paper{seed}", seed=seed, eval_=ev)
        better = ev | {"light_shading_si_mse": 0.003, "albedo_si_mse": 0.006 + 0.001 * seed}
        make_run(tmp_path / "runs", f"oracle{seed}", seed=seed, eval_=better, extra=("loss.recon_L_target=sh",))
    make_run(tmp_path / "runs", "tex", eval_=ev | {"albedo_si_mse": 0.0062}, extra=("loss.recon_L_target=sh_texture",))
    make_run(tmp_path / "runs", "alone", "implicit", eval_=ev, extra=("loss.recon_L_target=sh",))  # no implicit pair
    make_run(tmp_path / "runs", "mix", eval_=ev | {"albedo_si_mse": 0.0075}, extra=("loss.recon_L_oracle_mix=0.5",))
    at_lhat_scale = ("loss.recon_L_target=sh_texture", "loss.recon_L_scale=sh_pseudo")  # read against "tex"
    make_run(tmp_path / "runs", "texs", eval_=ev | {"albedo_si_mse": 0.0056}, extra=at_lhat_scale)
    texture = ("loss.recon_L_target=sh_texture",)  # a seed scored with the light's contrast, on both sides of a pair
    make_run(
        tmp_path / "runs",
        "tex1",
        seed=1,
        eval_=ev | {"albedo_si_mse": 0.0062, "light_contrast": 0.66, "light_pattern_corr": 0.9},
        extra=texture,
    )  # the pattern on both sides, the magnitude on one: only the pattern is read
    at_lhat_scale_contrast = ev | {"albedo_si_mse": 0.0056, "light_contrast": 0.70, "light_pattern_corr": 0.91}
    at_lhat_scale_contrast |= {"light_contrast_ratio": 0.77}
    make_run(tmp_path / "runs", "texs1", seed=1, eval_=at_lhat_scale_contrast, extra=at_lhat_scale)
    network = ("loss.recon_L_target=sh_network_texture", "loss.recon_L_network=implicit")  # the network comes along
    make_run(tmp_path / "runs", "nettex", eval_=ev | {"albedo_si_mse": 0.007}, extra=network)
    monkeypatch.setattr(shipped, "manifest", lambda: {})
    lines = targets.light_target_lines(find_runs([tmp_path / "runs"]))
    rows = [line for line in lines if line.startswith("- ")]
    assert rows == [
        "- `loss.recon_L_target=sh_texture` (explicit) against `(defaults)`: light on the face 0.0050 ± 0.0000 (n=2) "
        "-> 0.0050 ± 0.0000 (n=2); normals 12.40 ± 0.00 (n=2) -> 12.40 ± 0.00 (n=2) deg; albedo 0.0090 ± 0.0000 "
        "(n=2) -> 0.0062 ± 0.0000 (n=2), 0.72 -> 0.50 of the mean map's: meets the target (<= 0.5).",
        "- `loss.recon_L_network=implicit loss.recon_L_target=sh_network_texture` (explicit) against `(defaults)`: "
        "light on the face 0.0050 ± 0.0000 (n=2) -> 0.0050 (n=1); normals 12.40 ± 0.00 (n=2) -> 12.40 (n=1) deg; "
        "albedo 0.0090 ± 0.0000 (n=2) -> 0.0070 (n=1), 0.72 -> 0.56 of the mean map's: misses the target (<= 0.5).",
        "- `loss.recon_L_scale=sh_pseudo loss.recon_L_target=sh_texture` (explicit) against "
        "`loss.recon_L_target=sh_texture`: light on the face 0.0050 ± 0.0000 (n=2) -> 0.0050 ± 0.0000 (n=2); light "
        "contrast 0.66 (n=1) -> 0.70 (n=1); its pattern 0.90 (n=1) -> 0.91 (n=1); normals 12.40 ± 0.00 (n=2) -> "
        "12.40 ± 0.00 (n=2) deg; albedo 0.0062 ± 0.0000 (n=2) -> 0.0056 ± 0.0000 (n=2), 0.50 -> 0.45 of the mean "
        "map's: meets the target (<= 0.5).",
        "- `loss.recon_L_target=sh` (explicit) against `(defaults)`: light on the face 0.0050 ± 0.0000 (n=2) -> "
        "0.0030 ± 0.0000 (n=2); normals 12.40 ± 0.00 (n=2) -> 12.40 ± 0.00 (n=2) deg; albedo 0.0090 ± 0.0000 (n=2) "
        "-> 0.0065 ± 0.0007 (n=2), 0.72 -> 0.52 of the mean map's: misses the target (<= 0.5).",
        "- `loss.recon_L_oracle_mix=0.5` (explicit) against `(defaults)`: light on the face 0.0050 ± 0.0000 (n=2) -> "
        "0.0050 (n=1); normals 12.40 ± 0.00 (n=2) -> 12.40 (n=1) deg; albedo 0.0090 ± 0.0000 (n=2) -> 0.0075 (n=1), "
        "0.72 -> 0.60 of the mean map's: misses the target (<= 0.5).",
    ]
    assert [line.split(":")[0] for line in lines if line.startswith(("What", "How", "Its"))] == [
        "What a better L-hat without truth buys",
        "What a network's light with the texture model's refit buys as the target",
        "Its shape or its scale",
        "What a perfect L-hat buys",
        "How good L-hat must be",
    ]
    assert targets.light_target_lines([]) == []


def test_a_target_drawn_from_a_run_names_what_that_run_was(tmp_path):
    """A network target drawn from a run folder (an iterated target) says what that run trained at."""
    ev = {"trivial_albedo_si_mse": 0.0125, "light_shading_si_mse": 0.005, "normal_mean": 12.4, "albedo_si_mse": 0.009}
    first = ("loss.recon_L_target=sh_network_texture", "loss.recon_L_network=implicit")
    net = make_run(tmp_path / "nets", "first", seed=3, eval_=ev, extra=first)
    make_run(tmp_path / "runs", "paper", eval_=ev)
    second = (
        "loss.recon_L_target=sh_network_texture",
        f"loss.recon_L_network={net}",
        "loss.recon_L_network_share=0.35",
    )
    make_run(tmp_path / "runs", "second", eval_=ev | {"albedo_si_mse": 0.006}, extra=second)
    rows = [line for line in targets.light_target_lines(find_runs([tmp_path / "runs"])) if line.startswith("- ")]
    ref = f"loss.recon_L_network=run:{Run.load(net).id}"  # the network named by its run id, never by its folder
    assert len(rows) == 1 and ref in rows[0] and str(tmp_path) not in rows[0] and "against `(defaults)`" in rows[0]
    assert rows[0].endswith(
        " Its network: the explicit model trained at "
        "`loss.recon_L_network=implicit loss.recon_L_target=sh_network_texture`, seed 3."
    )
    assert targets.network_run_words("loss.recon_L_network=implicit", []) == ""  # a shipped name: nothing to add
    # the network's folder deleted (a new machine): its record, kept with the report's runs, still says what it was
    write_records(find_runs([net.parent]), tmp_path / "runs.jsonl")
    shutil.rmtree(net)
    runs = find_runs([tmp_path / "runs"], tmp_path / "runs.jsonl")
    assert targets.network_run(ref, runs).seed == 3
    assert rows[0] in targets.light_target_lines(runs)
    assert targets.drawn_target_words(" ".join(second), runs) == "explicit run's light + refit (0.35)"
    assert targets.network_run(ref, []) is None  # neither the folder nor its record


def test_light_pattern_section_reads_the_albedo_against_the_targets_pattern(tmp_path, monkeypatch):
    """One row per explicit setting that changes E_recon-L's target alone, with the target's pattern and magnitude
    from the lighting section's table and the network's own where its runs have them; a figure beside it; nothing
    without the lighting table."""
    import disent.models.shipped as shipped
    from disent import report

    monkeypatch.setattr(shipped, "manifest", lambda: {})
    ev = {"trivial_albedo_si_mse": 0.0125, "albedo_si_mse": 0.0093, "light_shading_si_mse": 0.005}
    for seed in (0, 1):
        make_run(tmp_path / "runs", f"paper{seed}", seed=seed, eval_=ev | {"light_pattern_corr": 0.93 + 0.01 * seed})
        truth = ev | {"albedo_si_mse": 0.0083, "light_pattern_corr": 0.97, "light_contrast_ratio": 0.89}
        truth |= {"light_log_error": 0.067, "shading_log_error": 0.27, "albedo_detailed_true_light_si_mse": 0.008}
        make_run(tmp_path / "runs", f"oracle{seed}", seed=seed, eval_=truth, extra=("loss.recon_L_target=sh",))
    make_run(tmp_path / "runs", "gray", eval_=ev, extra=("loss.lhat_gray=true",))  # not a target: no row
    implicit = ev | {"albedo_si_mse": 0.0075, "albedo_detailed_true_light_si_mse": 0.001}  # its own point, no cap
    make_run(tmp_path / "runs", "implicit", model="implicit", eval_=implicit, extra=("loss.recon_L_target=sh",))
    make_run(tmp_path / "runs", "baseline", model="baseline", eval_=ev)  # no light: no row
    runs = find_runs([tmp_path / "runs"])
    rep = report.Report(tmp_path)
    targets.light_pattern_section(rep, runs)
    assert rep.lines == []  # no lighting table yet
    rows = {
        "lhat": {"pattern_corr": 0.893, "contrast_ratio": 1.03},  # scored before the log error
        "true_pixels_normals_albedo": {"pattern_corr": 1.0, "contrast_ratio": 1.0, "log_error": 0.0},
    }
    (tmp_path / "lighting").mkdir()
    (tmp_path / "lighting" / "lhat_sources.json").write_text(json.dumps({"rows": rows}))
    targets.light_pattern_section(rep, runs)
    text = "\n".join(rep.lines)
    assert (
        "| `(defaults)` | explicit | default | 0.893 | 1.03 | – | 0.935 ± 0.007 (n=2) | – | – | – | 0.74 ± 0.00 (n=2) |"
        in text
    )
    assert (
        "| `loss.recon_L_target=sh` | explicit | default | 1.000 | 1.00 | 0.000 | 0.970 ± 0.000 (n=2) | "
        "0.89 ± 0.00 (n=2) | 0.067 ± 0.000 (n=2) | 0.270 ± 0.000 (n=2) | 0.66" in text
    )
    assert "| `loss.recon_L_target=sh` | implicit | default | 1.000 | 1.00 | 0.000 | – | – | – | – | 0.60" in text
    assert "baseline" not in text
    assert "lhat_gray" not in text and (tmp_path / "figures" / "albedo_vs_light_pattern.png").exists()
    assert "Rank agreement" not in text  # two settings: too few to rank
    # the normals' cap: only the oracle runs were scored with it (0.008 / 0.0125); no long-rung runs
    reading = "default rung 0.64 (short of the target; trained on the true light's shape the albedo ends at 0.66)."
    assert "a share of the mean map's: " + reading in text
    long = [{"rung": "long", "cap": c, "name": "L-hat", "share": {"mean": 0.6}} for c in (0.4, 0.5)]
    assert targets.normals_caps(long) == {"long": 0.45}
    assert "long rung 0.45 (within the target)." in targets.normals_cap_reading(long, targets.normals_caps(long))
    unscored = [{**long[0], "cap": None}]
    assert targets.normals_cap_reading(unscored, targets.normals_caps(unscored)) == ""
    # the shipped explicit weights (one long-rung seed on L-hat): a row of the table, not a point of the figure or ranks
    metrics = {"albedo_si_mse": 0.008, "trivial_albedo_si_mse": 0.0127, "light_pattern_corr": 0.95}
    metrics |= {"light_contrast_ratio": 0.857, "light_log_error": 0.146, "shading_log_error": 0.236}
    cfg = {"train": {"max_steps": 10000}, "loss": {}}  # a config older than the target's option: L-hat
    entries = {"explicit": {"metrics": metrics, "cfg": cfg}, "baseline": {"metrics": {}, "cfg": cfg}}
    monkeypatch.setattr(shipped, "manifest", lambda: entries)
    ranked = []
    monkeypatch.setattr(targets, "albedo_rank_reading", lambda points: ranked.extend(points) or "")
    rep = report.Report(tmp_path)
    targets.light_pattern_section(rep, runs)
    shipped_row = (
        "| `shipped` | explicit | long | 0.893 | 1.03 | – | 0.950 (n=1) | 0.86 (n=1) | 0.146 (n=1) | 0.236 (n=1) | "
    )
    assert shipped_row + "0.63 ± 0.00 (n=1) |" in rep.lines
    assert "one seed of `+experiment=long` as their manifest's config reads" in "\n".join(rep.lines)
    assert sorted(p["name"] for p in ranked) == ["L-hat", "truth's shape"]
    # weights trained at the default rung on the true light: their row reads that target's, at that rung
    cfg |= {"train": {"max_steps": 1200}, "loss": {"recon_L_target": "sh"}}
    rep = report.Report(tmp_path)
    targets.light_pattern_section(rep, runs)
    assert any(line.startswith("| `shipped` | explicit | default | 1.000 | 1.00 | 0.000 |") for line in rep.lines)


def test_a_target_without_a_lighting_row_is_placed_by_its_runs_own_scores(tmp_path, monkeypatch):
    """A network target the lighting table has no row for (a run's network, another share) takes the target's
    pattern, magnitude and log error its runs scored themselves (``target_light_*``), named by whose light it is;
    without those scores, or where the setting changes more than the target, it has no row."""
    import disent.models.shipped as shipped
    from disent import report

    monkeypatch.setattr(shipped, "manifest", lambda: {})
    ev = {"trivial_albedo_si_mse": 0.0125, "albedo_si_mse": 0.0093, "light_shading_si_mse": 0.005}
    first = ("loss.recon_L_target=sh_network_texture", "loss.recon_L_network=implicit")
    net = make_run(tmp_path / "nets", "first", eval_=ev, extra=first)
    second = (
        "loss.recon_L_target=sh_network_texture",
        f"loss.recon_L_network={net}",
        "loss.recon_L_network_share=0.35",
    )
    own = {"target_light_pattern_corr": 0.975, "target_light_contrast_ratio": 0.95, "target_light_log_error": 0.07}
    for seed in (0, 1):
        make_run(tmp_path / "runs", f"second{seed}", seed=seed, eval_=ev | own | {"albedo_si_mse": 0.006}, extra=second)
    make_run(tmp_path / "runs", "unscored", eval_=ev, extra=first[:1] + ("loss.recon_L_network_share=0.4",))
    make_run(tmp_path / "runs", "more", eval_=ev | own, extra=second + ("loss.lhat_gray=true",))
    (tmp_path / "lighting").mkdir()
    (tmp_path / "lighting" / "lhat_sources.json").write_text(json.dumps({"rows": {"lhat": {"pattern_corr": 0.89}}}))
    rep = report.Report(tmp_path)
    points = []
    monkeypatch.setattr(targets, "albedo_rank_reading", lambda p: points.extend(p) or "")
    targets.light_pattern_section(rep, find_runs([tmp_path / "runs"]))
    rows = [line for line in rep.lines if line.startswith("| `loss.")]
    named = sorted(t if "network=" not in t else f"loss.recon_L_network=run:{Run.load(net).id}" for t in second)
    assert len(rows) == 1 and rows[0].startswith(f"| `{' '.join(named)}` | explicit | default | 0.975 | 0.95 | 0.070 |")
    assert [p["name"] for p in points] == ["explicit run's light + refit (0.35)"]
    assert targets.drawn_target_words("loss.recon_L_target=sh_network loss.recon_L_network=implicit", []) == (
        "implicit's light"
    )


def test_albedo_rank_reading_ranks_the_albedo_against_each_measure_per_rung():
    """+1 where the better value always goes with the better albedo: a higher target pattern, a lower log error."""

    def point(rung, share, pattern=None, light=None, shading=None):
        return {"rung": rung, "share": {"mean": share}, "target_pattern": pattern, "light_log_error": light,
                "shading_log_error": shading}  # fmt: skip

    points = [point("default", m, x) for x, m in zip((0.89, 0.94, 0.98, 1.0), (0.74, 0.72, 0.70, 0.66))]
    points += [point("long", 0.62, 0.89, 0.13), point("long", 0.45, 1.0, 0.05)]
    text = targets.albedo_rank_reading(points)
    assert "default rung, the target's pattern (corr. of log shading with the truth): +1.00 over 4 settings" in text
    assert "long rung" not in text and "network" not in text  # 2 long settings; no network error at default
    points[1]["share"]["mean"] = 0.75  # one setting out of order
    assert "target's pattern (corr. of log shading with the truth): +0.80 over 4" in targets.albedo_rank_reading(points)
    points = [point("default", m, 0.9, e, e + 0.1) for e, m in ((0.14, 0.79), (0.13, 0.74), (0.1, 0.72), (0.07, 0.66))]
    text = targets.albedo_rank_reading(points)  # one target pattern for all: not ranked
    assert "default rung, the network's own light: log error: +1.00 over 4" in text and "target's" not in text
    assert "the network's own shading (its normals too): log error: +1.00 over 4" in text
    assert targets.albedo_rank_reading(points[4:]) == ""

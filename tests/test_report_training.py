"""The report's training sections (disent.report.training): teaser, ceiling, recipe, learning curves, UV by seed."""

import json
import re

from disent import report
from disent.report import document, tables, training
from disent.runs import Run, composed_config, find_runs, pick_runs
from tests.run_fakes import make_run


def test_teaser_needs_the_three_ladder_models(tmp_path, monkeypatch):
    """The teaser sets the paper's three models side by side: runs with another override (a loss weight) or only
    some of the models draw no partial teaser; the page says which models are missing."""
    title = "Teaser: input, recon, albedo, normal, shading, matte"
    out = tmp_path / "reports"
    ev = {"recon_mse": 0.02, "normal_mean": 20.0, "steps": 10}
    for name, extra in (("ladder", ()), ("weighted", ("loss.weights.recon_L=0.6",))):
        d = make_run(tmp_path / "runs", name, "explicit", eval_=ev, extra=extra)
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "last.pt").write_bytes(b"")
        (d / "status.json").write_text('{"status": "ok"}')
    loaded = []
    monkeypatch.setattr(training, "load_chosen", lambda chosen: loaded.append(chosen) or {})
    rep = report.Report(out)
    rep.section(title, report.sec_teaser, find_runs([tmp_path / "runs"]), 2)
    assert loaded == []  # no partial teaser drawn
    text = "\n".join(rep.lines)
    assert "> **Missing:**" in text and "`baseline`, `implicit`" in text and "weighted" not in text


def test_teaser_names_each_model_by_its_setting_seed_and_steps(tmp_path, monkeypatch):
    """Each teaser's title says what was trained (setting, seed, steps), not where the run folder lay."""
    import torch

    from disent.models import build_model

    ev = {"recon_mse": 0.02, "normal_mean": 20.0, "steps": 1200}
    for name, model in (("b", "baseline"), ("e", "explicit"), ("i", "implicit")):
        d = make_run(tmp_path / "runs", name, model, seed=2, eval_=ev)
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "last.pt").write_bytes(b"")
        (d / "status.json").write_text('{"status": "ok"}')
    torch.manual_seed(0)
    monkeypatch.setattr(
        training, "load_chosen", lambda chosen: {m: build_model(r.cfg["model"]).eval() for m, r in chosen.items()}
    )
    titles = []
    monkeypatch.setattr(training, "image_grid", lambda rows, path, title: titles.append(title))
    rep = report.Report(tmp_path / "reports")
    rep.section("Teaser", report.sec_teaser, find_runs([tmp_path / "runs"]), 2)
    teasers = [t for t in titles if "SynthFaces test images" in t]
    assert len(teasers) == 3 and all("(defaults), seed 2, 1,200 steps" in t for t in teasers)
    assert not any(str(tmp_path) in t for t in titles)
    assert not any(str(tmp_path) in line for line in rep.lines)  # runs are named by their ids, not their folders
    ids = {r.id for r in find_runs([tmp_path / "runs"])}
    assert sum(any(f"#{i})" in line for i in ids) for line in rep.lines) == 6  # 3 teasers, 3 normals rows


def test_teaser_without_ladder_runs_shows_the_shipped_weights(tmp_path, monkeypatch):
    """No ladder run of any model given: the teaser draws the shipped weights, each titled by the setting, seed and
    steps of their manifest and named by their file."""
    titles = []
    monkeypatch.setattr(training, "image_grid", lambda rows, path, title: titles.append(title))
    rep = report.Report(tmp_path / "reports")
    rep.section("Teaser", report.sec_teaser, [], 2)
    teasers = [t for t in titles if "SynthFaces test images" in t]
    from disent.models.shipped import manifest

    for name in ("baseline", "explicit", "implicit"):
        e = manifest()[name]
        rung = "+experiment=long" if e["steps"] == 10_000 else "(defaults)"  # the long rung's 10,000 steps
        title = rf"^{name} \(shipped weights, {re.escape(rung)}( [^,]+)?, seed {e['cfg']['seed']}, {e['steps']:,} steps"
        assert sum(bool(re.search(title, t)) for t in teasers) == 1
    assert len(teasers) == 3
    text = "\n".join(rep.lines)
    assert "`disent/weights/implicit.pt`, trained as run run:" in text and "/root" not in text
    normals = manifest()["explicit"]["metrics"]["normal_mean"]  # the normals table reads their manifest's metrics
    assert f"| explicit (shipped weights) | {normals:.2f} |" in text


def test_replicates_set_the_gap_between_a_seeds_runs_beside_the_seed_spread(tmp_path):
    """A seed trained again (another revision) is one seed in every table; the runs section says how far apart its
    runs lie beside the spread across seeds, how many revisions trained them, and which seeds agree exactly."""
    ev = {"recon_face_psnr": 26.0, "albedo_si_mse": 0.01}
    for name, seed, normal, rev in (("a", 0, 12.0, "aaa"), ("b", 0, 12.25, "bbb"), ("c", 1, 13.0, "aaa")):
        d = make_run(tmp_path, name, seed=seed, eval_={**ev, "normal_mean": normal})
        (d / "git.txt").write_text(f"revision: {rev}\nclean\n")
    for name, normal in (("d", 14.0), ("e", 14.0 + 1e-9)):  # seed 2 twice, the same up to float noise, no git.txt
        make_run(tmp_path, name, seed=2, eval_={**ev, "normal_mean": normal})
    make_run(tmp_path, "f", "implicit", eval_={**ev, "normal_mean": 11.0})  # a setting with no seed run twice
    (tmp_path / "d" / "git.txt").write_text("revision: unknown (not a git checkout)\nclean\n")  # trained off git
    lines = training.replicate_lines(find_runs([tmp_path]))
    (row,) = [line for line in lines if line.startswith("| `")]
    # seed means 12.125, 13, 14: std 0.94; the largest gap 0.25 (seed 0); revisions aaa, bbb; seed 2 agrees
    assert (
        row == "| `(defaults)` | explicit | 2 of 3 | 4 | 2 | 0.25 / 0.94 | 0.00 / 0.00 | 0.00000 / 0.00000 | 1 of 2 |"
    )
    assert training.replicate_lines(find_runs([tmp_path / "f"])) == []
    assert Run.load(tmp_path / "d").revision is None and Run.load(tmp_path / "a").revision == "aaa"


def test_ceiling_section_puts_the_trained_runs_between_floor_and_ceiling(tmp_path):
    def ev(normal, albedo):
        return {
            "normal_mean": normal,
            "shading_si_mse": albedo + 0.001,
            "albedo_si_mse": albedo,
            "albedo_coarse_si_mse": albedo / 2,
            "albedo_fine_si_mse": albedo / 4,
            "light_shading_si_mse": 0.005,
            "sh_error": 0.5,
            "steps": 1200,
            "trivial_normal_mean": 17.0,
            "trivial_albedo_si_mse": 0.0127,
            "trivial_albedo_coarse_si_mse": 0.0066,
            "trivial_albedo_fine_si_mse": 0.0038,
            "trivial_light_shading_si_mse": 0.016,
            "trivial_sh_error": 0.37,
        }

    rep = report.Report(tmp_path)
    report.sec_ceiling(rep, [])
    assert "no finished ceiling run" in "\n".join(rep.lines)
    for seed in (0, 1):
        make_run(tmp_path, f"t{seed}", seed=seed, eval_=ev(12.5 + seed, 0.010))
    ceiling = make_run(tmp_path, "c", eval_=ev(9.9, 0.0063), extra=["loss=ceiling"])  # runs come in id order
    (ceiling / "checkpoints").mkdir()
    (ceiling / "checkpoints" / "last.pt").write_bytes(b"")
    runs = find_runs([tmp_path])
    assert sorted(r.variant for r in runs) == ["explicit", "explicit", "explicit+ceiling"]
    assert pick_runs(runs) == {}  # a ceiling run is never picked as the paper's model (the others lack weights)
    rep = report.Report(tmp_path)
    report.sec_ceiling(rep, runs)
    lines = [line for line in rep.lines if line.startswith("| explicit")]
    floor = "| explicit | floor (dataset mean) | – | – | 17.00 | – | 0.0127 | 0.0066 | 0.0038 | 0.0160 | 0.370 |"
    assert lines[0] == floor
    assert lines[1].startswith(
        "| explicit | trained | `(defaults)` | 1,200 | 13.00 ± 0.71 (n=2) | 0.0110 ± 0.0000 (n=2) | "
        "0.0100 ± 0.0000 (n=2)"
    )
    assert lines[2].startswith(
        "| explicit | ceiling | `loss=ceiling` | 1,200 | 9.90 (n=1) | 0.0073 (n=1) | 0.0063 (n=1)"
    )
    assert len(lines) == 3
    # the trained runs close (17 - 13) / (17 - 9.9) of the normal gap, (0.0127 - 0.010) / (0.0127 - 0.0063) of the
    # albedo's ((0.0066 - 0.005) / (0.0066 - 0.00315) of its coarse part, (0.0038 - 0.0025) / (0.0038 - 0.001575)
    # of its detail), and all of the light's (trained and ceiling agree there)
    gap = (
        "- explicit, `(defaults)`: normals (deg) 56 %, shading si-MSE –, albedo si-MSE 42 %, albedo: coarse 46 %, "
        "albedo: detail 58 %, light on the face 100 %, SH error 100 %"
    )
    assert gap in rep.lines
    # the ceiling itself removes 1 - 0.00315 / 0.0066 of the mean map's coarse albedo error, 1 - 0.001575 / 0.0038
    # of its detail
    assert "- explicit, `loss=ceiling` (1,200 steps): 52 % of its coarse part and 59 % of its detail" in rep.lines


def test_curve_label_shares_a_setting_across_seeds_and_names_a_gpu(tmp_path):
    from disent.report.training import curve_label

    cpu0, cpu1, gpu = (
        Run.load(make_run(tmp_path, name, seed=seed, extra=("+experiment=long",)))
        for name, seed in (("c0", 0), ("c1", 1), ("g0", 0))
    )
    gpu.machine = {"device": "cuda", "gpu": "NVIDIA H100 80GB HBM3"}
    assert curve_label(cpu0) == curve_label(cpu1) == "explicit: +experiment=long"
    assert curve_label(gpu) == "explicit: +experiment=long (NVIDIA H100 80GB HBM3)"


def test_learning_curves_legend_names_each_model_or_each_setting(tmp_path, monkeypatch):
    """Coloured by model (the ablations' figure), a model's runs at every rung share one colour and one legend
    entry; coloured by setting, each setting has its own; the reference lines are in both."""
    import matplotlib.figure

    runs = []
    for name, abl, rung in (
        ("f0", (), "smoke"),
        ("f1", (), "long"),
        ("b0", ("no_bws",), "smoke"),
        ("b1", ("no_bws",), "long"),
    ):
        d = make_run(tmp_path, name, ablations=abl, extra=(f"+experiment={rung}",))
        vals = [{"normal_mean": 12.0 - i, "trivial_normal_mean": 17.0, "pseudo_normal_mean": 11.5} for i in range(3)]
        recs = [{"step": 10 * (i + 1), "wall": 60.0 * (i + 1), "val": v} for i, v in enumerate(vals)]
        (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
        runs.append(Run.load(d))
    legends = []
    monkeypatch.setattr(
        matplotlib.figure.Figure,
        "legend",
        lambda fig, handles, labels, **kw: legends.append((list(labels), [h.get_color() for h in handles])),
    )
    assert training.plot_learning_curves(runs, tmp_path / "by_model.png", colour_by_setting=False)
    assert training.plot_learning_curves(runs, tmp_path / "by_setting.png", colour_by_setting=True)
    (by_model, colours), (by_setting, _) = legends
    assert by_model == ["explicit", "explicit+no_bws", "dataset mean", "pseudo-GT"]
    assert len(set(colours[:2])) == 2
    assert sorted(by_setting[:4]) == sorted(training.curve_label(r) for r in runs) and len(by_setting) == 6


def test_concordance_counts_pairs_ordered_alike():
    """Pairs ordered alike count, opposite ones do not, ties in x are left out, and a missing y is skipped."""
    pairs = [((0.1, 9.0), (0.2, 10.0)), ((0.1, 9.0), (0.3, 8.0)), ((0.2, 1.0), (0.2, 2.0)), ((0.1, None), (0.2, 1.0))]
    assert training.concordance(pairs) == (1, 2)


def test_uv_weight_text_names_an_early_weight_of_e_uv(tmp_path):
    """Runs that trained E_UV at another weight for their first steps are not read as runs of the later weight."""
    loss = {"weights": {"UV": 1.0}, "early_weights": {"UV": 10.0}, "early_steps": 300}
    assert training.uv_weight_text(Run(tmp_path, cfg={"loss": loss})) == "10 for 300 steps, then 1"
    assert training.uv_weight_text(Run(tmp_path, cfg={"loss": {**loss, "early_steps": 0}})) == "1"
    assert training.uv_weight_text(Run(tmp_path, cfg={"loss": {"weights": {"UV": 10.0}}})) == "10"
    assert training.uv_weight_text(Run(tmp_path, cfg={"loss": {"weights": {"recon": 1.0}}})) is None


def test_an_early_weight_of_e_uv_is_read_beside_its_seed_at_one_weight(tmp_path):
    """A run with an early E_UV weight is set beside the runs of its seed and rung at one weight throughout; another
    seed's or rung's runs are not."""
    smoke = ("+experiment=smoke",)
    w1 = ("loss.weights.UV=1",)
    arms = {  # name: (seed, overrides, uv error)
        "w1": (2, w1, 0.24),
        "w10": (2, ("loss.weights.UV=10",), 0.037),
        "early": (2, (*w1, "+loss.early_weights.UV=10", "loss.early_steps=300"), 0.041),
        "w1_seed0": (0, w1, 0.05),
        "w1_default_rung": (2, w1, 0.3),
    }
    for name, (seed, extra, uv) in arms.items():
        rung = () if name == "w1_default_rung" else smoke
        make_run(tmp_path, name, "implicit", seed=seed, eval_={"uv_error": uv, "normal_mean": 10.0}, extra=rung + extra)
    (line,) = training.early_weight_lines(find_runs([tmp_path]))
    assert line == (
        "`+experiment=smoke`, seed 2, weight 10 for 300 steps, then 1: UV error 0.041, normals 10.00 deg (against "
        "weight 1 UV error 0.240, normals 10.00 deg, weight 10 UV error 0.037, normals 10.00 deg)"
    )


def test_uv_by_seed_reads_each_runs_uv_map_against_its_baselines(tmp_path):
    """The implicit runs' UV maps: a table row per scored run (explicit and unscored runs left out), each run's
    E_UV at step 1,000 from its log, the counts against the pseudo and mean UV maps, the seed's span over settings,
    and the pairs of one setting where the smaller UV error goes with the smaller normal error."""
    base = {"trivial_uv_error": 0.14, "pseudo_uv_error": 0.044}
    arms = {  # (setting, seed): (uv error, normals, albedo, E_UV logged)
        ("a", 0): (0.02, 9.2, 0.0070, 0.002),
        ("a", 2): (0.22, 9.9, 0.0080, 0.035),
        ("b", 0): (0.03, 9.3, 0.0060, 0.003),
        ("b", 2): (0.20, 9.1, 0.0065, 0.030),  # the one pair whose normals go against its UV error
    }
    for (arm, seed), (uv, normal, albedo, loss) in arms.items():
        extra = ("+experiment=smoke",) + (("loss.weights.Ni=5",) if arm == "b" else ())
        ev = {"uv_error": uv, "normal_mean": normal, "albedo_si_mse": albedo, "normal_at_true_uv_mean": 8.0, **base}
        d = make_run(tmp_path, f"{arm}{seed}", "implicit", seed=seed, eval_=ev, extra=extra)
        rows = [{"step": s, "total": 1.0, "UV": loss} for s in range(0, 1501, 25)]
        (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    make_run(tmp_path, "e0", "explicit", eval_={"normal_mean": 9.0}, extra=("+experiment=smoke",))
    make_run(tmp_path, "i9", "implicit", seed=9, eval_={"normal_mean": 9.0}, extra=("+experiment=smoke",))
    rep = report.Report(tmp_path / "reports")
    training.sec_uv_by_seed(rep, find_runs([tmp_path]))
    text = "\n".join(rep.lines)
    rows = [line for line in rep.lines if line.startswith("| ") and not line.startswith("| setting")]
    assert len(rows) == 4 + 2  # a row per run, then one per setting
    assert "| 2 | 0.0350 | 0.0350 | 0.220 | 9.90 |" in text
    assert "Of 4 runs, 2 draw a UV map nearer the truth than the pseudo UV" in text
    assert "2 one farther from it than the dataset-mean UV map (0.140)" in text
    w = f"{composed_config(('model=implicit',))['loss']['weights']['UV']:g}"  # the runs' E_UV weight: conf's
    assert f"weight {w}, seed 0: 0.020-0.030 over 2; weight {w}, seed 2: 0.200-0.220 over 2" in text
    assert "In 1 of 2 pairs of runs of one setting, the run with the smaller UV error has the smaller normal" in text
    assert "in 6 of 6 pairs of runs the one with the smaller E_UV at step 1,000 ends with the smaller UV error" in text
    assert "| +experiment=smoke | 0.120 ± 0.141 (n=2) | 1 of 2 | 9.55 ± 0.49 (n=2) |" in text  # by setting
    assert (tmp_path / "reports" / "figures" / "uv_by_seed.png").is_file()

    runs = find_runs([tmp_path])  # the glance counts the ladder's runs alone: setting b is off it
    assert tables.ladder_runs(runs) and training.uv_glance_lines(runs, tables.ladder_runs(runs)) == [
        "The implicit model's UV map, scored ladder runs whose UV map is farther from the truth than the "
        "dataset-mean UV map (0.140): `+experiment=smoke` 1 of 2 (seed(s) 2: normals 9.90 (n=1) deg against "
        "9.20 (n=1) for the others). The section *Stability across seeds* shows when and why.\n"
    ]
    assert training.uv_glance_lines([r for r in runs if r.model == "explicit"], tables.ladder_runs(runs)) == []

    rep = report.Report(tmp_path / "none")  # no scored implicit run: a note, no figure
    training.sec_uv_by_seed(rep, [r for r in find_runs([tmp_path]) if r.model == "explicit"])
    assert rep.lines[0].startswith(document.MISSING) and not (tmp_path / "none" / "figures" / "uv_by_seed.png").exists()

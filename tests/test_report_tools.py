"""The report's sections on the tools' results (disent.report.tools, disent.report.benchmarks)."""

import json

import pytest

from disent import report
from disent.eval.stability import training_stability
from disent.report import benchmarks, tools
from disent.runs import find_runs
from tests.run_fakes import fake_suite, make_run


def test_training_stability_rates(tmp_path):
    fake_suite(tmp_path)
    rows = training_stability(find_runs([tmp_path]))["rows"]
    r = {(x["model"], x["adversarial"]): x for x in rows}
    assert r[("explicit", False)]["nan_rate"] == 1.0
    assert r[("implicit", True)]["diverged_rate"] == 1.0 and r[("implicit", True)]["runs"] == 1
    assert r[("explicit", True)]["nan_rate"] == 0.0 and r[("explicit", True)]["runs"] == 2


def test_outcome_catches_early_explosion_and_dead_output(tmp_path):
    import torch

    from disent.eval.stability import FAILURES, input_dependence, outcome

    # the blow-up came before the first log, then the loss fell: last/first says "ok", the spread says "exploded"
    r = find_runs([make_run(tmp_path, "0", losses=(2e4, 5.0, 1.9), eval_={"recon_mse": 0.05})])[0]
    assert r.status == "ok" and outcome(r) == "exploded"
    ok = find_runs([make_run(tmp_path, "1", losses=(3.0, 2.0, 1.0), eval_={"recon_mse": 0.05})])[0]
    assert outcome(ok) == "ok" and outcome(ok, dependence=1e-4) == "collapsed" and outcome(ok, dependence=0.5) == "ok"
    images = torch.rand(4, 3, 8, 8, generator=torch.Generator().manual_seed(0))

    class Const(torch.nn.Module):
        def forward(self, x):
            return {"recon": torch.full_like(x, 0.3)}

    class Identity(torch.nn.Module):
        def forward(self, x):
            return {"recon": x.clone()}

    assert input_dependence(Const(), images) == 0.0
    assert input_dependence(Identity(), images) == pytest.approx(1.0)
    rows = training_stability(find_runs([tmp_path]))["rows"]
    assert len(rows) == 1 and rows[0]["exploded_rate"] == 0.5 and sum(rows[0][f + "_rate"] for f in FAILURES) == 0.5


def test_bench_section_charts_the_fractions_of_peak(tmp_path):
    """A bench.json with models and a profile gets the fraction-of-peak and the profile charts and
    every figure in a table; one without them gets only the tables."""
    models = {
        "explicit": {"train_fraction_of_peak": 0.58, "infer_fraction_of_peak": 0.66, "train_img_s": 52.0},
        "implicit": {"train_fraction_of_peak": 0.55, "infer_fraction_of_peak": 0.7, "train_img_s": 46.0},
    }
    profile = {
        "explicit_train_step_ms": {
            "01 aten::convolution_backward": 6.0,
            "02 aten::mm": 2.0,
            "03 aten::gather": 1.0,
            "other": 1.0,
            "total": 10.0,
            "convolution_share": 0.6,
        }
    }
    norm_cost = {
        "batch": {"infer_img_s": 0.99, "train_img_s": 0.78},
        "group": {"infer_img_s": 0.89, "train_img_s": 0.86},
    }
    (tmp_path / "bench.json").write_text(
        json.dumps({"device": "cpu", "threads": 2, "models": models, "profile": profile, "norm_cost": norm_cost})
    )
    rep = report.Report(tmp_path)
    report.sec_bench(rep, tmp_path)
    text = "\n".join(rep.lines)
    for fig in ("bench_fractions.png", "bench_profile.png"):
        assert (tmp_path / "figures" / fig).stat().st_size > 0 and f"figures/{fig}" in text
        (tmp_path / "figures" / fig).unlink()
    assert "| explicit.train_fraction_of_peak | 0.58 |" in text
    assert "| explicit | nan | 52.0 (0.58) | - |" in text  # no forward FLOPs nor inference rate given
    assert "| model.norm | train with D | infer batch 64 |" in text  # the rates in the models table's order
    assert "| batch | 0.78 | 0.99 |" in text and "| group | 0.86 | 0.89 |" in text
    (tmp_path / "bench.json").write_text(json.dumps({"device": "cpu", "data": {"images_per_s_64": 1000.0}}))
    rep = report.Report(tmp_path)
    report.sec_bench(rep, tmp_path)
    assert not (tmp_path / "figures" / "bench_fractions.png").exists() and "| images_per_s_64 | 1000 |" in "\n".join(
        rep.lines
    )


def test_bench_section_puts_gpu_figures_beside_the_cpu_ones(tmp_path):
    """``bench.json`` (CPU) and ``bench-cuda.json`` (GPU) each get a subsection naming the device, a
    row per model, their own charts; the CPU targets are checked against the CPU figures only, and the GPU's
    subsection says whether the suite's time on that card was measured."""

    def bench(device, train_frac, ratio):
        model = {
            "flops_per_image": 3.2e8,
            "train_img_s": 40.0,
            "train_fraction_of_peak": train_frac,
            "infer_img_s": 350.0,
            "infer_fraction_of_peak": 0.66,
        }
        return {
            "device": device,
            "threads": 2,
            "models": {"explicit": model, "implicit": dict(model)},
            "models_setup": {"implicit_vs_explicit": {"train_img_s": ratio}, "loader_vs_fastest_training": 4.0},
        }

    (tmp_path / "bench.json").write_text(json.dumps(bench("cpu", 0.54, 0.9)))
    (tmp_path / "bench-cuda.json").write_text(json.dumps(bench("cuda (NVIDIA H100)", 0.2, 0.6)))
    rep = report.Report(tmp_path)
    report.sec_bench(rep, tmp_path)
    text = "\n".join(rep.lines)
    cpu, gpu = text.split("### cuda (NVIDIA H100) (`reports/bench-cuda.json`)")
    assert "### cpu (`reports/bench.json`)" in cpu
    assert "| explicit | 0.320 | 40.0 (0.54) | 350.0 (0.66) |" in cpu and "| implicit | 0.320 | 40.0 (0.54)" in cpu
    assert "train with D, fraction of peak: 0.540 (target >= 0.55): **missed**" in cpu
    assert "infer batch 64, fraction of peak: 0.660 (target >= 0.6): **met**" in cpu
    assert "train with D: 0.900 (target >= 0.7): **met**" in cpu and "4.000 (target >= 1.0): **met**" in cpu
    assert "| explicit | 0.320 | 40.0 (0.20) |" in gpu and "Targets on the CPU" not in gpu and "(target >=" not in gpu
    assert "_Not measured on this card: the 33-run long-rung suite" in gpu and "Not measured" not in cpu
    for name in ("bench_fractions.png", "bench-cuda_fractions.png"):
        assert (tmp_path / "figures" / name).stat().st_size > 0
    assert "figures/bench_fractions.png" in cpu and "figures/bench-cuda_fractions.png" in gpu


def test_ood_table_reports_where_each_estimator_breaks(tmp_path):
    """The severity where an error first passes BREAK_FACTOR x its clean value is read off the curve; a model with
    neither normals nor light (the baseline) gets no row."""
    from disent import report

    res = {
        "severities": [0.0, 0.5, 1.0],
        "n": 4,
        "effects": {
            "yaw": {
                "explicit": {"normal_mean": [10.0, 14.0, 16.0], "sh_error": [0.6, 0.62, 0.7]},
                "ls_true": {"sh_error": [0.4, 0.7, 0.8]},
                "baseline": {"recon_face_mse": [0.002, 0.004, 0.008]},
            }
        },
    }
    rep = report.Report(tmp_path)
    tools._stability_ood(rep, res)
    rows = [line for line in rep.lines if line.startswith("| yaw |")]
    assert rows == [
        "| yaw | explicit | 10 -> 16 | 1 | 0.6 -> 0.7 | – |",  # 16 > 1.5 x 10 only at severity 1
        "| yaw | ls_true | – | – | 0.4 -> 0.8 | 0.5 |",
    ]


def test_bws_table_says_where_the_skin_went_and_keeps_older_studies_readable(tmp_path):
    """Each (arm, batch) row averages its seeds' skin correlations; the truth's are quoted once; a row scored
    before the skin metrics existed shows a dash instead of failing."""
    from disent import report

    base = {"variant": "explicit", "bws": True, "shading_mean_rgb": [0.75, 0.75, 0.75], "shading_cast": 0.01}
    base |= {"albedo_shading_corr": 0.1, "steps": 400, "true_shading_albedo_tone_corr": -0.04}
    base |= {"true_shading_albedo_brightness_corr": 0.06, "normal_mean": 15.0, "trivial_normal_mean": 17.07}
    rows = [
        {**base, "batch_size": 2, "seed": s, "shading_albedo_tone_corr": t, "shading_albedo_brightness_corr": b}
        for s, t, b in ((0, 0.2, 0.7), (1, 0.4, 0.9))
    ]
    old = {k: v for k, v in base.items() if not k.startswith(("true_", "normal", "trivial"))}
    old |= {"batch_size": 25, "seed": 0}
    rep = report.Report(tmp_path)
    tools._stability_bws(rep, {"rows": rows + [old], "n": 8})
    text = "\n".join(rep.lines)
    assert "(the true shading: -0.04 and 0.06)" in text and "(the dataset-mean normal map: 17.07 deg)" in text
    assert (
        "| with BWS | 2 | 400 | 2 | 0.75, 0.75, 0.75 | 0.010 ± 0.000 | 0.100 ± 0.000 | 0.300 ± 0.141 | 0.800 ± 0.141 "
        "| 15.000 ± 0.000 |" in text
    )
    assert "| with BWS | 25 | 400 | 1 | 0.75, 0.75, 0.75 | 0.010 | 0.100 | – | – | – |" in text


def test_photo_section_marks_a_network_no_better_than_the_training_means(tmp_path):
    """The domain gap beside the training set's constants: normals worse than the mean map are marked, a light
    better than the mean L-hat is not; a missing input says which command makes it."""
    rep = report.Report(tmp_path)
    report.sec_photos(rep, tmp_path)
    assert "python -m disent.eval.photos" in "\n".join(rep.lines)
    dom = {
        "n": 4,
        "recon_psnr": 21.8,
        "normal_vs_pseudo_deg": 17.5,
        "trivial_normal_vs_pseudo_deg": 16.7,
        "sh_vs_pseudo_mse": 0.30,
        "trivial_sh_vs_pseudo_mse": 0.38,
        "light_vs_pseudo_shading_si_mse": 0.009,
        "trivial_light_vs_pseudo_shading_si_mse": 0.007,
        "matte_iou_mask_pseudo": 0.7,
    }
    gap = {
        "model": "explicit",
        "training": {"epochs": 20, "train_size": 20000},
        "photo_pixels": "linear",
        "photos": dom,
        "synthfaces_test": dom,
    }
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "domain_gap_explicit_shipped.json").write_text(json.dumps(gap))
    rep = report.Report(tmp_path)
    report.sec_photos(rep, tmp_path)
    row = next(line for line in rep.lines if line.startswith("| explicit (explicit_shipped) |") and "photos" in line)
    assert (
        "| photos | 4 | 21.80 | 17.50 (not better) | 16.70 | 0.300 | 0.380 | 0.0090 (not better) | 0.0070 | 0.700 |"
        in row
    )


def test_time_to_accuracy_is_read_out_in_the_bench_section():
    tta = {
        "run": "/runs/x",
        "trivial": {"minutes": 1.1, "step": 150, "images": 3750, "source": "val", "normal_mean": 17.2, "target": 17.5},
        "pseudo_gt": {"minutes": None, "target": 11.46},
        "best_normal_mean": 12.48,
        "best_minutes": 9.33,
    }
    text = benchmarks.time_to_accuracy_text(tta)
    assert "mean map after **1.1 training minutes** (step 150, 3,750 images; 17.20 against 17.50" in text
    assert "the pseudo-GT never (its 11.46 deg)" in text and "best 12.48 deg after 9.3 minutes" in text


def test_ood_section_says_where_a_uv_model_breaks(tmp_path):
    """The out-of-distribution table, and for a model with a UV map the step its normals break in, read where they
    break: the UV map, the UV-space normals looked up at the true UV, or both."""

    def curves(normal, uv, looked_up):
        return {"implicit": {"normal_mean": normal, "uv_error": uv, "normal_at_true_uv_mean": looked_up}}

    res = {
        "severities": [0.0, 0.5, 1.0],
        "n": 8,
        "effects": {
            "yaw": curves([10.0, 12.0, 30.0], [0.02, 0.03, 0.2], [9.0, 10.0, 11.0]),
            "noise": curves([10.0, 16.0, 20.0], [0.02, 0.02, 0.03], [9.0, 15.0, 19.0]),
            "occluder": curves([10.0, 20.0, 20.0], [0.02, 0.1, 0.1], [9.0, 20.0, 20.0]),
            "light": curves([10.0, 11.0, 12.0], [0.02, 0.02, 0.02], [9.0, 9.5, 10.0]),
        },
    }
    rep = report.Report(tmp_path)
    tools._stability_ood(rep, res)
    text = "\n".join(rep.lines)
    assert "| yaw | implicit | 10 -> 30 | 1 |" in text and "| light | implicit | 10 -> 12 | – |" in text
    assert "| yaw | implicit | 0.02 -> 0.2 | 9 -> 11 | the UV map (at 1: uv error 0.2, normals 30 deg, 11 at" in text
    assert (
        "| noise | implicit | 0.02 -> 0.03 | 9 -> 19 | the UV-space normals (at 0.5: uv error 0.02, normals 16" in text
    )
    assert "| occluder | implicit | 0.02 -> 0.1 | 9 -> 20 | the UV map and the UV-space normals (at 0.5:" in text
    assert "| light | implicit | 0.02 -> 0.02 | 9 -> 10 | – |" in text


def test_bws_section_reads_the_fixed_images_budget(tmp_path):
    def row(bws, bs, steps, tone):
        return {
            "variant": "explicit",
            "bws": bws,
            "lhat_white": bws,
            "batch_size": bs,
            "steps": steps,
            "shading_mean_rgb": [0.7, 0.7, 0.7],
            "shading_cast": 0.01,
            "albedo_shading_corr": 0.1,
            "shading_albedo_tone_corr": tone,
            "shading_albedo_brightness_corr": 0.5,
            "true_shading_albedo_tone_corr": -0.04,
        }

    fixed_steps = [row(b, bs, 400, 0.5) for b in (True, False) for bs in (1, 25)]
    rep = report.Report(tmp_path)
    tools._stability_bws(rep, {"rows": fixed_steps, "n": 8})
    assert "On the same" not in "\n".join(rep.lines)  # one budget only: nothing to read
    images = [row(True, 1, 10000, t) for t in (-0.1, 0.1)] + [row(False, 1, 10000, t) for t in (0.2, 0.3)]
    rep = report.Report(tmp_path)
    tools._stability_bws(rep, {"rows": fixed_steps + images, "n": 8})
    text = "\n".join(rep.lines)
    assert "On the same 10,000 images" in text
    assert "batch 1: 0.00 ± 0.14 (n=2) with BWS, 0.25 ± 0.07 (n=2) without BWS, raw L-hat target" in text
    assert (
        "batch 25: 0.50 (n=1) with BWS, 0.50 (n=1) without BWS, raw L-hat target, lower with BWS: not testable" in text
    )

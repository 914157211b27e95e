"""The report and the run-folder readers on tiny fake run folders (no training)."""

import json
import math
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from disent import report
from disent.eval.ablation import ablation_table, to_markdown
from disent.eval.stability import training_stability
from disent.publish import write_records
from disent.report import ablations, benchmarks, claims, document, lighting, tables, tools, training
from disent.runs import Run, composed_config, find_runs, group_by_setting, measured_setting, pick_runs


def make_run(
    root, name, model="explicit", ablations=(), seed=0, losses=(3.0, 2.0, 1.0), eval_=None, ips=500.0, extra=()
):
    d = root / name
    (d / ".hydra").mkdir(parents=True)
    ov = [f"model={model}", f"seed={seed}", *extra] + ([f"+ablation=[{','.join(ablations)}]"] if ablations else [])
    cfg = composed_config(tuple(ov))  # what training resolves with these overrides
    (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    (d / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(ov))
    (d / ".hydra" / "hydra.yaml").write_text(
        yaml.safe_dump({"hydra": {"runtime": {"choices": {"model": model, "experiment": "smoke"}}}})
    )
    rows = [{"step": i, "total": l, "images_per_s": ips} for i, l in enumerate(losses)]  # what training logs
    (d / "metrics.jsonl").write_text(
        "".join(json.dumps(r) + "\n" for r in rows) + '{"step": 9, "total"'
    )  # torn last line
    if eval_ is not None:
        (d / "eval.json").write_text(json.dumps(eval_))
    return d


def fake_suite(root):
    smoke = ("+experiment=smoke",)
    make_run(root, "0", "baseline", eval_={"recon_mse": 0.01}, ips=900, extra=smoke)
    ev = {"recon_mse": 0.02, "normal_mean": 20.0, "pseudo_normal_mean": 15.0}
    make_run(root, "1", "explicit", seed=0, eval_=ev, extra=smoke)
    ev = {"recon_mse": 0.04, "normal_mean": 22.0, "pseudo_normal_mean": 15.0}
    make_run(root, "2", "explicit", seed=1, eval_=ev, extra=smoke)
    make_run(root, "3", "explicit", ["no_bws"], eval_={"recon_mse": 0.03, "normal_mean": 30.0}, ips=700, extra=smoke)
    make_run(root, "4", "explicit", ["no_adv"], losses=(1.0, None), extra=smoke)  # NaN logged as null
    make_run(root, "5", "implicit", losses=(1.0, 5.0), extra=smoke)  # diverged, never evaluated
    make_run(root, "6", "implicit", extra=smoke)  # still running: incomplete


def test_run_labels_and_status(tmp_path):
    fake_suite(tmp_path)
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert len(runs) == 7
    assert runs["3"].variant == "explicit+no_bws" and runs["4"].ablations == ["no_adv"] and not runs["4"].adversarial
    assert [runs[k].status for k in "0123456"] == ["ok", "ok", "ok", "ok", "nan", "diverged", "incomplete"]
    assert runs["1"].value("normal_mean") == 20.0 and runs["1"].value("images_per_s") == 500.0


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


def test_training_stability_rates(tmp_path):
    fake_suite(tmp_path)
    rows = training_stability(find_runs([tmp_path]))["rows"]
    r = {(x["model"], x["adversarial"]): x for x in rows}
    assert r[("explicit", False)]["nan_rate"] == 1.0
    assert r[("implicit", True)]["diverged_rate"] == 1.0 and r[("implicit", True)]["runs"] == 1
    assert r[("explicit", True)]["nan_rate"] == 0.0 and r[("explicit", True)]["runs"] == 2


def test_contents_links_each_section_by_githubs_heading_anchor():
    """GitHub's anchors: punctuation dropped, spaces made hyphens, a repeated heading numbered; the claims'
    subsections listed under their section, no other section's; headings inside code blocks are not headings."""
    md = "\n".join(
        [
            "# disent report",
            "## The paper's claims, measured",
            "### 1. The network's normals go beyond the fit",
            "## Benchmarks (`reports/bench*.json`)",
            "### (defaults)",
            "```",
            "## not a heading",
            "```",
            "## Ablations",
            "### (defaults)",
        ]
    )
    assert document.contents(md, open_sections=("The paper's claims, measured",)) == [
        "**Contents**\n\n"
        "- [The paper's claims, measured](#the-papers-claims-measured)\n"
        "  - [1. The network's normals go beyond the fit](#1-the-networks-normals-go-beyond-the-fit)\n"
        "- [Benchmarks (`reports/bench*.json`)](#benchmarks-reportsbenchjson)\n"
        "- [Ablations](#ablations)\n"
    ]
    seen = {}
    assert [document.heading_anchor("(defaults)", seen) for _ in range(3)] == ["defaults", "defaults-1", "defaults-2"]


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


def test_shipped_weights_are_named_by_every_setting_they_differ_in_from_todays_conf(monkeypatch):
    """Shipped weights trained before a default changed (E_UV x1 at the long rung, then x10): their full setting
    names the old value, as a run's does; in the light-target terms only the rung and the target count."""
    from disent.models import shipped

    cfg = composed_config(("+experiment=long", "model=implicit", "loss.weights.UV=0.5", "loss.recon_L_target=sh"))
    monkeypatch.setattr(shipped, "manifest", lambda folder=None: {"m": {"cfg": cfg, "run": "/gone/m"}})
    assert claims.shipped_setting("m", full=True) == "+experiment=long loss.recon_L_target=sh loss.weights.UV=0.5"
    assert claims.shipped_setting("m") == "+experiment=long loss.recon_L_target=sh"
    cfg = composed_config(("model=implicit",))
    monkeypatch.setattr(shipped, "manifest", lambda folder=None: {"m": {"cfg": cfg, "run": "/gone/m"}})
    assert claims.shipped_setting("m", full=True) == claims.shipped_setting("m") == "(defaults)"


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


def test_run_status_callback_marks_nan(tmp_path):
    from hydra.core.utils import JobReturn, JobStatus
    from omegaconf import OmegaConf

    from disent.runs import Run, RunStatus

    d = make_run(tmp_path, "r", losses=(1.0, 0.5))  # the log itself looks healthy
    hydra_cfg = OmegaConf.create({"hydra": {"runtime": {"output_dir": str(d)}}})
    ret = JobReturn(
        hydra_cfg=hydra_cfg,
        status=JobStatus.FAILED,
        _return_value=FloatingPointError("loss term 'BWS' is not finite at step 3"),
    )
    RunStatus().on_job_end(None, ret)
    assert Run.load(d).status == "nan"
    ret = JobReturn(hydra_cfg=hydra_cfg, status=JobStatus.FAILED, _return_value=RuntimeError("out of memory"))
    RunStatus().on_job_end(None, ret)
    assert Run.load(d).status == "failed"


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


def test_pick_runs_prefers_the_longest_trained_run(tmp_path):
    from disent.runs import pick_runs

    short = make_run(tmp_path, "short", "explicit", seed=0, eval_={"steps": 30})
    long = make_run(tmp_path, "long", "explicit", seed=1, eval_={"steps": 700})
    ablated = make_run(tmp_path, "abl", "explicit", ["no_bws"], seed=0, eval_={"steps": 900})
    for d in (short, long, ablated):
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "last.pt").write_bytes(b"")
    chosen = pick_runs(find_runs([tmp_path]))
    assert set(chosen) == {"explicit"} and chosen["explicit"].path.name == "long"


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
    row per model, their own charts; the CPU targets are checked against the CPU figures only."""

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
    assert "| explicit | 0.320 | 40.0 (0.20) |" in gpu and "target" not in gpu
    for name in ("bench_fractions.png", "bench-cuda_fractions.png"):
        assert (tmp_path / "figures" / name).stat().st_size > 0
    assert "figures/bench_fractions.png" in cpu and "figures/bench-cuda_fractions.png" in gpu


def test_placement_reading_quotes_the_refined_and_the_true_placement_on_both_splits():
    """The pseudo verdict says what the coarse fit's placement is worth under the residual process: refined against
    the image (with its uv registered too, where the study has that row), and made true, each on val and test with
    its scene counts; nothing where fewer than two rows are on both splits."""

    def row(accuracy, n):
        return {"evidence": {"accuracy": accuracy, "confusion": [[n, 0, 0], [0, 0, 0], [0, 0, 0]]}}

    order = {
        "val/texture/normal_pseudo_placed+residual_process": row(0.82, 300),
        "test/texture/normal_pseudo_placed+residual_process": row(0.79, 300),
        "val/texture/oracle_placement+residual_process": row(0.92, 60),
        "test/texture/oracle_placement+residual_process": row(0.83, 60),
    }
    text = lighting.placement_reading(order)
    assert "0.82/0.79 (300/300 scenes) with it refined against the image" in text, text
    assert "0.92/0.83 (60/60 scenes) with it made true (an oracle)" in text, text
    assert "registered" not in text  # a row the study lacks is not read
    order["val/texture/normal_pseudo_placed_registered+residual_process"] = row(0.88, 300)
    order["test/texture/normal_pseudo_placed_registered+residual_process"] = row(0.86, 240)
    assert "0.88/0.86 (300/240 scenes) with it refined and its uv registered" in lighting.placement_reading(order)
    del (
        order["test/texture/oracle_placement+residual_process"],
        order["val/texture/normal_pseudo_placed+residual_process"],
    )
    assert lighting.placement_reading(order) == ""  # one row on both splits is no comparison


def test_known_albedo_reading_quotes_the_best_known_albedo_row_on_pseudo_geometry():
    """The lighting verdict says what the pseudo geometry allows with the true albedo: the known-albedo row on
    pseudo normals best on val, read on val and test, whether that is under the target, and whether the target lies
    inside the row's 95 % interval (0.9 over 60 scenes: 0.80-0.95; over 1000: 0.88-0.92)."""

    def row(accuracy, n=60):
        return {"evidence": {"accuracy": accuracy, "confusion": [[n, 0, 0], [0, 0, 0], [0, 0, 0]]}}

    order = {
        "val/known/normal_pseudo": row(0.68),
        "test/known/normal_pseudo": row(0.73),
        "val/known/normal_pseudo+geometry_noise": row(0.82),
        "test/known/normal_pseudo+geometry_noise": row(0.88),
        "val/known/normal": row(1.0),
        "test/known/normal": row(1.0),
    }
    text = lighting.known_albedo_reading(order)
    assert "`known/normal_pseudo+geometry_noise`) the choice reaches 0.82 on val and 0.88 on test" in text, text
    assert text.endswith("not expected to bring it to the target on both splits.")
    both = {k: row(0.9) if "geometry_noise" in k else v for k, v in order.items()}
    assert lighting.known_albedo_reading(both).endswith(
        "is enough, but only just: the target lies inside its 95 % interval."
    )
    both = {k: row(0.9, 1000) if "geometry_noise" in k else v for k, v in order.items()}
    assert lighting.known_albedo_reading(both).endswith("is enough.")
    assert lighting.known_albedo_reading({"val/texture/normal_pseudo": row(0.7)}) == ""
    # the same reading for another geometry: only its own known-albedo rows count
    order |= {"val/known/network_a": row(0.86), "test/known/network_a": row(0.9), "val/known/network_b": row(0.8)}
    text = lighting.known_albedo_reading(order, "network_", "networks' geometry")
    assert "networks' geometry (the known-albedo row best on val, `known/network_a`) the choice reaches 0.86" in text
    assert text.endswith("is enough, but only just: the target lies inside its 95 % interval.")


def test_combined_reading_sets_both_noise_models_beside_each_alone():
    """The two noise models together, per geometry run on both splits, beside each model alone on the same row where
    the study has it; nothing where no combined row was run on both splits."""

    def row(accuracy):
        return {"evidence": {"accuracy": accuracy}}

    order = {
        f"{split}/texture/network_explicit{suffix}": row(value + (0.05 if split == "test" else 0))
        for split in ("val", "test")
        for suffix, value in (
            ("+geometry_noise", 0.67),
            ("+residual_process", 0.72),
            ("+geometry_noise+residual_process", 0.7),
        )
    } | {"val/texture/normal_pseudo_registered+geometry_noise+residual_process": row(0.6)}
    text = lighting.combined_reading(order)
    assert "0.70/0.75 on network_explicit" not in text  # the geometry's label, not its key
    assert "0.70/0.75 on " in text and "(0.67/0.72 geometry noise alone, 0.72/0.77 residual alone)" in text, text
    assert "0.60" not in text  # a row run on val alone is left out
    assert text.endswith("together beats each model alone on 0 of 1 geometries.\n")  # 0.70 on val against 0.72
    assert lighting.combined_reading({k: v for k, v in order.items() if "+geometry_noise+" not in k}) == ""


def test_uv_oracle_reading_says_whether_the_true_uv_reaches_the_target():
    """The networks' geometry with the true uv (an oracle row): at or above the target on both splits, the uv is what
    stands in the way; under it on either, not even a true uv is enough; nothing where the study lacks the row."""

    def row(accuracy):
        return {"evidence": {"accuracy": accuracy}}

    key = "texture/oracle_uv_network+geometry_noise"
    text = lighting.uv_oracle_reading({f"val/{key}": row(0.9), f"test/{key}": row(0.88)})
    assert "reaches 0.90 on val and 0.88 on test" in text and text.endswith(
        "stands between this geometry and the target."
    )
    assert lighting.uv_oracle_reading({f"val/{key}": row(0.9), f"test/{key}": row(0.8)}).endswith(
        "short of the target."
    )
    assert lighting.uv_oracle_reading({f"val/{key}": row(0.9)}) == ""


def test_band2_reading_sets_each_geometry_beside_the_true_order2_lights():

    def row(order1):
        return {"band2_share": {"fitted_by_true_order": [0.0, order1, 0.6], "true_order2": 0.56}}

    order = {"test/texture/normal": row(0.01), "test/known/normal_pseudo": row(0.44), "test/texture/x": row(0.71)}
    text = lighting.band2_reading(order, "texture/x")
    assert (
        "0.01 on true normals (texture model), 0.44 on pseudo normals with the known albedo, 0.71 on the chosen" in text
    )
    assert "a true order-2 light holds 0.56." in text
    assert lighting.band2_reading({**order, "test/texture/x": {}}, "texture/x") == ""  # a study from before band 2


def test_network_reading_sets_the_network_row_beside_the_pseudo_one():
    from disent.report import lighting

    def row(acc, order1=None):
        band2 = {"band2_share": {"fitted_by_true_order": [0.1, order1, 0.6], "true_order2": 0.56}} if order1 else {}
        return {"evidence": {"accuracy": acc, "confusion": [[20, 0, 0], [0, 20, 0], [0, 0, 20]]}} | band2

    # 60 scenes each: two rows closer than 1.96 sqrt(sum p (1 - p) / n), about 0.15, are within the spread
    assert lighting.difference_spread((0.77, 60), (0.75, 60)) == pytest.approx(0.153, abs=1e-3)
    order = {"test/texture/net": row(0.77, 0.71), "test/texture/pseudo": row(0.75, 0.68)}
    text = lighting.network_reading(order, "texture/net", "texture/pseudo")
    assert "scores +0.02 against the pseudo geometry's chosen row: within the sampling spread" in text
    assert "holds 0.71 in band 2 (0.68 on the pseudo geometry's); a true order-2 light holds 0.56." in text
    order["test/texture/pseudo"] = row(0.5)  # beyond the spread; a row from before the band-2 diagnostic
    text = lighting.network_reading(order, "texture/net", "texture/pseudo")
    assert (
        "+0.27 against the pseudo geometry's chosen row: beyond the sampling spread, in the networks' favour." in text
    )
    assert "band 2" not in text
    order["test/texture/pseudo"] = row(0.99)
    text = lighting.network_reading(order, "texture/net", "texture/pseudo")
    assert (
        "-0.22 against the pseudo geometry's chosen row: beyond the sampling spread, in the pseudo geometry's favour."
        in text
    )
    assert lighting.network_reading(order, "texture/net", None) == ""


def test_lighting_section_is_generated_from_the_published_json(tmp_path):
    """The lighting section tabulates order choice and calibration from reports/lighting/*.json and states the
    order-choice verdict from the numbers: on test, for the noise model best on val, reached only at or above
    the target."""
    import json

    from disent import report

    d = tmp_path / "lighting"
    d.mkdir()
    confusion = lambda acc: {"confusion": [[20, 0, 0], [0, 20, 0], [0, 0, 20]], "accuracy": acc}  # noqa: E731
    order = {
        "test/known/normal": {"evidence": confusion(1.0), "bic": confusion(0.9)},
        "val/texture/normal_pseudo+geometry_noise": {"evidence": confusion(0.47), "bic": confusion(0.4)},
        "val/texture/normal_pseudo+residual_process": {"evidence": confusion(0.55), "bic": confusion(0.5)},
        "test/texture/normal_pseudo+geometry_noise": {"evidence": confusion(0.95), "bic": confusion(0.5)},
        "test/texture/normal_pseudo+residual_process": {"evidence": confusion(0.62), "bic": confusion(0.5)},
    }
    for split, base, uv, normals in (("val", 0.53, 0.68, 0.45), ("test", 0.62, 0.8, 0.5)):  # the oracle rows
        order[f"{split}/texture/normal_pseudo_eroded"] = {"evidence": confusion(base), "bic": confusion(base)}
        order[f"{split}/texture/oracle_uv"] = {"evidence": confusion(uv), "bic": confusion(uv)}
        registered = {"val": 0.5, "test": 0.7}[split]  # below the residual process on val: not chosen
        order[f"{split}/texture/normal_pseudo_registered"] = {"evidence": confusion(registered), "bic": confusion(0.1)}
        order[f"{split}/texture/oracle_normals"] = {"evidence": confusion(normals), "bic": confusion(normals)}
        placement = {"val": 0.7, "test": 0.83}[split]  # the largest gain of val and test together, short of 0.85
        order[f"{split}/texture/oracle_placement"] = {"evidence": confusion(placement), "bic": confusion(placement)}
    order["test/known/normal"]["band2_share"] = {"fitted_by_true_order": [0.01, 0.02, 0.5], "true_order2": 0.48}
    # the network rows: the best on val of both (explicit, 0.9 > 0.7) has its own verdict, read on test (0.88, not
    # the implicit row's 0.95); the pseudo verdict never picks a network row, though it is best on val
    for split, explicit, implicit in (("val", 0.9, 0.7), ("test", 0.88, 0.95)):
        order[f"{split}/texture/network_explicit+residual_process"] = {
            "evidence": confusion(explicit),
            "bic": confusion(0.8),
        }
        order[f"{split}/texture/network_implicit+residual_process"] = {
            "evidence": confusion(implicit),
            "bic": confusion(0.8),
        }
    (d / "calibration.json").write_text(
        json.dumps({"lambertian/gaussian": {"inside68": 0.674, "inside95": 0.94, "z_rms": 1.02}, "settings": {"n": 10}})
    )
    fit = {"rho": 300.0, "ell": 1.0, "n_scenes": 18, "split": "train"}
    (d / "residual_process.json").write_text(json.dumps({"normal_pseudo": fit}))
    speed = {"n_pixels": 1918, "ls_ms_per_image": 0.6, "ls_batch": 256, "posterior_gaussian_s": 0.55}
    speed |= {"posterior_gaussian_steps": 250, "posterior_student_t_s": 1.04, "posterior_student_t_steps": 300}
    speed |= {"order_choice_s": {"normal_pseudo_registered": 1.23, "normal_pseudo_placed": 4.56}}
    (d / "speed.json").write_text(json.dumps(speed | {"order_choice_items": 3}))
    for acc, verdict in ((0.62, "not reached"), (0.9, "reached")):
        order["test/texture/normal_pseudo+residual_process"]["evidence"]["accuracy"] = acc
        (d / "order.json").write_text(json.dumps(order))
        rep = report.Report(tmp_path)
        report.sec_lighting(rep, tmp_path)
        text = "\n".join(rep.lines)
        row = "| test | texture | pseudo normals + mask, residual process | [[20, 0, 0], [0, 20, 0], [0, 0, 20]] |"
        assert f"{row} {acc:.2f} |" in text and f"{row} {acc:.2f} | 0.50 | – |" in text  # measured before band 2
        assert "| 1.00 | 0.90 | 0.01 / 0.02 / 0.50 (0.48) |" in text
        assert "rho 300, ell 1 px from 18 train scenes on pseudo normals + mask" in text
        # the residual process is best on val (0.55 > 0.47): its test figure decides, not the best test row (0.95)
        assert "(`texture/normal_pseudo+residual_process`, val 0.55)" in text
        lo, hi = lighting.wilson_interval(acc, 60)
        assert f"on test: {acc:.2f} (95 % interval {lo:.2f}-{hi:.2f} over its 60 scenes)" in text
        where = {0.62: "the target above its interval", 0.9: "but the target lies inside its interval"}[acc]
        assert f"against the target {lighting.ORDER_TARGET:.2f}: **{verdict}**, {where}" in text
        assert "Verdict, the networks' geometry without the true albedo" in text
        assert "(`texture/network_explicit+residual_process`, val 0.90), on test: 0.88" in text
        lo, hi = lighting.wilson_interval(0.88, 60)
        assert f"0.88 (95 % interval {lo:.2f}-{hi:.2f} over its 60 scenes) against the target 0.85: **reached**" in text
        # beside the pseudo geometry's chosen row on test (0.62 or 0.9): beyond, then within the sampling spread
        gap = {0.62: "+0.26 against the pseudo geometry's chosen row: beyond", 0.9: "-0.02 against the pseudo"}[acc]
        assert gap in text and ("better normals alone do not bring the choice to the target" in text) == (acc == 0.9)
        assert "| val | texture | explicit network's normals + matte eroded 1 px, pseudo uv registered, resid" in text
        assert "| lambertian / gaussian | 0.67 / 0.94 (1.0) | – |" in text and "settings" not in text
        assert "median of test items 0-2: 1.2 s on `normal_pseudo_registered`, 4.6 s on `normal_pseudo_placed`." in text
        # an oracle row (val 0.68, above every noise model) is a diagnosis, never the chosen method
        assert "| val | texture | pseudo normals + mask eroded 1 px, true uv (oracle) |" in text
        assert "0.53/0.62 on the pseudo geometry, 0.50/0.70 with its uv registered to the image, 0.68/0.80 with" in text
        assert "0.70/0.83 with the coarse fit's placement (pose, scale, shift) made true." in text
        assert (
            "Nothing made true alone brings the test accuracy to the target; the largest gain (val and test "
            "together) comes with the coarse fit's placement (pose, scale, shift) made true." in text
        )
    rep = report.Report(tmp_path / "empty")
    report.sec_lighting(rep, tmp_path / "empty")
    assert rep.lines[0].startswith(document.MISSING)


def test_lhat_sources_table_reads_which_input_costs_l_hat_most(tmp_path):
    """The table lists every light with its inputs in words; the reading names the input whose truth lowers L-hat's
    error most (the albedo or the normals) and says whether the networks' light is below every L-hat without truth,
    from the numbers; a light alone in the section still builds it."""
    import json

    from disent import report

    def row(e, inputs):
        return {"light_on_face": e, "light_on_face_se": e / 10, "beats_lhat": 0.5, "shown": 0.1, "inputs": inputs}

    rows = {
        "lhat": row(0.0086, ["normal_pseudo", "constant", "mask_pseudo"]),
        "true_pixels": row(0.0066, ["normal_pseudo", "constant", "face"]),
        "true_pixels_normals": row(0.0034, ["normal", "constant", "face"]),
        "true_pixels_albedo": row(0.0011, ["normal_pseudo", "albedo", "face"]),
        "texture_model": row(0.0054, ["normal_pseudo", "texture_model", "eroded"]),
        "oracle_mix_0.5": row(0.0022, ["normal_pseudo", "constant", "mask_pseudo"]),  # uses the truth: not "without"
        "network_explicit": row(0.0044, ["network"] * 3),
        "network_explicit_refit": row(0.0048, ["normal_pseudo", "network", "matte"]),
        "floor": row(0.0163, ["-"] * 3),
    }
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "| L-hat | **true** | constant (the paper's) | **true face** inside M-hat | 0.0034 ± 0.0003 | 0.50 |" in text
    assert "| explicit: least squares over its albedo | N-hat | the network's | M-hat inside its matte | 0.0048" in text
    assert "| constant light (the mean train light; the floor) | – | – | – | 0.0163" in text
    assert (
        "| L-hat moved 0.5 of the way to the true light (`loss.recon_L_oracle_mix=0.5`) | N-hat | constant (the "
        "paper's) | M-hat | 0.0022 ± 0.0002 |" in text
    )
    assert "L-hat's constant albedo costs it more than its coarse-fit normals" in text
    assert (
        "the best L-hat here is the texture model (0.0054); the networks' own light (explicit 0.0044) is below" in text
    )
    assert "does not improve on the network's (explicit 0.0048)" in text and "sh_network_texture" not in text
    rows["network_explicit_texture"] = row(0.0026, ["network", "texture_model", "eroded_matte"])
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert (
        "| explicit network's light and the texture model through its geometry (`sh_network_texture`) | the "
        "network's | texture model, fitted with L | M-hat eroded 1 px inside its matte | 0.0026" in text
    )
    assert "(`sh_network_texture`), a network's light gets nearer than either (explicit 0.0026)" in text
    assert "explicit 0.0044) is below" in text  # the texture row is not one more network
    rows["network_explicit_texture"]["light_on_face"] = 0.0050
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "a network's light gets no nearer than both (explicit 0.0050)" in text
    del rows["network_explicit_texture"]
    rows["true_pixels_albedo"]["light_on_face"] = 0.005  # now the normals' truth helps more
    rows["network_explicit"]["light_on_face"] = 0.006  # and the network is above the texture model
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "L-hat's coarse-fit normals cost it more than its constant albedo" in text
    assert "(explicit 0.0060) is not below it" in text and "does not improve" not in text
    assert "| 0.0163 ± 0.0016 | 0.50 | 0.100 | – / – |" in text and "keeps each face's skin" not in text  # older JSON
    skin = {"lhat": (0.8, 0.77), "texture_model": (0.61, 0.76), "true_pixels_albedo": (-0.04, 0.05), "floor": (0, 0)}
    for k, (tone, bright) in skin.items():
        rows[k] |= {"skin_tone_corr": tone, "skin_brightness_corr": bright}
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert (
        "| 0.0086 ± 0.0009 | 0.50 | 0.100 | +0.80 / +0.77 | – |" in text and "light is flatter" not in text
    )  # older JSON
    assert (
        "fitted without the true albedo keeps each face's skin in its shading (tone +0.61 to +0.80, brightness "
        "+0.76 to +0.77" in text
    )  # the true albedo's and the floor's rows stay out of the range
    rows["lhat"]["contrast"], rows["texture_model"]["contrast"] = 0.92, 0.88
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "| 0.0086 ± 0.0009 | 0.50 | 0.100 | +0.80 / +0.77 | 0.92 |" in text and "a better pattern" not in text
    rows["lhat"] |= {"pattern_corr": 0.893, "contrast_ratio": 1.03}  # the contrast's two parts, where scored
    rows["texture_model"] |= {"pattern_corr": 0.903, "contrast_ratio": 0.96}
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "| +0.80 / +0.77 | 0.92 (0.89, 1.03) |" in text
    assert (
        "The texture model's light has a better pattern (0.90 against 0.89) and less magnitude (0.96 against 1.03) "
        "than L-hat's: contrast 0.88 against 0.92." in text
    )
    rows["lhat"]["log_error"], rows["texture_model"]["log_error"] = 0.254, 0.232
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "than L-hat's: contrast 0.88 against 0.92, log error 0.232 against 0.254." in text
    assert "Calibration about L-hat" not in text  # no network row with the sweep
    sweep = {"0.8": 0.0098, "0.9": 0.0091, "1.0": 0.0090, "1.2": 0.0112}
    rows["network_explicit"] |= {"calibration": 1.08, "sharpened_albedo": sweep}
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "| network | calibration | k = 0.8 | k = 0.9 | k = 1.0 | k = 1.2 |" in text
    assert "| explicit | 1.08 | 0.00980 | 0.00910 | 0.00900 | 0.01120 |" in text
    assert "best at k = 1.0 for explicit: the networks' shading is as contrasty as its pattern allows" in text
    rows["network_explicit"]["sharpened_albedo"] = sweep | {"1.2": 0.0080}  # a sharper shading would help
    text = "\n".join(lighting.lhat_source_lines({"split": "test", "n": 256, "rows": rows}))
    assert "best at k = 1.2 for explicit (11.1% below k = 1): a more contrasty shading would help explicit's" in text
    (tmp_path / "lighting").mkdir()
    (tmp_path / "lighting" / "lhat_sources.json").write_text(json.dumps({"split": "test", "n": 256, "rows": rows}))
    rep = report.Report(tmp_path)
    report.sec_lighting(rep, tmp_path)
    text = "\n".join(rep.lines)
    assert "### Where L-hat's error comes from" in text and "### Lighting model order" not in text


def test_beyond_the_fit_reads_each_bin_against_the_seed_spread():
    from types import SimpleNamespace

    from disent.eval.scoring import PSEUDO_ERROR_BINS

    bins = [f"{lo}_{hi}" for lo, hi in zip(PSEUDO_ERROR_BINS, PSEUDO_ERROR_BINS[1:])]

    def run(net):  # the network's error in each bin; the pseudo-GT's is the bin's index x 10
        values = {f"share_where_pseudo_{b}": 0.25 for b in bins}
        values.update({f"pseudo_normal_mean_where_pseudo_{b}": 10.0 * i for i, b in enumerate(bins)})
        values.update({f"normal_mean_where_pseudo_{b}": v for b, v in zip(bins, net)})
        return SimpleNamespace(value=values.get)

    runs = [run([5, 10.2, 15, 20]), run([5, 9.8, 15, 21])]  # loses, ties, loses... beats, beats
    lines = claims.beyond_the_fit({("long", "explicit"): runs, ("long", "baseline"): runs})
    assert sum(line.startswith("| `long`") for line in lines) == 1  # no row for a model without normals
    beaten, lost = ", ".join(b.replace("_", "-") for b in bins[2:]), bins[0].replace("_", "-")
    assert lines[-1] == (
        f"- `long`: the network beats the pseudo-GT where that errs by {beaten} deg; it loses to the pseudo-GT where "
        f"that errs by {lost} deg."
    )
    assert claims.beyond_the_fit({("long", "explicit"): [SimpleNamespace(value=lambda k: None)]}) == []


def test_claim_verdicts_need_seeds_and_a_difference_beyond_the_spread():
    from disent.report.tables import MIN_SEEDS, verdict

    n = MIN_SEEDS
    arm = lambda mean, std, k=n: {"mean": mean, "std": std, "n": k}  # noqa: E731  (what tables.seed_spread returns)
    assert verdict(arm(10.0, 0.2), arm(11.5, 0.0), "lower") == "**confirmed**"
    assert verdict(arm(12.0, 0.2), arm(11.5, 0.0), "lower") == "**refuted**"
    assert verdict(arm(11.4, 0.3), arm(11.5, 0.0), "lower").startswith("not resolved")
    assert verdict(arm(27.0, 0.1), arm(24.0, 0.1), "higher") == "**confirmed**"
    assert verdict(arm(10.0, 0.0, 1), arm(11.5, 0.0), "lower").startswith("not testable (1 seed")
    assert verdict(None, arm(11.5, 0.0), "lower").startswith("not testable")


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
    lines = claims.without_truth_lines(find_runs([tmp_path]))
    assert lines[0].startswith("Off the ladder: of the 3 other setting(s)") and "1 meet(s) every target" in lines[0]
    assert lines[1:] == [
        f"- `{' '.join(sorted(target))}` (implicit, long rung): normals 9.20 ± 0.14 (n=2) deg, face PSNR "
        "28.80 ± 0.00 (n=2) dB, albedo 0.0058 ± 0.0000 (n=2), 0.464 of the mean map's.",
        "",
    ]
    assert claims.rung_of("+experiment=long loss.lhat_gray=true") == "long"
    assert claims.rung_of("loss.lhat_gray=true") == "default"
    assert claims.rung_of("+experiment=long train.max_steps=5750") is claims.rung_of("+experiment=smoke") is None
    runs = find_runs([tmp_path])
    explicit = [r for r in runs if r.path.name.startswith("e")]
    assert claims.rung_misses("long", explicit) == ["default rung's albedo 0.53 of the mean map's (<= 0.5)"]
    assert claims.rung_misses("default", explicit) == ["albedo 0.53 of the mean map's (<= 0.5)"]
    assert claims.rung_misses(None, explicit) is None
    met = claims.without_truth_lines([r for r in runs if r.path.name.startswith(("e", "gray"))])
    assert met == [met[0]] and met[0].endswith("none meets every target of its rung.\n")
    assert claims.without_truth_lines([r for r in runs if r.path.name == "ladder"]) == []


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


def test_claims_open_with_each_verdict_at_the_ladders_rungs(tmp_path):
    """The claims section opens with the verdicts of its tables at the ladder's rungs, a row per reading and a
    column per rung and model: claim 4's cells are the ablation's difference, with its budget gate said under the
    table; a setting off the ladder adds no cell, and a reading no rung can test is named, not listed."""
    good = {"normal_mean": 11.0, "pseudo_normal_mean": 11.5, "recon_face_psnr": 26.5}
    good |= {"albedo_si_mse": 0.005, "trivial_albedo_si_mse": 0.0127}
    for seed in range(3):
        make_run(tmp_path, f"full{seed}", seed=seed, eval_={**good, "normal_mean": 11.0 + 0.01 * seed})
        make_run(tmp_path, f"base{seed}", "baseline", seed=seed, eval_={"recon_face_psnr": 24.0 + 0.01 * seed})
        make_run(
            tmp_path, f"nopn{seed}", ablations=["no_pseudo_normal"], seed=seed, eval_={**good, "normal_mean": 15.0}
        )
        make_run(
            tmp_path, f"tv{seed}", seed=seed, eval_={**good, "normal_mean": 20.0}, extra=("loss.weights.smooth_A=0.5",)
        )
    runs = find_runs([tmp_path])
    rep = report.Report(tmp_path)
    claims.sec_claims(rep, runs, tmp_path / "eval")
    text = "\n".join(rep.lines)
    assert text.index("| claim | reading | explicit, `(defaults)` |") < text.index("### 1.")
    assert "| 1 | normals closer to the truth than the pseudo-GT's | **confirmed** | – | – | – |" in rep.lines
    assert "| 3 | face PSNR above the 265-d baseline's | **confirmed** | – | – | – |" in rep.lines
    assert "| 4 | no_pseudo_normal: normals (deg) | **confirmed** | – | – | – |" in rep.lines
    assert "refuted" not in text.split("### 1.")[0]  # the off-ladder setting's worse normals stay in its own rows
    assert "Claim 4's cells" not in text  # the full model meets the targets: claim 4's verdicts are read
    for r in runs:
        if r.path.name.startswith("full"):
            r.eval["recon_face_psnr"] = 25.0  # under the target; still above the baseline
    rep = report.Report(tmp_path)
    claims.sec_claims(rep, runs, tmp_path / "eval")
    # gated: the cell is the ablation's difference, unbolded (not a verdict), and the gate is said under the table
    assert "| 4 | no_pseudo_normal: normals (deg) | difference confirmed | – | – | – |" in rep.lines
    assert any("`(defaults)` explicit: targets missed: 1 of 3" in line for line in rep.lines)

    glance = tables.Glance()
    glance.put("5", "senior by dmt", "+experiment=long", "implicit", claims.tally(["not testable (1 seed)"] * 2))
    glance.put(
        "5",
        "beard by dmt",
        "model=implicit +experiment=long",
        "implicit",
        claims.tally(["**confirmed**", "not resolved (within)", "**confirmed**"]),
    )
    glance.put("5", "beard by dmt", "+experiment=long loss.weights.UV=1.0", "explicit", "**refuted**")  # off the ladder
    lines = glance.lines()
    assert "| 5 | beard by dmt | – | – | – | **confirmed** 2, not resolved 1 of 3 |" in lines, lines
    assert not any("| senior by dmt |" in line for line in lines)
    assert "Not testable at either rung, so not listed: 5: senior by dmt.\n" in lines


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


def test_edit_claims_are_read_over_the_seeds_of_a_setting(tmp_path):
    """Claim 5 sets the edit results of one setting's models side by side: a verdict needs three of them and a
    gain beyond the spread; one shipped model alone is not testable, nor is an attribute no manifold set edits."""

    def claims(paper, rival, success):
        rows = []
        for attribute, s in (("beard", success), ("smiling", 0.2)):
            rows.append({"attribute": attribute, "method": "dmt", "manifolds": "paper:Ae", "gain_per_leak": paper})
            rows.append({"attribute": attribute, "method": "dmt", "manifolds": "Ne", "gain_per_leak": rival})
            for r in rows[-2:]:
                r["best_success"] = s
        return rows

    out = tmp_path / "reports"
    for i, (paper, rival) in enumerate(((2.0, 1.0), (2.1, 1.1), (1.9, 0.9))):
        d = out / "edit" / f"explicit_seed{i}_1200steps"
        d.mkdir(parents=True)
        run = make_run(tmp_path / "runs", f"s{i}", seed=i, eval_={"normal_mean": 12.0})
        res = {"model": "explicit", "setting": "(defaults)", "claims": claims(paper, rival, 0.6), "relight": []}
        drawn = [  # how often the reconstructed (0.1 + 0.1 i) and the true faces with a smile read as smiling
            {"attribute": "smiling", "method": m, "success": v}
            for m, v in (("truth reconstructed", 0.1 * (i + 1)), ("truth", 0.7))
        ]
        (d / "edit.json").write_text(json.dumps(res | {"run": str(run), "traversal": drawn}))
    gone = out / "edit" / "explicit_seed9_1200steps"  # its run folder is gone and left no record: not counted
    gone.mkdir()
    stale = {"model": "explicit", "setting": "(defaults)", "claims": claims(9.0, 1.0, 0.6), "run": "/nowhere"}
    (gone / "edit.json").write_text(json.dumps(stale))
    (out / "edit" / "explicit").mkdir()
    shipped = {"model": "explicit", "setting": "shipped", "claims": claims(2.0, 1.0, 0.6), "relight": []}
    (out / "edit" / "explicit" / "edit.json").write_text(json.dumps(shipped))
    make_run(tmp_path / "runs", "a", eval_={"normal_mean": 12.0, "pseudo_normal_mean": 11.5})
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")
    rows = [line for line in rep.lines if line.startswith("| explicit |")]
    assert (
        "| explicit | `(defaults)` | dmt | beard | Ae: 2 ± 0.1 (n=3) | Ne: 1 ± 0.1 (n=3) | 0.60 | **confirmed** |"
        in rows
    )
    assert not any("| smiling |" in r for r in rows)  # no edit works: listed under the table, not as a row
    assert "| explicit | `(defaults)` | smiling by dmt 0.20 | smiling 0.20 (truth 0.70) |" in rep.lines  # mean of 3
    assert "| explicit | `shipped` | smiling by dmt 0.20 | – |" in rep.lines  # measured before the rows existed
    assert any(r.startswith("| explicit | `shipped` | dmt | beard |") and "not testable (1 seed(s)" in r for r in rows)


def test_an_edit_the_model_cannot_draw_gets_no_verdict_however_the_reader_reads_it(tmp_path):
    """An edit that reads as the attribute on every face of a model whose reconstructions of faces that have it
    never read as it fools the reader: listed as not testable beside that share, not tabled; a model with one code
    (the baseline) is a reference row without a verdict."""
    out = tmp_path / "reports"
    d = out / "edit" / "baseline"
    d.mkdir(parents=True)
    claims = [
        {"attribute": a, "method": "dmt", "manifolds": "paper:z", "gain_per_leak": 1.5, "best_success": 1.0}
        for a in ("eyeglasses", "beard")
    ]
    drawn = [
        {"attribute": a, "method": m, "success": v}
        for a, rates in (("eyeglasses", (0.0, 0.7)), ("beard", (0.7, 0.75)))
        for m, v in zip(("truth reconstructed", "truth"), rates)
    ]
    drawn[0]["drawn_share"] = 0.3  # the generator's change its reconstructions reproduce, whatever the reader says
    res = {"model": "baseline", "setting": "shipped", "claims": claims, "relight": [], "traversal": drawn}
    (d / "edit.json").write_text(json.dumps(res))
    make_run(tmp_path / "runs", "a", eval_={"normal_mean": 12.0, "pseudo_normal_mean": 11.5})
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")
    assert (
        "| baseline | `shipped` | eyeglasses by dmt 1.00 | eyeglasses 0.00 (truth 0.70; 30% of the change drawn) |"
        in (rep.lines)
    )
    rows = [line for line in rep.lines if line.startswith("| baseline | `shipped` | dmt |")]
    assert rows == ["| baseline | `shipped` | dmt | beard | z: 1.5 (n=1) | – | 1.00 | – (one code: a reference) |"]


def test_light_claim_is_read_over_the_seeds_the_protocol_scored(tmp_path):
    """Claim 2 groups the protocol's network rows by model and setting; three seeds lower than L-hat on both
    numbers beyond their spread confirm it, one seed is not testable."""
    out = tmp_path / "reports"
    (out / "eval").mkdir(parents=True)
    est = {"ls_pseudo": {"relative": 0.8, "sh_error": 0.9}}
    runs = {}
    for seed, rel in enumerate((0.18, 0.20, 0.16)):
        run = make_run(tmp_path / "runs", f"s{seed}", seed=seed, eval_={"normal_mean": 12.0})
        est[f"e{seed}"], runs[f"e{seed}"] = (
            {"relative": rel, "sh_error": 0.6},
            {"model": "explicit", "setting": "(defaults)", "run": str(run)},
        )
    long = make_run(tmp_path / "runs", "long", eval_={"normal_mean": 10.0}, extra=("+experiment=long",))
    est["long"], runs["long"] = {"relative": 0.5, "sh_error": 0.7}, {"model": "explicit", "run": str(long)}
    runs["long"]["setting"] = "(defaults)"  # as written on its day; read again from its folder: +experiment=long
    (out / "eval" / "sh_variance.json").write_text(json.dumps({"estimators": est, "runs": runs}))
    make_run(tmp_path / "runs", "a", eval_={"normal_mean": 12.0, "pseudo_normal_mean": 11.5})
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")
    rows = [line for line in rep.lines if line.startswith("| explicit |") and "0.800" in line]
    assert (
        rows[0]
        == "| explicit | `(defaults)` | 0.180 ± 0.020 (n=3) | 0.800 | 0.600 ± 0.000 (n=3) | 0.900 | **confirmed** |"
    )
    assert rows[1].endswith("| not testable (1 seed(s); 3 needed) |")
    assert not any("shown variance" in line for line in rep.lines)  # a protocol run before the split: no table

    # the protocol's split by what the faces show: a second table against L-hat and the mean light
    est["ls_pseudo"] |= {"variance_shown": 0.05, "sh_error_shown": 0.2}
    est["mean_light"] = {"relative": 0.0, "sh_error": 0.4, "variance_shown": 0.001, "sh_error_shown": 0.25}
    for seed, var in enumerate((0.02, 0.03, 0.04)):
        est[f"e{seed}"] |= {"variance_shown": var, "sh_error_shown": 0.1}
    (out / "eval" / "sh_variance.json").write_text(json.dumps({"estimators": est, "runs": runs}))
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")
    shown = [line for line in rep.lines if line.startswith("| explicit |") and "0.050" in line]
    assert shown == [
        "| explicit | `(defaults)` | 0.030 ± 0.010 (n=3) | 0.050 | 0.001 | 0.100 ± 0.000 (n=3) | 0.200 | 0.250 | "
        "**confirmed** |"
    ]  # the long run was measured before the split: not in this table


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


def test_captions_name_the_machines_the_runs_trained_on(tmp_path):
    a, b = make_run(tmp_path, "a", eval_={}), make_run(tmp_path, "b", eval_={})
    info = {"processor": "x86_64", "cpus": 2, "torch": "2.13.0+cpu", "device": "cpu", "threads": 1}
    (a / "machine.json").write_text(json.dumps(info))
    runs = find_runs([tmp_path])
    assert tables.machines(runs) == (
        "x86_64, 2 CPUs, torch 2.13.0+cpu, device cpu, 1 thread(s) (1 run(s) from before machines were recorded)"
    )
    assert tables.machines([r for r in runs if r.path == b]) == "not recorded"


def test_setting_is_what_one_types_today_to_train_the_run_again(tmp_path):
    """A run's setting: its config-group choices and each defining value that differs from today's conf/, so that
    a run trained before a default changed is told apart from one trained after, however it was typed."""
    from disent.config import ADDED_LATER
    from disent.runs import setting

    today = composed_config(("model=explicit",))
    lr = today["train"]["lr"]
    make_run(tmp_path, "a", extra=[f"train.lr={lr}"])  # an override that repeats today's default is none
    b = make_run(tmp_path, "b")  # trained under other defaults: another lr, before loss.recon_fg_p existed
    cfg = yaml.safe_load((b / ".hydra" / "config.yaml").read_text())
    cfg["train"].update(lr=10 * lr, threads=7)  # threads do not define a run
    del cfg["loss"]["recon_fg_p"]
    (b / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    make_run(tmp_path, "c", "implicit", ["no_bws"], extra=["+experiment=smoke"])
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["a"]) == "model=explicit" and setting(runs["a"], drop_model=True) == "(defaults)"
    before = ADDED_LATER["loss.recon_fg_p"]
    expected = ([f"loss.recon_fg_p={before}"] if before != today["loss"]["recon_fg_p"] else []) + [
        "model=explicit",
        f"train.lr={10 * lr}",
    ]
    assert setting(runs["b"]) == " ".join(expected)
    assert setting(runs["c"]) == "+ablation=[no_bws] +experiment=smoke model=implicit"
    assert setting(runs["c"], drop_model=True, drop=("ablation=",)) == "+experiment=smoke"
    # a tool's record of a run (edit.json, sh_variance.json) is read with the setting of today's conf/
    stale = {"run": str(b), "setting": "(defaults)"}
    assert measured_setting(stale) == setting(runs["b"], drop_model=True) != "(defaults)"
    assert measured_setting({"run": str(tmp_path / "gone"), "setting": "(defaults)"}) is None  # stale
    assert measured_setting({"run": "explicit", "setting": "shipped"}) == "shipped"


def test_bws_c_is_not_part_of_a_run_that_neither_uses_bws_nor_whitens_lhat(tmp_path):
    """c acts through BWS and the whitened L-hat target: a run with both off (``+ablation=no_bws``) trains the same
    under any c, and a run with either on does not (:func:`disent.train.idle_settings`)."""
    from disent.config import idle_settings
    from disent.runs import setting

    for name, bws, white in (("no_bws", 0.0, False), ("bws_off_white", 0.0, True), ("raw", 1.0, False)):
        d = make_run(tmp_path, name, "explicit")
        cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
        cfg["loss"]["weights"]["BWS"], cfg["loss"]["lhat_white"] = bws, white
        cfg["loss"]["bws_c"] = 0.3
        (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert "loss.bws_c" in idle_settings(runs["no_bws"].cfg)
    assert "loss.bws_c=" not in setting(runs["no_bws"])
    for name in ("bws_off_white", "raw"):
        assert "loss.bws_c" not in idle_settings(runs[name].cfg) and "loss.bws_c=0.3" in setting(runs[name])


def test_a_loss_weight_the_model_has_no_term_for_is_not_part_of_its_setting(tmp_path):
    """The baseline has no normals: a run of it trained under another E_recon-N weight (or the masked
    reconstruction's norm) is the same setting as today's; the explicit model's is not."""
    from disent.runs import setting

    for model in ("baseline", "explicit"):
        d = make_run(tmp_path, model, model)
        cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
        cfg["loss"]["weights"]["recon_N"] += 1.0
        cfg["loss"]["recon_fg_p"] = 3 - cfg["loss"]["recon_fg_p"]  # 1 <-> 2
        (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["baseline"]) == "model=baseline"
    assert "loss.weights.recon_N=" in setting(runs["explicit"]) and "loss.recon_fg_p=" in setting(runs["explicit"])
    # compared across models, the baseline joins the explicit runs it trains the same as, and leaves its own group
    groups = group_by_setting(list(runs.values()))
    assert list(groups) == [setting(runs["explicit"], drop_model=True)]
    assert sorted(r.model for r in groups[setting(runs["explicit"], drop_model=True)]) == ["baseline", "explicit"]
    alone = group_by_setting([runs["baseline"]])
    assert list(alone) == ["(defaults)"]


def test_an_early_weight_is_part_of_a_setting_only_where_it_reaches_training(tmp_path):
    """``loss.early_weights`` is an empty map in conf/, so a run's early weight reads ``+key=value`` (what one types
    to train it again); the explicit model has no E_UV, so its early UV weight is no part of its setting, and neither
    is an early weight given no early steps or one equal to the term's own weight."""
    from disent.runs import composed_config, setting

    weight = composed_config(("model=implicit",))["loss"]["weights"]["UV"]
    early = (f"+loss.early_weights.UV={weight + 40:g}", "loss.early_steps=300")
    make_run(tmp_path, "implicit", "implicit", extra=early)
    make_run(tmp_path, "explicit", "explicit", extra=early)
    make_run(tmp_path, "no_steps", "implicit", extra=early[:1])
    make_run(tmp_path, "same", "implicit", extra=(f"+loss.early_weights.UV={weight:g}", "loss.early_steps=300"))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["implicit"]) == f"{early[0]} loss.early_steps=300 model=implicit"
    assert setting(runs["explicit"]) == "model=explicit"
    assert setting(runs["no_steps"]) == setting(runs["same"]) == "model=implicit"


def test_a_weight_typed_as_an_int_is_the_setting_of_the_same_float_in_a_config(tmp_path):
    """``loss.weights.UV=1`` on the command line (an int) and ``UV: 1.0`` in a config (a float) train the same run:
    one setting, not two."""
    from disent.runs import setting

    weight = composed_config(("model=implicit",))["loss"]["weights"]["UV"]
    make_run(tmp_path, "typed", "implicit", extra=(f"loss.weights.UV={int(weight) + 1}",))
    d = make_run(tmp_path, "yaml", "implicit")
    cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
    cfg["loss"]["weights"]["UV"] = float(int(weight) + 1)
    (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert runs["typed"].cfg["loss"]["weights"]["UV"] == int(weight) + 1
    assert setting(runs["typed"]) == setting(runs["yaml"]) == f"loss.weights.UV={float(int(weight) + 1)} model=implicit"


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


def test_a_curve_ending_above_the_panel_is_marked_at_its_edge_with_its_value():
    """A broken run whose final error lies above a learning-curve panel's y limit gets an arrow at the top edge
    labelled with its value; a run inside the panel gets none; ends at nearly one x share a label."""
    from disent.report.training import mark_off_chart

    plt = document.pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 10], [20, 64.07])
    ax.set_ylim(0, 51.2)
    ax.set_xlim(0, 10)
    assert mark_off_chart(ax, [(10, 64.07, "C0"), (10, 12.0, "C1"), (2, 80.89, "C2"), (9.8, 82.2, "C3")]) == [
        80.89,
        82.2,
        64.07,
    ]
    labels = {t.get_text(): t.get_color() for t in ax.texts}
    assert sorted(labels) == ["64.1, 82.2", "80.9"]
    assert labels["80.9"] == "C2" and labels["64.1, 82.2"] == "0.2"  # a shared label of two lines: neutral
    assert all(t.xy[1] == 51.2 for t in ax.texts)  # the arrow points at the edge, not at the clipped value
    assert {t.get_text(): t.get_ha() for t in ax.texts} == {"64.1, 82.2": "right", "80.9": "center"}  # runs inwards
    plt.close(fig)


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


def test_target_reading_says_whether_the_target_lies_outside_the_interval():
    """A row's test accuracy against the order target: reached or not, and beyond the sampling spread only where
    the target lies outside the accuracy's 95 % interval (0.80 over 300 scenes: 0.75-0.84; over 60: 0.68-0.88)."""
    from disent.report.lighting import ORDER_TARGET, target_reading, wilson_interval

    assert wilson_interval(0.80, 300)[1] < ORDER_TARGET < wilson_interval(0.80, 60)[1]
    assert target_reading(0.80, 300) == "**not reached**, the target above its interval"
    assert target_reading(0.80, 60).startswith("**not reached**, but the target lies inside its interval")
    assert target_reading(0.95, 300) == "**reached**, the target below its interval"
    assert target_reading(0.88, 60).startswith("**reached**, but the target lies inside")


def test_wilson_interval_matches_the_closed_form():
    """Wilson's 95 % score interval: 50 of 100 gives 0.404-0.596 (the textbook value); it stays inside [0, 1] at
    0 and n successes, where the normal approximation would not."""
    from disent.report.lighting import wilson_interval

    lo, hi = wilson_interval(0.5, 100)
    assert lo == pytest.approx(0.4038, abs=1e-4) and hi == pytest.approx(0.5962, abs=1e-4)
    assert wilson_interval(0.0, 20)[0] == pytest.approx(0.0, abs=1e-12) and 0 < wilson_interval(0.0, 20)[1] < 0.2
    assert wilson_interval(1.0, 20)[1] == pytest.approx(1.0, abs=1e-12)


def test_paired_order_outcomes_count_the_discordant_scenes_and_mcnemar_is_exact():
    """Two rows compared on the scenes both read (face and true order): the scenes each alone gets right, and the
    exact McNemar p-value (0 against 5 discordant scenes: 2 / 2^5; an even split: 1); a row without its scenes'
    outcomes is not compared."""
    from disent.report.lighting import mcnemar_p, paired_outcomes, paired_reading

    def row(index, true, chosen):
        return {"scenes": {"index": index, "true_order": true, "evidence": chosen}}

    order = {  # scene (3, 2) is read by a alone; of the four shared, a alone is right on 2, b alone on 1, both on 1
        "val/a": row([0, 1, 2, 0, 3], [0, 0, 1, 2, 2], [0, 0, 1, 1, 2]),
        "val/b": row([0, 1, 2, 0], [0, 0, 1, 2], [1, 2, 1, 2]),
        "val/c": {"evidence": {"accuracy": 0.5}},
    }
    assert paired_outcomes(order, "val/a", "val/b") == (4, 2, 1)
    assert paired_outcomes(order, "val/b", "val/a") == (4, 1, 2)
    assert paired_outcomes(order, "val/a", "val/c") is None and paired_reading(order, "val", "a", "c", "c") == ""
    assert mcnemar_p(0, 5) == pytest.approx(2 / 2**5) and mcnemar_p(5, 0) == pytest.approx(2 / 2**5)
    assert mcnemar_p(4, 4) == pytest.approx(1.0) and mcnemar_p(0, 0) == 1.0
    assert "2 right only under it and 1 only under b" in paired_reading(order, "val", "a", "b", "b")


def test_failure_region_lines_flag_the_parts_taking_twice_their_share():
    """The table of where the order choice's misfit lies: one row per split and kind of error, each part's share of
    the reduction beside its share of the pixels, and the parts at twice their share named (none where none is)."""
    from disent.report.lighting import failure_region_lines

    def kind(reduction, pixels):
        parts = ("silhouette", "eyes and brows", "rest")
        return {"scenes": 3, "reduction_share": dict(zip(parts, reduction)), "pixel_share": dict(zip(parts, pixels))}

    regions = {
        "val": {"row": "texture/x", "split": "val", "kinds": {"1->2": kind((0.2, 0.5, 0.3), (0.2, 0.1, 0.7))}},
        "test": {"row": "texture/x", "split": "test", "kinds": {"0->1": kind((0.3, 0.1, 0.6), (0.3, 0.1, 0.6))}},
    }
    text = "\n".join(failure_region_lines(regions))
    assert "| val | 1 -> 2 | 3 | 0.20 (0.20) | 0.50 (0.10) | 0.30 (0.70) |" in text
    assert "| test | 0 -> 1 | 3 |" in text
    assert "twice their share of the pixels: val 1 -> 2: eyes and brows." in text
    assert failure_region_lines({}) == [] and failure_region_lines({"val": {}}) == []
    regions["val"]["kinds"]["1->2"] = kind((0.2, 0.1, 0.7), (0.2, 0.1, 0.7))
    assert "twice their share of the pixels: none." in "\n".join(failure_region_lines(regions))


def test_background_diagnostic_sets_edits_through_the_background_against_the_face_codes():
    """``edit measure --background`` results: per attribute and method, the best success of the sets holding the
    background code beside the best of the face codes alone; none measured, no lines."""
    from disent.report.claims import background_lines

    claims = [
        {"attribute": "senior", "method": "dmt", "manifolds": "paper:Ae+Ne", "best_success": 0.0},
        {"attribute": "senior", "method": "dmt", "manifolds": "Ae", "best_success": 0.06},
        {"attribute": "senior", "method": "dmt", "manifolds": "bg", "best_success": 1.0},
        {"attribute": "senior", "method": "dmt", "manifolds": "all+bg", "best_success": 0.94},
    ]
    lines = background_lines([("explicit", "shipped", {"claims": claims})])
    assert "- explicit (`shipped`): senior by dmt: 1.00 with it, 0.06 with the face codes alone." in lines
    assert background_lines([]) == []


def test_claim_two_reads_the_light_as_learned_only_where_the_face_shows_it(tmp_path):
    """The shown/hidden table: each setting's and model's shown SH error over its seeds against the mean light's;
    confirmed only with three seeds beyond the spread, each rung on its own row (and in the glance), and no table
    for runs scored before the split existed."""
    from disent.report.claims import shown_hidden_lines

    light = {"trivial_sh_error_shown": 0.25, "trivial_sh_error_hidden": 0.14, "trivial_sh_error": 0.37}
    light |= {"pseudo_sh_error_shown": 0.19, "pseudo_sh_error_hidden": 19.0}
    for seed, shown in enumerate((0.11, 0.12, 0.115)):  # over all 9 coefficients worse than the mean light
        ev = {"sh_error_shown": shown, "sh_error_hidden": 1.1, "sh_error": 0.5 + 0.01 * seed} | light
        make_run(tmp_path, f"e{seed}", "explicit", seed=seed, eval_=ev)
        ev = {"sh_error_shown": 0.3, "sh_error_hidden": 0.5, "sh_error": 0.2} | light  # the long rung: the reverse
        make_run(tmp_path, f"l{seed}", "explicit", seed=seed, eval_=ev, extra=("+experiment=long",))
    make_run(tmp_path, "i0", "implicit", eval_={"sh_error_shown": 0.3} | light)
    make_run(tmp_path, "old", "explicit", seed=3, eval_={"sh_error": 0.5})
    glance = tables.Glance()
    lines = shown_hidden_lines(find_runs([tmp_path]), glance)
    assert "the mean light 0.250 shown / 0.140 hidden" in lines[0] and "L-hat 0.190 shown / 19.000 hidden" in lines[0]
    rows = {tuple(c.strip() for c in line.split("|")[1:3]): line for line in lines if line.startswith("| `")}
    assert (
        "| 0.115 ± 0.005 (n=3) | 1.100 ± 0.000 (n=3) | – | 0.510 ± 0.010 (n=3) | **confirmed** | **refuted** |"
        in rows["`(defaults)`", "explicit"]
    )
    assert rows["`+experiment=long`", "explicit"].endswith("| **refuted** | **confirmed** |")
    assert rows["`(defaults)`", "implicit"].endswith("| not testable (1 seed(s); 3 needed) | not testable (no runs) |")
    shown, whole = (v for (claim, _), v in glance.cells.items() if claim == "2")
    assert shown == {
        ("(defaults)", "explicit"): "**confirmed**",
        ("+experiment=long", "explicit"): "**refuted**",
        ("(defaults)", "implicit"): "not testable (1 seed(s); 3 needed)",
    }
    assert (
        whole[("(defaults)", "explicit")] == "**refuted**"
        and whole[("+experiment=long", "explicit")] == "**confirmed**"
    )
    assert shown_hidden_lines(find_runs([tmp_path / "old"]), glance) == []
    filled = {"sh_error_completed": 0.27, "pseudo_sh_error_completed": 0.29}
    make_run(tmp_path, "c", "explicit", seed=4, eval_={"sh_error_shown": 0.1} | light | filled)
    lines = shown_hidden_lines(find_runs([tmp_path]), tables.Glance())
    assert (
        "0.370 filled and all 9 (itself)" in lines[0] and "L-hat 0.190 shown / 19.000 hidden / 0.290 filled" in lines[0]
    )
    assert any(line.startswith("| `(defaults)` | explicit |") and "| 0.270 (n=1) |" in line for line in lines)


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


def test_wrapped_titles_break_only_between_name_parts_and_keep_every_character():
    """A figure title's lines stay within the width wherever a break is allowed, never split a name between its
    ``_``/``-``/``.``/space-separated parts, and lose nothing but the spaces at the breaks."""
    from disent.report.pictures import wrapped

    text = "+experiment=long loss.bws_c=0.3 (explicit_long_gpu_s12-explicit_s0)"
    lines = wrapped(text, 22).split("\n")
    assert len(lines) > 1 and all(len(line) <= 22 for line in lines), lines
    assert "".join(lines).replace(" ", "") == text.replace(" ", "")
    at = 0
    for line in lines[:-1]:  # each break follows a separator of the original text
        at = text.index(line, at) + len(line)
        at += text[at] == " "
        assert text[at - 1] in " _-.", (line, text[at - 1])
    assert wrapped("supercalifragilistic", 5) == "supercalifragilistic"  # no break inside a part
    assert wrapped("a b", 22) == "a b"


def test_relight_rows_read_each_region_the_results_scored():
    """The relighting tables: per setting, transfer less input and less ratio (mean ± std over models) for each
    score key; results measured before a key existed are left out of that table, and with no result there is no
    row."""
    scores = ("psnr", "psnr_face", "psnr_skin")

    def result(transfer, ratio, skin=True):
        rows = [{"method": m, **{k: v + (k == "psnr") for k in scores}} for m, v in (("transfer", transfer),)]
        rows += [{"method": m, **{k: v for k in scores}} for m, v in (("ratio", ratio), ("input", 18.0))]
        return {"relight": [{k: v for k, v in r.items() if skin or k != "psnr_skin"} for r in rows]}

    results = [result(21.0, 21.5), result(22.0, 21.5), result(30.0, 20.0, skin=False)]
    (head,) = claims.relight_rows("explicit", "(defaults)", results, ("psnr_face",), all_methods=True)
    assert head.startswith("| explicit | `(defaults)` | 24.33 ± 4.93 (n=3) | 21.00 ± 0.87 (n=3) | – | 18.00 ± 0.00")
    (regions,) = claims.relight_rows("explicit", "(defaults)", results[:2] + results[2:], ("psnr_skin", "psnr"))
    # the third result has no psnr_skin: two models; the whole image adds 1 dB to transfer's score
    assert regions == (
        "| explicit | `(defaults)` | 3.50 ± 0.71 (n=2) | 0.00 ± 0.71 (n=2) | 4.50 ± 0.71 (n=2) | 1.00 ± 0.71 (n=2) |"
    )
    assert claims.relight_rows("explicit", "x", [{"relight": []}], ("psnr",)) == []
    # against the ratio only, after transfer's own value of a method-independent key (a share, in percent)
    share = [{**r, "share": 0.5 + 0.1 * k} for k, res in enumerate(results[:2]) for r in res["relight"]]
    (split,) = claims.relight_rows(
        "explicit",
        "(defaults)",
        [{"relight": share[:3]}, {"relight": share[3:]}],
        ("psnr_face",),
        against=("ratio",),
        values=("share",),
    )
    assert split == "| explicit | `(defaults)` | 55% ± 7% (n=2) | 0.00 ± 0.71 (n=2) |"


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
    lines = claims.matte_lines(find_runs([tmp_path / "runs"]))
    rows = [line for line in lines if line.startswith("| `")]
    assert rows == [
        "| `(defaults)` | explicit | 0.920 ± 0.010 (n=3) | 0.860 | 0.700 | M-hat, the mean region | – / – | – / – |",
        "| `(defaults)` | implicit | 0.800 (n=1) | 0.860 | 0.700 | the mean region | 0.98 / 0.06 | 0.75 / 0.76 |",
        "| `shipped` | implicit | 0.500 (n=1) | 0.860 | 0.700 | neither | – / – | – / – |",
    ]
    monkeypatch.setattr(shipped, "manifest", lambda: {})
    assert claims.matte_lines([]) == []


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
    lines = claims.albedo_cause_lines(find_runs([tmp_path / "runs"]))
    rows = [line for line in lines if line.startswith("| `")]
    assert rows == [
        "| `(defaults)` | explicit | 0.0080 ± 0.0000 (0.64; n=3) | 0.0090 ± 0.0000 (0.72; n=3) | "
        "0.0060 ± 0.0010 (0.48; n=3) | 0.0075 ± 0.0000 (0.60; n=3) | 0.0125 | its N, the true L |"
    ]
    assert claims.albedo_cause_lines([]) == []


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
    lines = claims.light_target_lines(find_runs([tmp_path / "runs"]))
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
    assert claims.light_target_lines([]) == []


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
    rows = [line for line in claims.light_target_lines(find_runs([tmp_path / "runs"])) if line.startswith("- ")]
    ref = f"loss.recon_L_network=run:{Run.load(net).id}"  # the network named by its run id, never by its folder
    assert len(rows) == 1 and ref in rows[0] and str(tmp_path) not in rows[0] and "against `(defaults)`" in rows[0]
    assert rows[0].endswith(
        " Its network: the explicit model trained at "
        "`loss.recon_L_network=implicit loss.recon_L_target=sh_network_texture`, seed 3."
    )
    assert claims.network_run_words("loss.recon_L_network=implicit", []) == ""  # a shipped name: nothing to add
    # the network's folder deleted (a new machine): its record, kept with the report's runs, still says what it was
    write_records(find_runs([net.parent]), tmp_path / "runs.jsonl")
    shutil.rmtree(net)
    runs = find_runs([tmp_path / "runs"], tmp_path / "runs.jsonl")
    assert claims.network_run(ref, runs).seed == 3
    assert rows[0] in claims.light_target_lines(runs)
    assert claims.drawn_target_words(" ".join(second), runs) == "explicit run's light + refit (0.35)"
    assert claims.network_run(ref, []) is None  # neither the folder nor its record


def test_target_source_names_the_lighting_row_of_a_settings_e_recon_l_target():
    assert claims.target_source("(defaults)") == claims.target_source("+experiment=long") == "lhat"
    assert claims.target_source("loss.recon_L_target=sh_pseudo_eroded") == "lhat_eroded"
    assert claims.target_source("loss.recon_L_scale=sh_pseudo loss.recon_L_target=sh_texture") == (
        "texture_model_lhat_scale"
    )
    assert claims.target_source("loss.recon_L_oracle_mix=0.25") == "oracle_mix_0.25"
    assert claims.target_source("loss.recon_L_target=sh_network") == "network_explicit"
    assert claims.target_source("loss.recon_L_network=implicit loss.recon_L_target=sh_network") == "network_implicit"
    both = "loss.recon_L_network=implicit loss.recon_L_target=sh_network_texture"
    assert claims.target_source(both) == "network_implicit_texture"
    assert claims.target_source(f"{both} loss.recon_L_network_share=0.6") == "network_implicit_texture"
    assert claims.target_source(f"{both} loss.recon_L_network_share=0.4") is None  # the rows are at 0.6
    where = f"{both} loss.recon_L_network_share=0.4 loss.lhat_gray=true"  # the network and its share come along
    assert ablations.setting_picks(where, "loss.recon_L_target=sh_network_texture") == [
        "loss.recon_L_target=sh_network_texture",
        "loss.recon_L_network=implicit",
        "loss.recon_L_network_share=0.4",
    ]
    truth = "true_pixels_normals_albedo"  # the truth's shape, at whichever scale
    assert claims.target_source("+experiment=long loss.recon_L_target=sh") == truth
    assert claims.target_source("loss.recon_L_oracle_mix=1.0 loss.recon_L_target=sh_texture") == truth
    assert claims.target_source("loss.recon_L_oracle_mix=0.5 loss.recon_L_target=sh_texture") is None  # no such row
    assert claims.target_source("loss.lhat_gray=true") is None  # changes more than the target
    assert claims.target_source("+ablation=no_bws") is None


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
    claims.light_pattern_section(rep, runs)
    assert rep.lines == []  # no lighting table yet
    rows = {
        "lhat": {"pattern_corr": 0.893, "contrast_ratio": 1.03},  # scored before the log error
        "true_pixels_normals_albedo": {"pattern_corr": 1.0, "contrast_ratio": 1.0, "log_error": 0.0},
    }
    (tmp_path / "lighting").mkdir()
    (tmp_path / "lighting" / "lhat_sources.json").write_text(json.dumps({"rows": rows}))
    claims.light_pattern_section(rep, runs)
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
    assert claims.normals_caps(long) == {"long": 0.45}
    assert "long rung 0.45 (within the target)." in claims.normals_cap_reading(long, claims.normals_caps(long))
    unscored = [{**long[0], "cap": None}]
    assert claims.normals_cap_reading(unscored, claims.normals_caps(unscored)) == ""
    # the shipped explicit weights (one long-rung seed on L-hat): a row of the table, not a point of the figure or ranks
    metrics = {"albedo_si_mse": 0.008, "trivial_albedo_si_mse": 0.0127, "light_pattern_corr": 0.95}
    metrics |= {"light_contrast_ratio": 0.857, "light_log_error": 0.146, "shading_log_error": 0.236}
    cfg = {"train": {"max_steps": 10000}, "loss": {}}  # a config older than the target's option: L-hat
    entries = {"explicit": {"metrics": metrics, "cfg": cfg}, "baseline": {"metrics": {}, "cfg": cfg}}
    monkeypatch.setattr(shipped, "manifest", lambda: entries)
    ranked = []
    monkeypatch.setattr(claims, "albedo_rank_reading", lambda points: ranked.extend(points) or "")
    rep = report.Report(tmp_path)
    claims.light_pattern_section(rep, runs)
    shipped_row = (
        "| `shipped` | explicit | long | 0.893 | 1.03 | – | 0.950 (n=1) | 0.86 (n=1) | 0.146 (n=1) | 0.236 (n=1) | "
    )
    assert shipped_row + "0.63 ± 0.00 (n=1) |" in rep.lines
    assert "one seed of `+experiment=long` as their manifest's config reads" in "\n".join(rep.lines)
    assert sorted(p["name"] for p in ranked) == ["L-hat", "truth's shape"]
    # weights trained at the default rung on the true light: their row reads that target's, at that rung
    cfg |= {"train": {"max_steps": 1200}, "loss": {"recon_L_target": "sh"}}
    rep = report.Report(tmp_path)
    claims.light_pattern_section(rep, runs)
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
    monkeypatch.setattr(claims, "albedo_rank_reading", lambda p: points.extend(p) or "")
    claims.light_pattern_section(rep, find_runs([tmp_path / "runs"]))
    rows = [line for line in rep.lines if line.startswith("| `loss.")]
    named = sorted(t if "network=" not in t else f"loss.recon_L_network=run:{Run.load(net).id}" for t in second)
    assert len(rows) == 1 and rows[0].startswith(f"| `{' '.join(named)}` | explicit | default | 0.975 | 0.95 | 0.070 |")
    assert [p["name"] for p in points] == ["explicit run's light + refit (0.35)"]
    assert claims.drawn_target_words("loss.recon_L_target=sh_network loss.recon_L_network=implicit", []) == (
        "implicit's light"
    )


def test_albedo_rank_reading_ranks_the_albedo_against_each_measure_per_rung():
    """+1 where the better value always goes with the better albedo: a higher target pattern, a lower log error."""

    def point(rung, share, pattern=None, light=None, shading=None):
        return {"rung": rung, "share": {"mean": share}, "target_pattern": pattern, "light_log_error": light,
                "shading_log_error": shading}  # fmt: skip

    points = [point("default", m, x) for x, m in zip((0.89, 0.94, 0.98, 1.0), (0.74, 0.72, 0.70, 0.66))]
    points += [point("long", 0.62, 0.89, 0.13), point("long", 0.45, 1.0, 0.05)]
    text = claims.albedo_rank_reading(points)
    assert "default rung, the target's pattern (corr. of log shading with the truth): +1.00 over 4 settings" in text
    assert "long rung" not in text and "network" not in text  # 2 long settings; no network error at default
    points[1]["share"]["mean"] = 0.75  # one setting out of order
    assert "target's pattern (corr. of log shading with the truth): +0.80 over 4" in claims.albedo_rank_reading(points)
    points = [point("default", m, 0.9, e, e + 0.1) for e, m in ((0.14, 0.79), (0.13, 0.74), (0.1, 0.72), (0.07, 0.66))]
    text = claims.albedo_rank_reading(points)  # one target pattern for all: not ranked
    assert "default rung, the network's own light: log error: +1.00 over 4" in text and "target's" not in text
    assert "the network's own shading (its normals too): log error: +1.00 over 4" in text
    assert claims.albedo_rank_reading(points[4:]) == ""


def test_edit_claims_without_the_reader_read_the_drawn_share(tmp_path):
    """Claim 5's reader-free tables, over the image and inside the face region: the paper's manifolds against the
    best other set by drawn share per leakage over three seeds, read where the best set draws at least half of what
    the model's reconstructions of the true faces draw; an edit under that is listed as not testable, and results
    measured before the drawn share add no row. An edit whose change lies mostly outside the face (a senior face's
    grey hair) is testable in the face region alone. With no reader at all (per off-target change) the same rule
    reads the seeds that measured it."""
    out = tmp_path / "reports"
    readings = (  # attribute, (best drawn, ceiling) over the image and in the face, paper's and rival's per leakage
        ("beard", (0.8, 0.9), (0.8, 0.9), 3.9, 3.3),
        ("smiling", (0.15, 0.4), (0.15, 0.4), 1.0, 0.7),
        ("senior", (0.15, 0.95), (0.6, 0.88), 1.0, 1.4),
    )
    for i in range(3):
        d = out / "edit" / f"explicit_seed{i}_1200steps"
        d.mkdir(parents=True)
        run = make_run(tmp_path / "runs", f"s{i}", seed=i, eval_={"normal_mean": 12.0})
        claims = [
            {"attribute": a, "method": "dmt", "manifolds": m, "gain_per_leak": 1.0, "best_success": 0.2}
            | {"drawn_per_leak": v + 0.1 * i, "best_drawn": image[0]}
            | {"drawn_face_per_leak": 2 * v + 0.1 * i, "best_drawn_face": face[0]}
            | ({"drawn_per_off_target": 1 / v + 0.1 * i} if i else {})  # seed 0 measured before the off-target change
            for a, image, face, paper, rival in readings
            for m, v in (("paper:Ae", paper), ("Ne", rival))
        ]
        ceiling = [
            {"attribute": a, "method": "truth reconstructed", "success": 0.1}
            | {"drawn_share": image[1], "drawn_share_face": face[1]}
            for a, image, face, _, _ in readings
        ] + [{"attribute": "senior", "method": "truth", "success": 1.0, "change_in_face": 0.14 + 0.01 * i}]
        res = {"model": "explicit", "setting": "(defaults)", "claims": claims, "relight": [], "traversal": ceiling}
        (d / "edit.json").write_text(json.dumps(res | {"run": str(run)}))
    (out / "edit" / "explicit").mkdir()  # a shipped model measured before the drawn share: no row of its own
    old = {"model": "explicit", "setting": "shipped", "claims": [dict(claims[0], gain_per_leak=2.0)], "relight": []}
    for c in old["claims"]:
        for key in ("drawn_per_leak", "best_drawn", "drawn_face_per_leak", "best_drawn_face", "drawn_per_off_target"):
            c.pop(key)
    (out / "edit" / "explicit" / "edit.json").write_text(json.dumps(old))
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")

    def table(column):
        free = rep.lines[rep.lines.index(next(line for line in rep.lines if column in line)) + 2 :]
        return free[: free.index("")]

    gated = "not testable (draws under 50% of what the model draws) |"
    assert table("paper's manifolds: drawn share per leakage") == [
        "| explicit | `(defaults)` | dmt | beard | Ae: 4 ± 0.1 (n=3) | Ne: 3.4 ± 0.1 (n=3) | 80% of 90% | "
        "**confirmed** |",
        f"| explicit | `(defaults)` | dmt | smiling | Ae: 1.1 ± 0.1 (n=3) | Ne: 0.8 ± 0.1 (n=3) | 15% of 40% | {gated}",
        f"| explicit | `(defaults)` | dmt | senior | Ae: 1.1 ± 0.1 (n=3) | Ne: 1.5 ± 0.1 (n=3) | 15% of 95% | {gated}",
    ]
    assert table("paper's manifolds: drawn share in the face per leakage") == [
        "| explicit | `(defaults)` | dmt | beard | Ae: 7.9 ± 0.1 (n=3) | Ne: 6.7 ± 0.1 (n=3) | 80% of 90% | "
        "**confirmed** |",
        f"| explicit | `(defaults)` | dmt | smiling | Ae: 2.1 ± 0.1 (n=3) | Ne: 1.5 ± 0.1 (n=3) | 15% of 40% | {gated}",
        "| explicit | `(defaults)` | dmt | senior | Ae: 2.1 ± 0.1 (n=3) | Ne: 2.9 ± 0.1 (n=3) | 60% of 88% | "
        "**refuted** |",
    ]
    assert (
        "The share of the generator's change inside the face region (`change_in_face`, the source faces): senior 15%."
        in "\n".join(rep.lines)
    )
    # per off-target change the paper's set loses the beard (1 / 3.9 against 1 / 3.3), over the two seeds that have it
    assert table("paper's manifolds: drawn share per off-target change") == [
        "| explicit | `(defaults)` | dmt | beard | Ae: 0.406 ± 0.0707 (n=2) | Ne: 0.453 ± 0.0707 (n=2) | 80% of 90% | "
        "not testable (2 seed(s); 3 needed) |",
        f"| explicit | `(defaults)` | dmt | smiling | Ae: 1.15 ± 0.0707 (n=2) | Ne: 1.58 ± 0.0707 (n=2) | 15% of 40% | "
        f"{gated}",
        f"| explicit | `(defaults)` | dmt | senior | Ae: 1.15 ± 0.0707 (n=2) | Ne: 0.864 ± 0.0707 (n=2) | 15% of 95% | "
        f"{gated}",
    ]
    assert not any("manifolds: drawn share in the face per off-target change" in line for line in rep.lines)
    # at a glance: each reading's verdict alone, for the edits some reading can judge (the smile none can)
    assert table("| gain per leakage (reader) | drawn share per leakage |") == [
        "| explicit | `(defaults)` | dmt | beard | not testable | **confirmed** | not testable | **confirmed** | – |",
        "| explicit | `(defaults)` | dmt | senior | not testable | not testable | not testable | **refuted** | – |",
    ]


def test_claim_5_shows_the_shipped_models_progression_figures(tmp_path):
    """Each shipped model's lambda progression figures are shown under claim 5; a seed's folder or the background
    diagnostic adds none, and without any there is no caption."""
    edit = tmp_path / "reports" / "edit"
    for name, setting, background in (("explicit", "shipped", False), ("explicit_background", "shipped", True)):
        (edit / name).mkdir(parents=True)
        res = {"model": "explicit", "setting": setting, "background": background, "claims": []}
        (edit / name / "edit.json").write_text(json.dumps(res))
        for attribute in ("smiling", "beard"):
            (edit / name / f"fig_{attribute}_progression.png").write_bytes(b"png")
    (edit / "explicit_seed0_1200steps").mkdir()
    (edit / "explicit_seed0_1200steps" / "edit.json").write_text(json.dumps({"model": "explicit", "setting": "x"}))
    (edit / "explicit_seed0_1200steps" / "fig_beard_progression.png").write_bytes(b"png")
    rep = report.Report(tmp_path / "reports")
    claims.progression_figures(rep, edit)
    images = [line for line in rep.lines if line.startswith("![")]
    assert images == [
        "![explicit: beard progression](edit/explicit/fig_beard_progression.png)\n",
        "![explicit: smiling progression](edit/explicit/fig_smiling_progression.png)\n",
    ]
    empty = report.Report(tmp_path / "other")
    claims.progression_figures(empty, tmp_path / "other" / "edit")
    assert empty.lines == []


def test_reconstruction_claim_reads_sharper_on_the_face_and_in_the_albedo_details(tmp_path):
    """Claim 3: each rendering model against the baseline on face PSNR, and the implicit against the explicit on
    two readings of "sharper" (Sec. 3.2): face SSIM, and the albedo's detail error (lower is better)."""
    out = tmp_path / "reports"
    (out / "eval").mkdir(parents=True)
    for seed in range(3):
        make_run(tmp_path / "runs", f"b{seed}", "baseline", seed=seed, eval_={"recon_face_psnr": 24.0 + 0.1 * seed})
        for model, psnr, ssim, fine in (("explicit", 26.0, 0.72, 0.0036), ("implicit", 26.1, 0.73, 0.0030)):
            ev = {"recon_face_psnr": psnr + 0.01 * seed, "recon_face_ssim": ssim + 0.02 * seed}
            ev |= {"albedo_fine_si_mse": fine + 0.0001 * seed, "normal_mean": 12.0}
            make_run(tmp_path / "runs", f"{model[0]}{seed}", model, seed=seed, eval_=ev)
    rep = report.Report(out)
    report.sec_claims(rep, find_runs([tmp_path / "runs"]), out / "eval")
    row = next(line for line in rep.lines if line.startswith("| `(defaults)` | 24.10 ± 0.10 (n=3) |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[4:6] == ["**confirmed**", "**confirmed**"]  # both > the baseline beyond the spread
    assert cells[6].startswith("not resolved")  # SSIM 0.01 apart, spread 0.02
    assert cells[7] == "**confirmed** (0.00370 ± 0.00010 (n=3) / 0.00310 ± 0.00010 (n=3))"
    assert any("leading to sharper, more accurate reconstructions" in line for line in rep.lines)


def test_failure_lines_read_the_order_choice_by_yaw_and_pixels_and_flag_the_bin_that_fails():
    """A row whose choice fails on every face turned more than 30 deg and on no other: the table gives each bin's
    accuracy and count; the far bin reads as beyond the spread of the other scenes, the pixels' thirds (unrelated to
    the failure) do not; a row without scene records gives no lines."""
    import numpy as np

    rng = np.random.default_rng(0)
    yaw = rng.uniform(-45, 45, 300)
    truth = np.tile([0, 1, 2], 100)
    chosen = np.where(np.abs(yaw) >= 30, (truth + 1) % 3, truth)
    pixels = np.arange(300) + 1000  # unrelated to the failure
    scenes = {"true_order": truth.tolist(), "evidence": chosen.tolist(), "yaw": yaw.tolist(), "pixels": pixels.tolist()}
    order = {"test/texture/x": {"scenes": scenes}, "val/texture/x": {}}
    lines = lighting.failure_lines(order, ["texture/x", "texture/x"])
    far = np.abs(yaw) >= 30
    row = [line for line in lines if line.startswith("| test |")]
    assert len(row) == 1 and f"| 0.00 ({far.sum()}) |" in row[0], row
    assert f"| {1 - far.mean():.2f} (300) |" in row[0]
    note = lines[-1]
    assert "yaw 30-45 deg (0.00 against 1.00;" in note and "yaw 0-15 deg" in note  # the near bin: all right
    assert all(line.count("|") == 10 for line in lines if line.startswith("|"))  # no stray pipe breaks the table
    assert "fewest pixels" not in note and "most pixels" not in note, note
    assert lighting.failure_lines({"test/texture/x": {}}, ["texture/x"]) == []


def test_failure_lines_flag_the_attribute_whose_faces_fail():
    """Faces index the scenes: with a row that fails on every scene of the bearded faces (every third face) and on
    no other, the "with beard" bin reads 0.00 and is flagged against the other scenes; the label of an attribute
    unrelated to the failure (every other face) is not; the labels are the faces', looked up by each scene's index."""
    import numpy as np

    faces = np.arange(100)
    beard, smiling = faces % 3 == 0, faces % 2 == 0
    index = np.tile(faces, 3)
    truth = np.repeat([0, 1, 2], 100)
    chosen = np.where(beard[index], (truth + 1) % 3, truth)
    scenes = {
        "index": index.tolist(),
        "true_order": truth.tolist(),
        "evidence": chosen.tolist(),
        "yaw": np.zeros(300).tolist(),
        "pixels": (np.arange(300) + 1000).tolist(),
    }
    labels = {"test": {"beard": beard, "smiling": smiling}}
    lines = lighting.failure_lines({"test/texture/x": {"scenes": scenes}}, ["texture/x"], labels)
    row = next(line for line in lines if line.startswith("| test |"))
    assert row.endswith(f"| 0.00 ({3 * beard.sum()}) | {1 - beard[smiling].mean():.2f} ({3 * smiling.sum()}) |"), row
    assert "with beard (0.00 against 1.00; by true order 0.00/0.00/0.00 against 1.00/1.00/1.00)" in lines[-1]
    assert "with smiling" not in lines[-1], lines[-1]
    assert all(line.count("|") == 12 for line in lines if line.startswith("|"))


def test_failure_figure_caption_names_each_scene_and_its_signed_evidence():
    """The failure figure's caption gives the row and, per scene, its face, true and chosen order and the chosen
    candidate's log evidence over the true order's best with its sign (an under-fit may be chosen at a loss)."""
    wrong = {
        "row": "texture/x+residual_process",
        "scenes": [
            {"index": 4, "true_order": 0, "chosen": 1, "evidence_gain": 115.9},
            {"index": 1, "true_order": 2, "chosen": 1, "evidence_gain": -2.2},
        ],
    }
    text = lighting.failure_figure_text(wrong)
    assert "`texture/x+residual_process`" in text
    assert "face 4: true order 0, chosen 1, +116; face 1: true order 2, chosen 1, -2)" in text, text


def test_face_attributes_are_the_labels_the_dataset_gives_its_items():
    """The report's attribute labels of a row's faces are those SynthFaces gives the same items, per split."""
    from disent.data import SynthFaces

    scenes = {"index": [0, 1, 2, 3, 4, 0, 1]}
    order = {"val/texture/x": {"scenes": scenes, "settings": {"seed": 0}}, "test/texture/y": {"scenes": scenes}}
    labels = lighting.face_attributes(order, ["texture/x"])
    assert set(labels) == {"val"}  # the row asked for only
    attrs = SynthFaces("val", seed=0).get_batch(range(5))["attrs"]
    for a in ("smiling", "beard", "eyeglasses", "senior"):
        assert labels["val"][a].tolist() == attrs[a].bool().tolist(), a


def test_unoverlap_moves_point_labels_apart_and_keeps_the_highest_in_place():
    """Six labels of nearly one point: afterwards no two texts overlap, the highest has not moved, and each still
    points at its own point."""
    from matplotlib.text import Text

    plt = document.pyplot()
    fig, ax = plt.subplots()
    points = [(0.5, 0.5 + 0.001 * i) for i in range(6)]
    labels = [
        ax.annotate(f"label {i}", p, textcoords="offset points", xytext=(4, 3), arrowprops={"arrowstyle": "-"})
        for i, p in enumerate(points)
    ]
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    boxes = lambda: [Text.get_window_extent(t, renderer) for t in labels]  # noqa: E731
    assert any(a.overlaps(b) for i, a in enumerate(boxes()) for b in boxes()[i + 1 :])
    document.unoverlap(ax, labels)
    after = boxes()
    assert not any(a.overlaps(b) for i, a in enumerate(after) for b in after[i + 1 :])
    assert labels[-1].xyann == (4, 3) and all(t.xyann[1] < 3 for t in labels[:-1])
    assert [t.xy for t in labels] == points
    plt.close(fig)


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


def test_conf_at_a_revision_is_that_revisions_conf():
    """``conf_at``: the ``conf/`` folder of a git revision (where the checkout has its history), None for a revision
    git does not know."""
    from disent.runs import CONF_DIR, conf_at

    head = conf_at("HEAD")
    if head is None:
        pytest.skip("no git history here")
    committed = subprocess.run(
        ["git", "-C", str(CONF_DIR.parent), "show", "HEAD:conf/config.yaml"], capture_output=True, text=True
    ).stdout
    assert (Path(head) / "config.yaml").read_text() == committed
    assert conf_at("0000000000000000000000000000000000000000") is None

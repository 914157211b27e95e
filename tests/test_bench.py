"""``python -m disent.bench``: the JSON a tiny run writes (no timing asserts) and what it counts.  The speed
kernels' equality with the plain layers is tested in test_kernels.py."""

import json

import pytest
import torch
import torch.nn.functional as F

from disent import bench
from disent.bench.__main__ import main as bench_main
from disent.bench.models import time_to_accuracy
from disent.render import sh_shading
from disent.storage import cpu_name

RATES = ("train_img_s", "train_no_d_img_s", "infer_img_s")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    threads = torch.get_num_threads()
    try:
        bench_main(
            [
                "peak",
                "models",
                "profile",
                "norm_cost",
                "stack",
                "--runs",
                "2",
                "--models",
                "explicit",
                "implicit",
                "--rounds",
                "1",
                "--peak-n",
                "256",
                "--train-batch",
                "2",
                "--infer-batches",
                "1",
                "64",
                "--threads",
                "1",
                "--no-bf16",
                "--out",
                str(out),
            ]
        )
    finally:
        torch.set_num_threads(threads)
    assert (out.parent / ".tool").read_text() == "bench\n"  # --out FILE: its folder is a tool folder to publish
    return json.loads(out.read_text())


def test_gpu_figures_go_beside_the_cpu_ones():
    assert bench.bench_json("cpu") == bench.BENCH_JSON
    assert bench.bench_json("cuda") == bench.bench_json("cuda:1") == bench.BENCH_JSON.with_name("bench-cuda.json")


def test_load_average_names_only_this_machines_sections(tmp_path):
    path = tmp_path / "bench.json"
    path.write_text(
        json.dumps({"cpu": "another CPU", "device": "cpu", "data": {"x": 1}, "load_average_1min": {"data": 0.1}})
    )
    bench.save("peak", {"gflops": 1.0}, path)
    d = json.loads(path.read_text())
    assert d["cpu"] == cpu_name() and d["data"] == {"x": 1}  # the other machine's section is kept,
    assert set(d["load_average_1min"]) == {"peak"}  # but not listed as measured here
    bench.save("render", {"ms": 2.0}, path)
    assert set(json.loads(path.read_text())["load_average_1min"]) == {"peak", "render"}


def test_bench_json_schema(tiny_run):
    d = tiny_run
    assert d["peak_gflops"] > 0 and d["threads"] == 1 and d["device"] == "cpu" and d["torch"] == torch.__version__
    for name in ("explicit", "implicit"):
        m = d["models"][name]
        for rate in RATES:
            assert m[rate] > 0, (name, rate)
            frac = rate.replace("_img_s", "_fraction_of_peak")
            flops = m["flops_per_image"] if rate.startswith("infer") else m[rate.replace("img_s", "flops_per_image")]
            assert m[frac] == pytest.approx(flops * m[rate] / 1e9 / m[rate.replace("img_s", "peak_gflops")])
        assert "infer_b1_img_s" in m and "infer_b256_img_s" not in m  # only the batches asked for
        # FLOPs: a training step (forward + backward) costs more than the forward, D adds to it
        assert 0 < m["flops_per_image"] < m["train_no_d_flops_per_image"] < m["train_flops_per_image"]
        # every generated image past D's margin: D's backward skips the generated batch for D's own loss
        assert m["train_no_d_flops_per_image"] < m["train_past_margin_flops_per_image"] < m["train_flops_per_image"]
        assert not any("bf16" in k for k in m)  # --no-bf16
    setup = d["models_setup"]
    assert setup["train_batch"] == 2 and setup["loader_img_s"] > 0 and setup["loader_img_cpu_s"] > 0
    assert setup["loader_vs_explicit_training"] > 0
    assert set(setup["implicit_vs_explicit"]) == set(RATES)


def test_profile_section(tiny_run):
    """Per operator self CPU ms of a training step and an inference batch: the largest first,
    the rest in ``other``, and the parts sum to ``total``."""
    for name in ("explicit", "implicit"):
        for part in ("train_step_ms", "infer_batch_ms"):
            ops = dict(tiny_run["profile"][f"{name}_{part}"])
            total, share = ops.pop("total"), ops.pop("convolution_share")
            assert sum(ops.values()) == pytest.approx(total) and 0 < share < 1
            named = [v for k, v in sorted(ops.items()) if k != "other"]  # keys "01 name", "02 name", ...
            assert len(named) == 12 and named == sorted(named, reverse=True)
    assert any("convolution_backward" in k for k in tiny_run["profile"]["explicit_train_step_ms"])


def test_norm_cost_section(tiny_run):
    """Each normalisation's images/s over none, for the three rates."""
    cost = tiny_run["norm_cost"]
    assert set(cost) == {"batch", "group"}
    for ratios in cost.values():
        assert set(ratios) == set(RATES) and all(r > 0 for r in ratios.values())


def test_layer_overrides_build_the_asked_normalisation():
    """A model built inside ``layer_overrides`` has the asked layers; the overrides are restored after."""
    from disent.bench.models import LAYER_OVERRIDES, Trainer, layer_overrides, synth_batch

    batch, before = synth_batch(2, 64, "cpu", True), dict(LAYER_OVERRIDES)
    kinds = {}
    for norm, layer in (("none", None), ("batch", torch.nn.BatchNorm2d), ("group", torch.nn.GroupNorm)):
        with layer_overrides(norm=norm):
            model = Trainer("explicit", batch, False, "cpu").model
        kinds[norm] = {type(m) for m in model.modules() if isinstance(m, (torch.nn.BatchNorm2d, torch.nn.GroupNorm))}
        assert kinds[norm] == ({layer} if layer else set()), norm
    assert LAYER_OVERRIDES == before


def test_timed_rounds_alternates_and_times_each_call(monkeypatch):
    """A rate and its peak run in turn within every round (so they share the load of the moment);
    warm-up rounds are run but not timed, and each time is that call's own clock difference."""
    clock, calls = iter(range(100)), []
    monkeypatch.setattr(bench.time, "perf_counter", lambda: next(clock))
    fns = [lambda: calls.append("rate"), lambda: (calls.append("peak"), next(clock))]  # the peak takes 1 tick more
    times = bench.timed_rounds(fns, rounds=3, warmup=1)
    assert calls == ["rate", "peak"] * 4
    assert times == [[1, 1, 1], [2, 2, 2]]


def test_bf16_figures_and_bf16_stays_close_to_float32():
    """bfloat16 autocast beside float32: rates, and the same weights give nearly the same losses and outputs."""
    from argparse import Namespace

    from disent.bench.models import add_fractions, bench_bf16, synth_batch

    args = Namespace(train_batch=2, rounds=1, no_channels_last=False, peak_n=128)
    fig = bench_bf16("explicit", args, "cpu", lambda: None, synth_batch(2, 64, "cpu", True))
    assert fig["train_bf16_img_s"] > 0 and fig["infer_bf16_img_s"] > 0
    assert fig["bf16_first_step_total_rel_diff"] < 1e-2 and fig["bf16_first_step_D_rel_diff"] < 1e-2
    assert 0 < fig["bf16_recon_max_abs_diff"] < 0.05 and fig["bf16_normal_mean_angle_deg"] < 2
    fig.update(flops_per_image=1e9, train_flops_per_image=3e9)
    add_fractions(fig, 1.0)  # bf16 training does the FLOPs of a float32 step, stated against the float32 peak
    assert fig["train_bf16_fraction_of_peak"] == pytest.approx(
        3 * fig["train_bf16_img_s"] / fig["train_bf16_peak_gflops"]
    )
    assert fig["infer_bf16_fraction_of_peak"] == pytest.approx(fig["infer_bf16_img_s"] / fig["infer_bf16_peak_gflops"])


def test_loader_figure_renders_n_fresh_images_per_round(monkeypatch):
    from disent.bench.models import loader_img_s
    from disent.data import SynthFaces

    seen = []
    monkeypatch.setattr(SynthFaces, "get_batch", lambda self, idx: seen.append(list(idx)))
    wall, cpu = loader_img_s(4, 64, 3)
    assert wall > 0 and cpu > 0
    assert [len(i) for i in seen] == [4] * 4  # the table warm-up, then 3 timed rounds of exactly 4 images
    assert len({i for idx in seen for i in idx}) == 16  # every round on fresh images


def test_flops_scale_with_resolution():
    """The FLOP counter sees every convolution: 4x the pixels, ~4x the convolution FLOPs."""
    from disent.bench.models import count_flops, model_cfg
    from disent.models import build_model

    f = {}
    for res in (16, 32):
        torch.manual_seed(0)
        model = build_model(model_cfg("explicit", res))
        f[res] = count_flops(lambda: model(torch.rand(1, 3, res, res)))
    assert 3.0 < f[32] / f[16] < 4.0  # the fully connected layers grow less than 4x


def test_shading_stays_float32_under_mixed_precision():
    normal = F.normalize(torch.randn(2, 3, 4, 4), dim=1)
    sh = torch.randn(2, 3, 9)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        s = sh_shading(normal.bfloat16(), sh)
    assert s.dtype == torch.float32
    torch.testing.assert_close(s, sh_shading(normal.bfloat16().float(), sh))


def test_time_to_accuracy_reads_metrics(tmp_path):
    """Minutes of training wall time until the first validation (or the final evaluation) whose network
    normal error beats the dataset-mean map's, and the pseudo-GT's; else null with the best error and when."""
    log = tmp_path / "metrics.jsonl"
    train = {"step": 5, "wall": 1.0, "total": 1.0}
    val = lambda step, wall, err: {
        "step": step,
        "wall": wall,
        "minutes": wall / 60,
        "val": {"normal_mean": err, "pseudo_normal_mean": 20.0, "trivial_normal_mean": 26.0},
    }
    final = {
        "step": 40,
        "wall": 300.0,
        "eval": {"normal_mean": 18.0, "pseudo_normal_mean": 19.0, "trivial_normal_mean": 26},
    }
    write = lambda *recs: log.write_text("\n".join(json.dumps(r) for r in recs) + "\n")
    write(train, val(10, 60.0, 30.0), val(20, 150.0, 19.5), val(30, 240.0, 25.0), final)
    r = time_to_accuracy(log)
    assert r["trivial"]["minutes"] == 2.5 and r["trivial"]["step"] == 20
    assert r["pseudo_gt"]["minutes"] == 2.5 and r["pseudo_gt"]["source"] == "val" and r["pseudo_gt"]["target"] == 20.0
    write(train, val(10, 60.0, 30.0), val(20, 150.0, 22.0), val(30, 240.0, 25.0), final)
    r = time_to_accuracy(log)  # the mean map is beaten at step 20, the pseudo-GT only by the final evaluation
    assert r["trivial"]["minutes"] == 2.5 and r["trivial"]["normal_mean"] == 22.0
    assert r["pseudo_gt"]["minutes"] == 5.0 and r["pseudo_gt"]["step"] == 40 and r["pseudo_gt"]["source"] == "eval"
    write(train, val(10, 60.0, 30.0), val(20, 150.0, 27.0), val(30, 240.0, 28.0))
    r = time_to_accuracy(log)
    assert r["trivial"]["minutes"] is None and r["pseudo_gt"]["minutes"] is None
    assert r["best_normal_mean"] == 27.0 and r["best_step"] == 20
    assert r["best_minutes"] == 2.5 and r["last_minutes"] == 4.0
    write(train)
    assert "trivial" not in time_to_accuracy(log)


@pytest.mark.parametrize("fmt", [torch.contiguous_format, torch.channels_last])
def test_unit_equals_normalize(fmt):
    from disent.render import unit

    x = torch.randn(2, 3, 5, 5, dtype=torch.float64).contiguous(memory_format=fmt)
    x[0, :, 0, 0] = 0  # F.normalize's eps: a zero vector stays zero
    torch.testing.assert_close(unit(x), F.normalize(x, dim=1))


def test_out_in_the_working_folder_is_refused(tmp_path, monkeypatch):
    """``--out FILE`` makes FILE's folder a tool folder: a bare name would make the working folder one."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit):
        bench_main(["peak", "--out", "bench.json", "--threads", "1"])
    assert not (tmp_path / ".tool").exists() and not (tmp_path / "bench.json").exists()


def test_a_suite_slice_gives_images_per_wall_second_and_the_projected_suite_time(tmp_path):
    """``python -m disent.bench.suite``: the slice's images (steps x batch of each finished run) over its wall time,
    the 33 long runs' minutes at that rate, merged into the benchmark file; the report states them against the
    targets, and says the suite is not measured where a GPU file has no slice."""
    import yaml

    from disent.bench.suite import main as suite_main
    from disent.report.benchmarks import suite_text

    for name, steps in (("explicit_s0", 100), ("explicit_s1", 100), ("explicit_s2", 50)):
        run = tmp_path / "slice" / name
        (run / ".hydra").mkdir(parents=True)
        (run / ".hydra" / "config.yaml").write_text(yaml.safe_dump({"train": {"batch_size": 25}, "seed": 0}))
        (run / "eval.json").write_text(json.dumps({"steps": steps, "train_seconds": 3.0, "normal_mean": 20.0}))
    (tmp_path / "slice" / "cut").mkdir()  # an unfinished run (no eval.json) trained nothing that counts
    bench_file = tmp_path / "bench.json"
    bench_file.write_text(json.dumps({"device": "cuda", "models": {}}))
    suite_main([str(tmp_path / "slice"), "1000", "1010", "--into", str(bench_file)])
    suite = json.loads(bench_file.read_text())["suite"]
    assert suite["images"] == 250 * 25 and suite["wall_s"] == 10 and suite["images_per_s"] == 625
    assert suite["suite_projected_min"] == pytest.approx(33 * 250_000 / 625 / 60)
    assert [r["run"] for r in suite["runs"]] == ["explicit_s0", "explicit_s1", "explicit_s2"]
    text = suite_text(suite)
    assert "625 images/s" in text and "target 20,000; missed" in text and "220 min" in text
    assert "Not measured" in suite_text(None)


@pytest.mark.slow
def test_the_models_benchmark_times_compiled_steps_with_compile(tmp_path):
    """``--compile`` times the training steps compiled (``train.compile``), counts their FLOPs eager, and says so in
    the file."""
    out = tmp_path / "bench" / "bench.json"
    threads = torch.get_num_threads()
    try:
        bench_main(
            [
                *("models", "--models", "explicit", "--compile", "--rounds", "1", "--peak-n", "256"),
                *("--train-batch", "2", "--infer-batches", "64", "--threads", "1", "--no-bf16", "--out", str(out)),
            ]
        )
    finally:
        torch.set_num_threads(threads)
    b = json.loads(out.read_text())
    assert b["models_setup"]["compile"] is True
    explicit = b["models"]["explicit"]
    assert explicit["train_img_s"] > 0 and explicit["train_flops_per_image"] > 0


def test_the_stack_benchmark_times_stacked_runs_beside_the_same_runs_one_after_another(tiny_run):
    """``stack``: the runs' images/s stacked and one after another, each against the peak measured beside it, the
    same FLOPs per image for both, and their ratio."""
    s = tiny_run["stack"]
    assert s["runs"] == 2 and s["batch"] == 2 and s["flops_per_image"] > 0
    for key in ("sequential", "stacked"):
        assert s[f"{key}_img_s"] > 0 and s[f"{key}_flops_per_image"] == s["flops_per_image"]
        expected = s["flops_per_image"] * s[f"{key}_img_s"] / 1e9 / s[f"{key}_peak_gflops"]
        assert s[f"{key}_fraction_of_peak"] == pytest.approx(expected)
    assert s["stacked_over_sequential"] == pytest.approx(s["stacked_img_s"] / s["sequential_img_s"])

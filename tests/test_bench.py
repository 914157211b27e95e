"""``python -m disent.bench``: the JSON a tiny run writes (no timing asserts), and the fast
paths of the models equal the plain computations they replace."""
import json

import pytest
import torch
import torch.nn.functional as F

from disent import bench
from disent.models.bench import time_to_accuracy
from disent.models.networks import upsample_conv
from disent.render import sh_shading

RATES = ("train_img_s", "train_no_d_img_s", "infer_img_s")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    threads = torch.get_num_threads()
    try:
        bench.main(["peak", "models", "profile", "--models", "explicit", "implicit", "--rounds", "1", "--peak-n", "256",
                    "--train-batch", "2", "--infer-batches", "1", "64", "--threads", "1", "--no-bf16", "--out", str(out)])
    finally:
        torch.set_num_threads(threads)
    return json.loads(out.read_text())


def test_gpu_figures_go_beside_the_cpu_ones():
    assert bench.bench_json("cpu") == bench.BENCH_JSON
    assert bench.bench_json("cuda") == bench.bench_json("cuda:1") == bench.BENCH_JSON.with_name("bench-cuda.json")


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

    from disent.models.bench import add_fractions, bench_bf16, synth_batch

    args = Namespace(train_batch=2, rounds=1, no_channels_last=False, peak_n=128)
    fig = bench_bf16("explicit", args, "cpu", lambda: None, synth_batch(2, 64, "cpu", True))
    assert fig["train_bf16_img_s"] > 0 and fig["infer_bf16_img_s"] > 0
    assert fig["bf16_first_step_total_rel_diff"] < 1e-2 and fig["bf16_first_step_D_rel_diff"] < 1e-2
    assert 0 < fig["bf16_recon_max_abs_diff"] < 0.05 and fig["bf16_normal_mean_angle_deg"] < 2
    fig.update(flops_per_image=1e9, train_flops_per_image=3e9)
    add_fractions(fig, 1.0)  # bf16 training does the FLOPs of a float32 step, stated against the float32 peak
    assert fig["train_bf16_fraction_of_peak"] == pytest.approx(3 * fig["train_bf16_img_s"] / fig["train_bf16_peak_gflops"])
    assert fig["infer_bf16_fraction_of_peak"] == pytest.approx(fig["infer_bf16_img_s"] / fig["infer_bf16_peak_gflops"])


def test_loader_figure_renders_n_fresh_images_per_round(monkeypatch):
    from disent.data import SynthFaces
    from disent.models.bench import loader_img_s

    seen = []
    monkeypatch.setattr(SynthFaces, "get_batch", lambda self, idx: seen.append(list(idx)))
    wall, cpu = loader_img_s(4, 64, 3)
    assert wall > 0 and cpu > 0
    assert [len(i) for i in seen] == [4] * 4  # the table warm-up, then 3 timed rounds of exactly 4 images
    assert len({i for idx in seen for i in idx}) == 16  # every round on fresh images


def test_flops_scale_with_resolution():
    """The FLOP counter sees every convolution: 4x the pixels, ~4x the convolution FLOPs."""
    from disent.models import build_model
    from disent.models.bench import count_flops, model_cfg

    f = {}
    for res in (16, 32):
        torch.manual_seed(0)
        model = build_model(model_cfg("explicit", res))
        f[res] = count_flops(lambda: model(torch.rand(1, 3, res, res)))
    assert 3.0 < f[32] / f[16] < 4.0  # the fully connected layers grow less than 4x


@pytest.mark.parametrize("c,o", [(8, 3), (5, 4), (6, 5)])  # phase form, and a wide layer as written
def test_upsample_conv_equals_conv_of_nearest_upsampling(c, o):
    torch.manual_seed(0)
    conv = torch.nn.Conv2d(c, o, 3, padding=1).double()
    x = torch.randn(2, c, 5, 7, dtype=torch.float64, requires_grad=True)
    ref = conv(F.interpolate(x, scale_factor=2, mode="nearest"))
    out = upsample_conv(x, conv.weight, conv.bias)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref)
    grads = torch.autograd.grad(out, (x, conv.weight, conv.bias), g)
    ref_grads = torch.autograd.grad(ref, (x, conv.weight, conv.bias), g)
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b)


@pytest.mark.parametrize("o", [1, 3, 12])
@pytest.mark.parametrize("fn", ["narrow_conv", "NarrowConv"])  # autograd through it / its own backward
def test_narrow_conv_equals_conv2d_with_gradients(o, fn):
    import disent.models.networks as N

    conv = N.narrow_conv if fn == "narrow_conv" else N.NarrowConv.apply
    torch.manual_seed(0)
    x = torch.randn(2, 5, 6, 7, dtype=torch.float64).contiguous(memory_format=torch.channels_last).requires_grad_()
    w = torch.randn(o, 5, 3, 3, dtype=torch.float64, requires_grad=True)
    b = torch.randn(o, dtype=torch.float64, requires_grad=True)
    ref = F.conv2d(x, w, b, padding=1)
    out = conv(x, w, b)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref)
    for a, r in zip(torch.autograd.grad(out, (x, w, b), g), torch.autograd.grad(ref, (x, w, b), g)):
        torch.testing.assert_close(a, r)
    if fn == "NarrowConv":  # gradients against finite differences
        assert torch.autograd.gradcheck(conv, (x[:1, :, :3, :4].detach().requires_grad_(), w, b))


@pytest.mark.parametrize("channels_last", [True, False])
def test_max_unpool_equals_torch_with_gradients(channels_last):
    """MaxUnpool: F.max_unpool2d's output, and its gradient for channels-last (the gather along
    NHWC pixels) and contiguous maps; gradients against finite differences too."""
    import disent.models.networks as N

    torch.manual_seed(0)
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    pooled, switches = F.max_pool2d(torch.randn(3, 5, 8, 6, dtype=torch.float64).contiguous(memory_format=fmt), 2,
                                    return_indices=True)
    assert switches.is_contiguous(memory_format=fmt)
    x = pooled.detach().requires_grad_()
    out, ref = N.MaxUnpool.apply(x, switches), F.max_unpool2d(x, switches, 2)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref).contiguous(memory_format=fmt)
    grad = torch.autograd.grad(out, x, g)[0]
    torch.testing.assert_close(grad, torch.autograd.grad(ref, x, g)[0])
    assert grad.shape == x.shape and grad.is_contiguous(memory_format=fmt)
    assert torch.autograd.gradcheck(lambda v: N.MaxUnpool.apply(v, switches), (x,))


def test_inference_fast_paths_leave_the_outputs_unchanged():
    """The explicit model with and without narrow_conv at inference: the same outputs."""
    import disent.models.networks as N
    from disent.models import build_model
    from disent.models.bench import model_cfg

    torch.manual_seed(0)
    model = build_model(model_cfg("explicit", 16)).eval().to(memory_format=torch.channels_last)
    x = torch.rand(3, 3, 16, 16).contiguous(memory_format=torch.channels_last)
    with torch.no_grad():
        fast = model(x)
        narrow, N.NARROW_MAX = N.NARROW_MAX, 0
        try:
            plain = model(x)
        finally:
            N.NARROW_MAX = narrow
    assert narrow > 0
    for k in ("recon", "background", "matte", "normal", "albedo"):
        torch.testing.assert_close(fast[k], plain[k], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", ["explicit", "implicit"])
def test_channels_last_model_computes_the_same_outputs_and_gradients(name):
    """Memory format is a speed choice only: a channels-last copy of a model (NHWC from the
    decoders' first map on) gives the contiguous model's outputs and weight gradients."""
    import copy

    from disent.models import build_model
    from disent.models.bench import model_cfg

    torch.manual_seed(0)
    model = build_model(model_cfg(name, 16))
    nhwc = copy.deepcopy(model).to(memory_format=torch.channels_last)
    x = torch.rand(2, 3, 16, 16)
    outs, grads = [], []
    for m, image in ((model, x), (nhwc, x.contiguous(memory_format=torch.channels_last))):
        out = m(image)
        (out["recon"].square().mean() + out["normal"].sum()).backward()
        outs.append(out)
        grads.append({k: p.grad for k, p in m.named_parameters()})
    for k in ("recon", "normal", "albedo", "matte", "background"):
        torch.testing.assert_close(outs[1][k], outs[0][k], rtol=1e-4, atol=1e-5)
    for k, g in grads[0].items():  # BatchNorm's backward cancels large sums: float32 rounding scales with the
        # tensor's largest gradient (in float64 the layouts agree to 1e-12, but the CPU kernels run in float32 only)
        torch.testing.assert_close(grads[1][k], g, rtol=1e-3, atol=1e-5 * max(1.0, g.abs().max().item()), msg=k)


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
    val = lambda step, wall, err: {"step": step, "wall": wall, "minutes": wall / 60,
                                   "val": {"normal_mean": err, "pseudo_normal_mean": 20.0, "trivial_normal_mean": 26.0}}
    final = {"step": 40, "wall": 300.0, "eval": {"normal_mean": 18.0, "pseudo_normal_mean": 19.0, "trivial_normal_mean": 26}}
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


@pytest.mark.parametrize("name", ["explicit", "implicit", "baseline"])
def test_batchnorm_folding_is_the_same_function_in_eval_mode(name, monkeypatch):
    """Eval mode folds each BatchNorm into the convolution before it: the same outputs and input gradients
    as applying the BatchNorm (with non-trivial running statistics and affine weights), in both layouts."""
    from disent.models import build_model, networks
    from disent.models.bench import model_cfg

    torch.manual_seed(0)
    model = build_model({**model_cfg(name, 16), "norm": "batch"}).double()
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            for t in (m.running_mean, m.weight, m.bias):
                t.data.normal_()
            m.running_var.data.uniform_(0.5, 2.0)
    model.eval()
    x = torch.rand(2, 3, 16, 16, dtype=torch.float64)
    outs = {}
    for fold in (True, False):
        monkeypatch.setattr(networks, "FOLD_BATCHNORM", fold)
        image = x.clone().requires_grad_(True)
        out = model(image)
        grad, = torch.autograd.grad(out["recon"].square().sum(), image)
        outs[fold] = ({k: v for k, v in out.items() if torch.is_tensor(v)}, grad)
    for k, v in outs[False][0].items():
        torch.testing.assert_close(outs[True][0][k], v, msg=k)
    torch.testing.assert_close(outs[True][1], outs[False][1])
    assert networks.conv_then_norm(model.encoder.convs[0], model.encoder.norms[0])[2] is False  # monkeypatched off
    model.train()  # training mode never folds: the batch statistics are the layer
    monkeypatch.setattr(networks, "FOLD_BATCHNORM", True)
    assert networks.conv_then_norm(model.encoder.convs[0], model.encoder.norms[0])[2] is False


def test_bench_rejects_a_thread_count_below_one(capsys):
    from disent.bench import main

    with pytest.raises(SystemExit) as e:
        main(["models", "--threads", "-2"])
    assert e.value.code == 2 and "--threads -2: must be a whole number >= 1" in capsys.readouterr().err

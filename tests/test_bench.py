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
        bench.main(["peak", "models", "--models", "explicit", "implicit", "--rounds", "1", "--peak-n", "256",
                    "--train-batch", "2", "--infer-batches", "1", "64", "--threads", "1", "--out", str(out)])
    finally:
        torch.set_num_threads(threads)
    return json.loads(out.read_text())


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
    setup = d["models_setup"]
    assert setup["train_batch"] == 2 and setup["loader_img_s"] > 0
    assert set(setup["implicit_vs_explicit"]) == set(RATES)


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


@pytest.mark.parametrize("c,o", [(8, 3), (5, 4)])
def test_upsample_conv_equals_conv_of_nearest_upsampling(c, o):
    torch.manual_seed(0)
    conv = torch.nn.Conv2d(c, o, 3, padding=1).double()
    x = torch.randn(2, c, 5, 7, dtype=torch.float64, requires_grad=True)
    ref = conv(F.interpolate(x, scale_factor=2, mode="nearest"))
    out = upsample_conv(x, conv)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref)
    grads = torch.autograd.grad(out, (x, conv.weight, conv.bias), g)
    ref_grads = torch.autograd.grad(ref, (x, conv.weight, conv.bias), g)
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b)


def test_shading_stays_float32_under_mixed_precision():
    normal = F.normalize(torch.randn(2, 3, 4, 4), dim=1)
    sh = torch.randn(2, 3, 9)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        s = sh_shading(normal.bfloat16(), sh)
    assert s.dtype == torch.float32
    torch.testing.assert_close(s, sh_shading(normal.bfloat16().float(), sh))


def test_time_to_accuracy_reads_metrics(tmp_path):
    log = tmp_path / "metrics.jsonl"
    evals = [{"step": 10, "wall": 60.0, "eval": {"normal_mean": 30.0, "pseudo_normal_mean": 20.0}},
             {"step": 20, "wall": 150.0, "eval": {"normal_mean": 19.0, "pseudo_normal_mean": 20.0}}]
    log.write_text("\n".join(json.dumps(r) for r in [{"step": 5, "wall": 1.0, "total": 1.0}, *evals]))
    r = time_to_accuracy(log)
    assert r["minutes"] == 2.5 and r["step"] == 20
    log.write_text(json.dumps(evals[0]))
    assert time_to_accuracy(log)["minutes"] is None


@pytest.mark.parametrize("fmt", [torch.contiguous_format, torch.channels_last])
def test_unit_equals_normalize(fmt):
    from disent.render import unit

    x = torch.randn(2, 3, 5, 5, dtype=torch.float64).contiguous(memory_format=fmt)
    x[0, :, 0, 0] = 0  # F.normalize's eps: a zero vector stays zero
    torch.testing.assert_close(unit(x), F.normalize(x, dim=1))

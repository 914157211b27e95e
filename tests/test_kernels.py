"""The CPU speed kernels (disent/models/kernels.py) compute the plain layers' functions: each kernel against
the torch operation it replaces, forward and backward, and whole models with ``kernels`` on against off."""

import copy

import pytest
import torch
import torch.nn.functional as F

from disent.bench.models import model_cfg
from disent.models import build_model
from disent.models import kernels as K


@pytest.mark.parametrize("c,o", [(8, 3), (5, 4), (6, 5)])  # phase form, and a wide layer as written
def test_upsample_conv_equals_conv_of_nearest_upsampling(c, o):
    torch.manual_seed(0)
    conv = torch.nn.Conv2d(c, o, 3, padding=1).double()
    x = torch.randn(2, c, 5, 7, dtype=torch.float64, requires_grad=True)
    ref = conv(F.interpolate(x, scale_factor=2, mode="nearest"))
    out = K.upsample_conv(x, conv.weight, conv.bias)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref)
    grads = torch.autograd.grad(out, (x, conv.weight, conv.bias), g)
    ref_grads = torch.autograd.grad(ref, (x, conv.weight, conv.bias), g)
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b)


@pytest.mark.parametrize("o", [1, 3, 12])
@pytest.mark.parametrize("fn", ["narrow_conv", "NarrowConv"])  # autograd through it / its own backward
def test_narrow_conv_equals_conv2d_with_gradients(o, fn):
    conv = K.narrow_conv if fn == "narrow_conv" else K.NarrowConv.apply
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
    torch.manual_seed(0)
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    pooled, switches = F.max_pool2d(
        torch.randn(3, 5, 8, 6, dtype=torch.float64).contiguous(memory_format=fmt), 2, return_indices=True
    )
    assert switches.is_contiguous(memory_format=fmt)
    x = pooled.detach().requires_grad_()
    out, ref = K.MaxUnpool.apply(x, switches), F.max_unpool2d(x, switches, 2)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(ref).contiguous(memory_format=fmt)
    grad = torch.autograd.grad(out, x, g)[0]
    torch.testing.assert_close(grad, torch.autograd.grad(ref, x, g)[0])
    assert grad.shape == x.shape and grad.is_contiguous(memory_format=fmt)
    assert torch.autograd.gradcheck(lambda v: K.MaxUnpool.apply(v, switches), (x,))


@pytest.mark.parametrize("name", ["explicit", "implicit"])
def test_channels_last_model_computes_the_same_outputs_and_gradients(name):
    """Memory format is a speed choice only: a channels-last copy of a model (NHWC from the
    decoders' first map on) gives the contiguous model's outputs and weight gradients."""
    import copy

    from disent.models import build_model

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


def randomise_batchnorm(model):
    """Non-trivial running statistics and affine weights, so that folding them is a real test."""
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            for t in (m.running_mean, m.weight, m.bias):
                t.data.normal_()
            m.running_var.data.uniform_(0.5, 2.0)


def outputs_and_gradients(model, x):
    image = x.clone().requires_grad_(True)
    out = model(image)
    loss = out["recon"].square().sum() + (out["normal"].sum() if "normal" in out else 0)
    grads = torch.autograd.grad(loss, [image, *model.parameters()], allow_unused=True)
    return {k: v for k, v in out.items() if torch.is_tensor(v)}, grads


@pytest.mark.parametrize("name", ["explicit", "implicit", "baseline"])
@pytest.mark.parametrize("train", [True, False])  # eval mode folds each BatchNorm into its convolution
def test_kernels_on_and_off_are_the_same_function(name, train):
    """In float64 (tight tolerance) the model with the kernels (phase-form upsampling, unpooling, BatchNorm
    folding at inference) and without them give the same outputs, input gradients and weight gradients."""
    torch.manual_seed(0)
    fast = build_model({**model_cfg(name, 16), "norm": "batch", "kernels": True}).double()
    randomise_batchnorm(fast)
    plain = build_model({**model_cfg(name, 16), "norm": "batch", "kernels": False}).double()
    plain.load_state_dict(fast.state_dict())
    fast.train(train), plain.train(train)
    x = torch.rand(3, 3, 16, 16, dtype=torch.float64)
    (out_f, grads_f), (out_p, grads_p) = outputs_and_gradients(fast, x), outputs_and_gradients(plain, x)
    assert out_f.keys() == out_p.keys()
    for k, v in out_p.items():
        torch.testing.assert_close(out_f[k], v, msg=k)
    for a, b in zip(grads_f, grads_p):
        if b is not None:
            torch.testing.assert_close(a, b)


@pytest.mark.parametrize("name", ["explicit", "implicit"])
def test_kernels_on_and_off_agree_in_float32_channels_last(name):
    """Where the narrow-convolution kernels engage (float32, channels-last, CPU): the same outputs and weight
    gradients as the plain layers, to float32 rounding."""
    torch.manual_seed(0)
    fast = build_model({**model_cfg(name, 16), "kernels": True}).to(memory_format=torch.channels_last)
    plain = copy.deepcopy(fast)
    for m in plain.modules():
        if hasattr(m, "layers"):
            m.layers = type(m.layers)(m.layers.norm, m.layers.centre_input, m.layers.z_act, kernels=False)
    x = torch.rand(4, 3, 16, 16).contiguous(memory_format=torch.channels_last)
    (out_f, grads_f), (out_p, grads_p) = outputs_and_gradients(fast, x), outputs_and_gradients(plain, x)
    for k, v in out_p.items():
        torch.testing.assert_close(out_f[k], v, rtol=1e-4, atol=1e-5, msg=k)
    for a, b in zip(grads_f, grads_p):
        if b is not None:
            torch.testing.assert_close(a, b, rtol=1e-3, atol=1e-5 * max(1.0, b.abs().max().item()))
    fast.eval(), plain.eval()
    with torch.no_grad():
        for k, v in plain(x).items():
            if torch.is_tensor(v):
                torch.testing.assert_close(fast(x)[k], v, rtol=1e-4, atol=1e-5, msg=k)


def test_the_scatter_unpooling_is_max_unpool2d_and_batches_under_vmap():
    """``networks.scatter_unpool`` (what stacked models unpool with) gives ``F.max_unpool2d``'s values and gradient,
    channels-last input too, and runs under ``torch.func.vmap`` over a stack of maps."""
    import torch.nn.functional as F

    from disent.models.networks import scatter_unpool

    g = torch.Generator().manual_seed(0)
    x = torch.randn(3, 5, 16, 16, generator=g)
    pooled, idx = F.max_pool2d(x, 2, return_indices=True)
    pooled.requires_grad_()
    grad = torch.randn(3, 5, 16, 16, generator=g)
    for y in (pooled, pooled.contiguous(memory_format=torch.channels_last)):
        plain, scattered = F.max_unpool2d(y, idx, 2), scatter_unpool(y, idx, 2)
        assert torch.equal(plain, scattered)
        assert torch.equal(*(torch.autograd.grad(out, pooled, grad)[0] for out in (plain, scattered)))
    stacked = torch.stack([pooled.detach(), 2 * pooled.detach()])
    out = torch.func.vmap(lambda p, i: scatter_unpool(p, i, 2), in_dims=(0, None))(stacked, idx)
    assert torch.equal(out[1], 2 * F.max_unpool2d(pooled.detach(), idx, 2))

"""CPU speed kernels for the networks of :mod:`disent.models.networks`: the same functions as the plain
PyTorch layers there, computed faster on the CPU (measured by ``python -m disent.bench models``).

Switched by ``model.kernels`` (``Layers.kernels``, default true); ``model.kernels=false`` runs the plain
layers, and ``tests/test_kernels.py`` checks both paths agree, forward and backward.

- :func:`upsample_conv`: nearest 2x upsampling + 3x3 convolution at the low resolution (phase taps).
- :func:`narrow_conv` / :class:`NarrowConv`: 3x3 convolutions with 1-4 output maps as one matrix product.
- :class:`MaxUnpool`: max-unpooling whose backward gathers a channels-last gradient in memory order.
- :func:`conv_then_norm`: at inference a BatchNorm is folded into the convolution before it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

NARROW_MAX = 4  # skip-decoder convolutions with at most this many outputs run as narrow_conv on the CPU


# Nearest 2x upsampling followed by a 3x3 convolution, done at the low resolution: output pixel
# (2i+a, 2j+b) sees input rows i-1..i+1 with the kernel rows summed as PHASE_TAPS[a] says
# (a=0: row i-1 <- w0, row i <- w1+w2; a=1: row i <- w0+w1, row i+1 <- w2), the same for columns.
PHASE_TAPS = torch.tensor(
    [[[1.0, 0, 0], [0, 1, 1], [0, 0, 0]], [[0.0, 0, 0], [1, 1, 0], [0, 0, 1]]]
)  # [phase, low-res offset, kernel tap]


def upsample_conv(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``F.conv2d(interpolate(x, scale_factor=2, mode="nearest"), weight, bias, padding=1)``.  A narrow layer (at most
    ``NARROW_MAX`` outputs, the last one) runs as one convolution with 4x the output channels
    (one per phase) and a pixel shuffle: the upsampled tensor is never built, and 3 outputs
    become 12, which runs several times faster.  Wider layers run as written: on the CPU oneDNN
    takes the full-resolution convolution faster than the 4x-wide low-resolution one."""
    o, c = weight.shape[:2]
    if o > NARROW_MAX:
        return conv3x3(F.interpolate(x, scale_factor=2, mode="nearest"), weight, bias)
    taps = PHASE_TAPS.to(weight)
    w = torch.einsum("apk,bql,ockl->oabcpq", taps, taps, weight).reshape(4 * o, c, 3, 3)
    y = conv3x3(x, w, bias.repeat_interleave(4))
    return shuffle_to_planes(y) if cpu_nhwc(y) and not torch.is_grad_enabled() else F.pixel_shuffle(y, 2)


def cpu_nhwc(x: torch.Tensor) -> bool:
    """Channels-last maps on the CPU: where the narrow fast paths pay."""
    return x.device.type == "cpu" and x.is_contiguous(memory_format=torch.channels_last)


def shuffle_to_planes(y: torch.Tensor) -> torch.Tensor:
    """``F.pixel_shuffle(y, 2)`` of a channels-last ``y``, written channels first: with a few output
    maps the channels-last result has a 1-3 element inner dimension and takes ~3x longer to write."""
    B, C4, h, w = y.shape
    C = C4 // 4
    planes = y.permute(0, 2, 3, 1).reshape(B, h, w, C, 2, 2).permute(0, 3, 1, 4, 2, 5)  # [B, C, h, a, w, b]
    return planes.reshape(B, C, 2 * h, 2 * w)


def narrow_conv(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``F.conv2d(x, weight, bias, padding=1)`` for a 3x3 convolution with few outputs on
    channels-last ``x``: one matrix product gives every tap's contribution at every pixel,
    ``[9*O, C] @ [C, B*H*W]``, and eight shifted adds sum them.  The same multiply-adds as the
    convolution, which oneDNN runs at a fraction of the matmul rate with 1 or 3 output maps."""
    B, C, H, W = x.shape
    O = weight.shape[0]
    taps = weight.permute(2, 3, 0, 1).reshape(9 * O, C) @ x.permute(1, 0, 2, 3).reshape(C, B * H * W)
    taps = taps.view(3, 3, O, B, H, W)
    out = F.pad(taps[1, 1] + bias.view(O, 1, 1, 1), (1, 1, 1, 1))  # [O, B, H+2, W+2]
    for dy in range(3):
        for dx in range(3):
            if (dy, dx) != (1, 1):  # output (y, x) gets tap (dy, dx) of input pixel (y + dy - 1, x + dx - 1)
                out[:, :, 2 - dy : H + 2 - dy, 2 - dx : W + 2 - dx] += taps[dy, dx]
    return out[:, :, 1 : H + 1, 1 : W + 1].permute(1, 0, 2, 3)


class NarrowConv(torch.autograd.Function):
    """:func:`narrow_conv` with a backward for training: the input gradient from oneDNN (fast with
    few output maps), the weight gradient as one matrix product of the nine shifted output gradients
    with the input, ``[9*O, B*H*W] @ [B*H*W, C]`` (oneDNN's runs at ~10-20 GFLOP/s with 1-3 outputs)."""

    @staticmethod
    def forward(ctx, x, weight, bias):
        ctx.save_for_backward(x, weight)
        return narrow_conv(x, weight, bias)

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        (_, C, H, W), O = x.shape, weight.shape[0]
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:
            grad_x = torch.ops.aten.convolution_backward(
                grad, x, weight, None, [1, 1], [1, 1], [1, 1], False, [0, 0], 1, [True, False, False]
            )[0]
        if ctx.needs_input_grad[1]:  # tap (dy, dx) of input pixel p meets the output gradient at p - (dy - 1, dx - 1)
            g = F.pad(grad.permute(1, 0, 2, 3), (1, 1, 1, 1))  # [O, B, H+2, W+2]
            shifted = torch.stack(
                [g[:, :, 2 - dy : H + 2 - dy, 2 - dx : W + 2 - dx] for dy in range(3) for dx in range(3)]
            )
            grad_w = shifted.view(9 * O, -1) @ x.permute(0, 2, 3, 1).reshape(-1, C)
            grad_w = grad_w.view(3, 3, O, C).permute(2, 3, 0, 1)
        if ctx.needs_input_grad[2]:
            grad_b = grad.sum((0, 2, 3))
        return grad_x, grad_w, grad_b


def conv3x3(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``F.conv2d(x, weight, bias, padding=1)``; on the CPU with channels-last maps, outputs of at most
    ``NARROW_MAX`` maps go through :func:`narrow_conv` (:class:`NarrowConv` in float32 training)."""
    if weight.shape[0] <= NARROW_MAX and cpu_nhwc(x):
        if not torch.is_grad_enabled():
            return narrow_conv(x, weight, bias)
        if x.dtype == weight.dtype == torch.float32 and not torch.is_autocast_enabled("cpu"):
            return NarrowConv.apply(x, weight, bias)
    return F.conv2d(x, weight, bias, padding=1)


class MaxUnpool(torch.autograd.Function):
    """``F.max_unpool2d(x, switches, 2)`` whose backward pass gathers a channels-last gradient along its
    pixels with the channels innermost: autograd's gather along the flattened plane of a channels-last
    tensor strides through memory (8.4 against 4.0 ms for a ``[64,32,64,64]`` gradient)."""

    @staticmethod
    def forward(ctx, x, switches):
        ctx.save_for_backward(switches)
        return F.max_unpool2d(x, switches, 2)

    @staticmethod
    def backward(ctx, grad):
        (switches,) = ctx.saved_tensors
        B, C, h, w = switches.shape
        if not (
            grad.is_contiguous(memory_format=torch.channels_last)
            and switches.is_contiguous(memory_format=torch.channels_last)
        ):
            return grad.flatten(2).gather(2, switches.flatten(2)).view(B, C, h, w), None
        g, idx = (t.permute(0, 2, 3, 1).reshape(B, -1, C) for t in (grad, switches))  # views [B, pixels, C]
        return torch.gather(g, 1, idx).view(B, h, w, C).permute(0, 3, 1, 2), None


def conv_then_norm(conv: nn.Conv2d, norm: nn.Module):
    """``(weight, bias, norm_done)`` of ``conv`` followed by ``norm``.  In eval mode a BatchNorm is an affine
    map per channel, folded into the convolution (w * s, (b - mean) * s + beta with s = gamma / sqrt(var + eps)),
    which saves a pass over the activations at inference; otherwise the convolution's own weights, and the
    caller applies ``norm``."""
    if isinstance(norm, nn.BatchNorm2d) and not norm.training:
        scale = norm.weight * torch.rsqrt(norm.running_var + norm.eps)
        shift = norm.bias - norm.running_mean * scale
        bias = shift if conv.bias is None else shift + conv.bias * scale
        fmt = (
            torch.channels_last
            if conv.weight.is_contiguous(memory_format=torch.channels_last)
            else torch.contiguous_format
        )
        return (conv.weight * scale[:, None, None, None]).contiguous(memory_format=fmt), bias, True  # keep the layout
    return conv.weight, conv.bias, False


def conv_norm(conv: nn.Conv2d, norm: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``norm(conv(x))``, with the BatchNorm folded into the convolution at inference."""
    weight, bias, norm_done = conv_then_norm(conv, norm)
    x = F.conv2d(x, weight, bias, padding=1)
    return x if norm_done else norm(x)


def decoder_stages(decoder, x: torch.Tensor, switches) -> torch.Tensor:
    """The upsampling stages of :class:`~disent.models.networks.Decoder` from its first ``[B,64,h,w]`` map."""
    if decoder.convs[0].weight.is_contiguous(memory_format=torch.channels_last):
        x = x.contiguous(memory_format=torch.channels_last)  # a channels-last model: NHWC from the first map on
    for i, conv in enumerate(decoder.convs):
        hidden = i < len(decoder.convs) - 1
        weight, bias, norm_done = conv_then_norm(conv, decoder.norms[i]) if hidden else (conv.weight, conv.bias, True)
        if decoder.skips:
            x = conv3x3(MaxUnpool.apply(x, switches[-1 - i]), weight, bias)
        else:
            x = upsample_conv(x, weight, bias)  # = conv(nearest 2x upsampling of x)
        if hidden:
            x = F.relu(x if norm_done else decoder.norms[i](x))
    return x

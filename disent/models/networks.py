"""Encoder and decoder stacks of Sec. 4.1, shared by every model and by the discriminator.

Encoder: three 3x3 convolutions (32, 64, 64 filters), each followed by 2x2 max-pooling and a
ReLU, so a 3x64x64 image becomes 64x8x8; a fully connected layer gives the 128-d code Z_I.
Decoders are strictly symmetric: a fully connected layer back to 64x8x8, then three
(2x upsampling, 3x3 convolution) stages with 64, 32 and ``out_channels`` filters.  A decoder
with ``skips=True`` (background and matte, Sec. 3.3) upsamples by max-unpooling with the
encoder's pooling switches; without skips (every foreground decoder) it upsamples by nearest
neighbour, so the face passes through the bottleneck only.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

CHANNELS = (32, 64, 64)  # Sec. 4.1 filter counts of the encoder
NARROW_MAX = 4  # skip-decoder convolutions with at most this many outputs run as narrow_conv on the CPU


# Nearest 2x upsampling followed by a 3x3 convolution, done at the low resolution: output pixel
# (2i+a, 2j+b) sees input rows i-1..i+1 with the kernel rows summed as PHASE_TAPS[a] says
# (a=0: row i-1 <- w0, row i <- w1+w2; a=1: row i <- w0+w1, row i+1 <- w2), the same for columns.
PHASE_TAPS = torch.tensor([[[1.0, 0, 0], [0, 1, 1], [0, 0, 0]],
                           [[0.0, 0, 0], [1, 1, 0], [0, 0, 1]]])  # [phase, low-res offset, kernel tap]


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
                out[:, :, 2 - dy:H + 2 - dy, 2 - dx:W + 2 - dx] += taps[dy, dx]
    return out[:, :, 1:H + 1, 1:W + 1].permute(1, 0, 2, 3)


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
            grad_x = torch.ops.aten.convolution_backward(grad, x, weight, None, [1, 1], [1, 1], [1, 1], False, [0, 0],
                                                         1, [True, False, False])[0]
        if ctx.needs_input_grad[1]:  # tap (dy, dx) of input pixel p meets the output gradient at p - (dy - 1, dx - 1)
            g = F.pad(grad.permute(1, 0, 2, 3), (1, 1, 1, 1))  # [O, B, H+2, W+2]
            shifted = torch.stack([g[:, :, 2 - dy:H + 2 - dy, 2 - dx:W + 2 - dx] for dy in range(3) for dx in range(3)])
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
        if not (grad.is_contiguous(memory_format=torch.channels_last)
                and switches.is_contiguous(memory_format=torch.channels_last)):
            return grad.flatten(2).gather(2, switches.flatten(2)).view(B, C, h, w), None
        g, idx = (t.permute(0, 2, 3, 1).reshape(B, -1, C) for t in (grad, switches))  # views [B, pixels, C]
        return torch.gather(g, 1, idx).view(B, h, w, C).permute(0, 3, 1, 2), None


def check_resolution(resolution: int) -> int:
    if resolution < 8 or resolution % 8:
        raise ValueError(f"resolution must be a positive multiple of 8 (three 2x2 poolings), got {resolution}")
    return resolution // 8


@dataclass(frozen=True)
class Layers:
    """Choices about the layers that the paper leaves open, shared by every encoder and decoder of a
    model and by its discriminator, so that comparisons between them stay fair.

    ``norm``: normalisation after each hidden convolution ("none" as in the paper and the release,
    "batch" or "group"); ``centre_input``: feed the encoder ``2 * image - 1`` instead of [0, 1];
    ``z_act``: the nonlinearity on Z_I ("relu", "sigmoid" as in the release, or "none")."""
    norm: str = "none"
    centre_input: bool = False
    z_act: str = "relu"

    def __post_init__(self):
        for key, value, allowed in (("norm", self.norm, NORMS), ("z_act", self.z_act, Z_ACTS)):
            if value not in allowed:
                raise ValueError(f"model.{key}={value!r}; choose from {', '.join(allowed)}")


NORMS = ("none", "batch", "group")
Z_ACTS = ("relu", "sigmoid", "none")


FOLD_BATCHNORM = True  # eval mode: a BatchNorm after a convolution is folded into its weights (the same function)


def conv_then_norm(conv: nn.Conv2d, norm: nn.Module):
    """``(weight, bias, norm_done)`` of ``conv`` followed by ``norm``.  In eval mode a BatchNorm is an affine
    map per channel, folded into the convolution (w * s, (b - mean) * s + beta with s = gamma / sqrt(var + eps)),
    which saves a pass over the activations at inference; otherwise the convolution's own weights, and the
    caller applies ``norm``."""
    if FOLD_BATCHNORM and isinstance(norm, nn.BatchNorm2d) and not norm.training:
        scale = norm.weight * torch.rsqrt(norm.running_var + norm.eps)
        shift = norm.bias - norm.running_mean * scale
        bias = shift if conv.bias is None else shift + conv.bias * scale
        fmt = torch.channels_last if conv.weight.is_contiguous(memory_format=torch.channels_last) else torch.contiguous_format
        return (conv.weight * scale[:, None, None, None]).contiguous(memory_format=fmt), bias, True  # keep the layout
    return conv.weight, conv.bias, False


def norm_layer(kind: str, channels: int) -> nn.Module:
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "group":
        return nn.GroupNorm(8, channels)  # 4-8 channels a group at 32-64 maps
    return nn.Identity()


class Encoder(nn.Module):
    """Image ``[B,3,H,W]`` -> (code ``[B,code_dim]``, pooling switches, finest first)."""

    def __init__(self, resolution: int = 64, code_dim: int = 128, in_channels: int = 3, layers: Layers = Layers()):
        super().__init__()
        side = check_resolution(resolution)
        chans = (in_channels, *CHANNELS)
        self.layers = layers
        bias = layers.norm == "none"  # a normalisation layer subtracts any bias: none before one
        self.convs = nn.ModuleList(nn.Conv2d(a, b, 3, padding=1, bias=bias) for a, b in zip(chans[:-1], chans[1:]))
        self.norms = nn.ModuleList(norm_layer(layers.norm, b) for b in CHANNELS)
        self.fc = nn.Linear(CHANNELS[-1] * side * side, code_dim)

    def forward(self, image: torch.Tensor):
        x, switches = (2 * image - 1 if self.layers.centre_input else image), []
        for conv, norm in zip(self.convs, self.norms):
            weight, bias, norm_done = conv_then_norm(conv, norm)
            x = F.conv2d(x, weight, bias, padding=1)
            x, idx = F.max_pool2d(x if norm_done else norm(x), 2, return_indices=True)  # conv -> 2x2 max-pool -> ReLU
            x = F.relu(x)
            switches.append(idx)
        z = self.fc(x.flatten(1))
        act = self.layers.z_act
        return (F.relu(z) if act == "relu" else torch.sigmoid(z) if act == "sigmoid" else z), tuple(switches)


class Decoder(nn.Module):
    """Code ``[B,code_dim]`` -> map ``[B,out_channels,H,W]`` (no output nonlinearity)."""

    def __init__(self, out_channels: int, resolution: int = 64, code_dim: int = 128, skips: bool = False,
                 layers: Layers = Layers()):
        super().__init__()
        self.side = check_resolution(resolution)
        self.skips = skips
        chans = (*CHANNELS[::-1], out_channels)  # 64 -> 64 -> 32 -> out, the encoder reversed
        self.fc = nn.Linear(code_dim, CHANNELS[-1] * self.side * self.side)
        last = len(chans) - 2  # the output convolution keeps its bias; the hidden ones feed a normalisation layer
        self.convs = nn.ModuleList(nn.Conv2d(a, b, 3, padding=1, bias=layers.norm == "none" or i == last)
                                   for i, (a, b) in enumerate(zip(chans[:-1], chans[1:])))
        self.norms = nn.ModuleList(norm_layer(layers.norm, b) for b in chans[1:-1])  # hidden maps only

    def forward(self, code: torch.Tensor, switches=None) -> torch.Tensor:
        if self.skips and switches is None:
            raise ValueError("this decoder unpools with the encoder's switches; pass codes['switches']")
        x = F.relu(self.fc(code)).view(code.shape[0], CHANNELS[-1], self.side, self.side)
        if self.convs[0].weight.is_contiguous(memory_format=torch.channels_last):
            x = x.contiguous(memory_format=torch.channels_last)  # a channels-last model: NHWC from the first map on
        for i, conv in enumerate(self.convs):
            hidden = i < len(self.convs) - 1
            weight, bias, norm_done = conv_then_norm(conv, self.norms[i]) if hidden else (conv.weight, conv.bias, True)
            if self.skips:
                x = conv3x3(MaxUnpool.apply(x, switches[-1 - i]), weight, bias)
            else:
                x = upsample_conv(x, weight, bias)  # = conv(nearest 2x upsampling of x)
            if hidden:
                x = F.relu(x if norm_done else self.norms[i](x))
        return x


class CodeHeads(nn.Module):
    """Z_I -> the named latent codes (fully connected, Sec. 4.1); ``L`` is the 27-d SH light."""

    def __init__(self, names, code_dim: int = 128, white: float = 0.75):
        super().__init__()
        self.heads = nn.ModuleDict({n: nn.Linear(code_dim, 27 if n == "L" else code_dim) for n in names})
        if "L" in self.heads:  # start from a white ambient light, shading = white everywhere
            from disent.render import C4

            nn.init.zeros_(self.heads["L"].bias)
            with torch.no_grad():
                self.heads["L"].bias.view(3, 9)[:, 0] = white / C4

    def forward(self, z: torch.Tensor) -> dict:
        return {n: head(z) for n, head in self.heads.items()}

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

from disent.models import kernels

CHANNELS = (32, 64, 64)  # Sec. 4.1 filter counts of the encoder


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
    ``z_act``: the nonlinearity on Z_I ("relu", "sigmoid" as in the release, or "none"); ``decoder_convs``: 3x3
    convolutions per upsampling stage of a decoder without skips (1: the paper; more: a deeper decoder, beyond
    the paper, for the detail a face passes through the bottleneck with).  ``kernels`` is not a modelling choice:
    the same layers computed by the CPU speed kernels of :mod:`disent.models.kernels`."""

    norm: str = "none"
    centre_input: bool = False
    z_act: str = "relu"
    kernels: bool = True
    decoder_convs: int = 1

    def __post_init__(self):
        for key, value, allowed in (("norm", self.norm, NORMS), ("z_act", self.z_act, Z_ACTS)):
            if value not in allowed:
                raise ValueError(f"model.{key}={value!r}; choose from {', '.join(allowed)}")
        if not (isinstance(self.decoder_convs, int) and self.decoder_convs >= 1):
            raise ValueError(f"model.decoder_convs={self.decoder_convs!r}; a whole number >= 1 (1: the paper)")


NORMS = ("none", "batch", "group")
Z_ACTS = ("relu", "sigmoid", "none")


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
            x = kernels.conv_norm(conv, norm, x) if self.layers.kernels else norm(conv(x))
            x, idx = F.max_pool2d(x, 2, return_indices=True)  # conv -> 2x2 max-pool -> ReLU
            x = F.relu(x)
            switches.append(idx)
        z = self.fc(x.flatten(1))
        act = self.layers.z_act
        return (F.relu(z) if act == "relu" else torch.sigmoid(z) if act == "sigmoid" else z), tuple(switches)


def scatter_unpool(x: torch.Tensor, switches: torch.Tensor, kernel_size: int = 2) -> torch.Tensor:
    """``F.max_unpool2d(x, switches, 2)`` as a scatter into zeros: the same values and gradient, and, unlike
    max_unpool2d, a batching rule under ``torch.func.vmap`` (models trained stacked, :mod:`disent.stack`)."""
    B, C, H, W = x.shape
    out = x.new_zeros(B, C, kernel_size * H * kernel_size * W)
    out = out.scatter(2, switches.reshape(B, C, -1), x.reshape(B, C, -1))
    return out.view(B, C, kernel_size * H, kernel_size * W)


class Decoder(nn.Module):
    """Code ``[B,code_dim]`` -> map ``[B,out_channels,H,W]`` (no output nonlinearity)."""

    unpool_by_scatter = False  # True: unpool by scatter_unpool (the same function; batches under vmap)

    def __init__(
        self,
        out_channels: int,
        resolution: int = 64,
        code_dim: int = 128,
        skips: bool = False,
        layers: Layers = Layers(),
    ):
        super().__init__()
        self.side = check_resolution(resolution)
        self.skips, self.layers = skips, layers
        chans = (*CHANNELS[::-1], out_channels)  # 64 -> 64 -> 32 -> out, the encoder reversed
        self.fc = nn.Linear(code_dim, CHANNELS[-1] * self.side * self.side)
        last = len(chans) - 2  # the output convolution keeps its bias; the hidden ones feed a normalisation layer
        self.convs = nn.ModuleList(
            nn.Conv2d(a, b, 3, padding=1, bias=layers.norm == "none" or i == last)
            for i, (a, b) in enumerate(zip(chans[:-1], chans[1:]))
        )
        self.norms = nn.ModuleList(norm_layer(layers.norm, b) for b in chans[1:-1])  # hidden maps only
        # beyond the paper (Layers.decoder_convs): more 3x3 convolutions a stage, each with its norm and ReLU, after
        # a hidden stage's convolution and before the output convolution; none with skips or at the paper's 1
        extra = 0 if skips else layers.decoder_convs - 1
        width = [*chans[1:-1], chans[-2]]  # each stage's hidden width: its output's, the last stage's input's
        self.extra = nn.ModuleList(
            nn.ModuleList(nn.Conv2d(w, w, 3, padding=1, bias=layers.norm == "none") for _ in range(extra))
            for w in width
        )
        self.extra_norms = nn.ModuleList(nn.ModuleList(norm_layer(layers.norm, w) for _ in range(extra)) for w in width)

    def forward(self, code: torch.Tensor, switches=None) -> torch.Tensor:
        if self.skips and switches is None:
            raise ValueError("this decoder unpools with the encoder's switches; pass codes['switches']")
        x = F.relu(self.fc(code)).view(code.shape[0], CHANNELS[-1], self.side, self.side)
        if self.layers.kernels and not any(self.extra):  # the speed kernels compute the paper's decoder
            return kernels.decoder_stages(self, x, switches)
        last = len(self.convs) - 1
        for i, conv in enumerate(self.convs):
            x = (
                (scatter_unpool if self.unpool_by_scatter else F.max_unpool2d)(x, switches[-1 - i], 2)
                if self.skips
                else F.interpolate(x, scale_factor=2, mode="nearest")
            )
            if i < last:  # hidden maps: normalisation, ReLU; the output map has no nonlinearity
                x = F.relu(self.norms[i](conv(x)))
            for more, norm in zip(self.extra[i], self.extra_norms[i]):
                x = F.relu(norm(more(x)))
            if i == last:
                x = conv(x)
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

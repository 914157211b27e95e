"""Baseline autoencoder B (Sec. 5.1): the albedo path's encoder and decoder, a 265-d bottleneck
(128 + 128 + 9), no rendering layers."""

from __future__ import annotations

import torch
from torch import nn

from disent.models.networks import Decoder, Encoder, Layers


class Baseline(nn.Module):
    CODE_NAMES = ("z",)

    def __init__(
        self,
        resolution: int = 64,
        code_dim: int = 265,
        matting: bool = False,
        norm: str = "none",
        centre_input: bool = False,
        z_act: str = "relu",
        kernels: bool = True,
        decoder_convs: int = 1,
    ):
        super().__init__()
        if matting:
            raise ValueError("the baseline autoencoder has no matting layer (model.matting must be false)")
        self.resolution = resolution
        self.layers = layers = Layers(
            norm, centre_input, z_act, kernels, decoder_convs
        )  # the same layers as the rendering models
        self.encoder = Encoder(resolution, code_dim, layers=layers)
        self.decoder = Decoder(3, resolution, code_dim, layers=layers)

    def encode(self, image: torch.Tensor) -> dict:
        if image.dim() != 4 or image.shape[1] != 3 or image.shape[-2:] != (self.resolution, self.resolution):
            raise ValueError(f"image must be [B,3,{self.resolution},{self.resolution}], got {tuple(image.shape)}")
        return {"z": self.encoder(image)[0]}

    def decode(self, codes: dict) -> dict:
        return {"recon": torch.sigmoid(self.decoder(codes["z"])), "codes": codes}

    def forward(self, image: torch.Tensor) -> dict:
        return self.decode(self.encode(image))

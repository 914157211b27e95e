"""EBGAN discriminator (Zhao et al. 2016), as used in Sec. 4.2: an autoencoder whose energy is
its reconstruction error.

``energy(x)`` is the per-image mean squared error ``mean_{c,h,w} (D(x) - x)^2``, the same units
as E_recon.  The margin loss that trains D and the generator's term ``E_adv = D(G)`` are in
:mod:`disent.losses`.
"""

from __future__ import annotations

import torch
from torch import nn

from disent.models.networks import Decoder, Encoder, Layers


class Discriminator(nn.Module):
    def __init__(self, resolution: int = 64, code_dim: int = 128, layers: Layers = Layers()):
        super().__init__()
        self.encoder = Encoder(resolution, code_dim, layers=layers)
        self.decoder = Decoder(3, resolution, code_dim, layers=layers)  # no skips: D must go through its bottleneck

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """D's reconstruction of ``image``."""
        return torch.sigmoid(self.decoder(self.encoder(image)[0]))

    def energy(self, image: torch.Tensor) -> torch.Tensor:
        """Per-image reconstruction error ``[B]``."""
        return energy_of(self(image), image)


def energy_of(reconstruction: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """EBGAN's energy ``[B]`` from D's ``reconstruction`` of ``image``: their mean squared difference per image."""
    return (reconstruction - image).pow(2).flatten(1).mean(1)

"""The explicit model, Fig. 2(a): per-pixel normal and albedo in image space.

image -> Z_I -> {Z_bg, Z_m, Z_L, Z_Ne, Z_Ae};  N_e = normalize(dec_N(Z_Ne)), A_e = sigmoid(dec_A(Z_Ae)),
S_e = f_shading(N_e, L) (Eqs. 3-5), I_fg = A_e (.) S_e (Eq. 2), I_o = M (.) I_fg + (1 - M) (.) I_bg (Eq. 6).
"""
from __future__ import annotations

import torch
from torch import nn

from disent.models.networks import CodeHeads, Decoder, Encoder
from disent.render import composite, image_formation, sh_shading, unit


class Explicit(nn.Module):
    CODE_NAMES = ("bg", "m", "L", "Ne", "Ae")

    def __init__(self, resolution: int = 64, code_dim: int = 128, matting: bool = True):
        super().__init__()
        self.resolution, self.matting = resolution, matting
        self.encoder = Encoder(resolution, code_dim)
        self.codes = CodeHeads(self.CODE_NAMES, code_dim)
        self.dec_bg = Decoder(3, resolution, code_dim, skips=True)  # Sec. 3.3: skips for bg and matte only
        self.dec_m = Decoder(1, resolution, code_dim, skips=True)
        self.build_foreground(resolution, code_dim)

    def build_foreground(self, resolution, code_dim):
        self.dec_N = Decoder(3, resolution, code_dim)
        self.dec_A = Decoder(3, resolution, code_dim)

    def decode_foreground(self, codes: dict) -> dict:
        return {"normal": unit(self.dec_N(codes["Ne"])),
                "albedo": torch.sigmoid(self.dec_A(codes["Ae"]))}

    def encode(self, image: torch.Tensor) -> dict:
        """Latent codes by paper name, plus the encoder's pooling ``switches`` (used by bg/matte)."""
        if image.dim() != 4 or image.shape[1] != 3 or image.shape[-2:] != (self.resolution, self.resolution):
            raise ValueError(f"image must be [B,3,{self.resolution},{self.resolution}], got {tuple(image.shape)}")
        z, switches = self.encoder(image)
        return {**self.codes(z), "switches": switches}

    def decode(self, codes: dict) -> dict:
        out = self.decode_foreground(codes)
        B = out["normal"].shape[0]
        out["sh"] = codes["L"].reshape(B, 3, 9)  # Z_L = L, RGB x L1..L9
        out["shading"] = sh_shading(out["normal"], out["sh"])
        out["foreground"] = image_formation(out["albedo"], out["shading"])
        if self.matting:
            out["background"] = torch.sigmoid(self.dec_bg(codes["bg"], codes["switches"]))
            out["matte"] = torch.sigmoid(self.dec_m(codes["m"], codes["switches"]))
        else:  # ablation: no matting layer, the rendered face must explain the whole image
            out["background"] = torch.zeros_like(out["foreground"])
            out["matte"] = torch.ones_like(out["foreground"][:, :1])
        out["recon"] = composite(out["matte"], out["foreground"], out["background"])
        out["codes"] = codes
        return out

    def forward(self, image: torch.Tensor) -> dict:
        return self.decode(self.encode(image))

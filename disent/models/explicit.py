"""The explicit model, Fig. 2(a): per-pixel normal and albedo in image space.

image -> Z_I -> {Z_bg, Z_m, Z_L, Z_Ne, Z_Ae};  N_e = decode_normal(dec_N(Z_Ne)), A_e = sigmoid(dec_A(Z_Ae)),
S_e = f_shading(N_e, L) (Eqs. 3-5), I_fg = A_e (.) S_e (Eq. 2), I_o = M (.) I_fg + (1 - M) (.) I_bg (Eq. 6).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from disent.models.networks import CodeHeads, Decoder, Encoder, Layers
from disent.render import composite, image_formation, sh_shading, unit

NORMAL_PARAMS = ("unit", "xy")


def decode_normal(raw: torch.Tensor, param: str) -> torch.Tensor:
    """Unit normals from a decoder's output.  ``unit``: its first 3 channels normalised.  ``xy`` (the
    authors' release): n_x, n_y = HardTanh of the first 2 channels, n_z = sqrt(1 - n_x^2 - n_y^2) >= 0,
    so every normal faces the camera and a zero output is the frontal normal (0, 0, 1)."""
    if param == "xy":
        xy = F.hardtanh(raw[:, :2])
        z = (1 - xy.pow(2).sum(1, keepdim=True)).clamp_min(1e-4).sqrt()
        return unit(torch.cat([xy, z], 1))
    return unit(raw[:, :3])


class Explicit(nn.Module):
    CODE_NAMES = ("bg", "m", "L", "Ne", "Ae")

    def __init__(
        self,
        resolution: int = 64,
        code_dim: int = 128,
        matting: bool = True,
        normal: str = "unit",
        norm: str = "none",
        centre_input: bool = False,
        z_act: str = "relu",
        kernels: bool = True,
        decoder_convs: int = 1,
    ):
        super().__init__()
        if normal not in NORMAL_PARAMS:
            raise ValueError(f"model.normal={normal!r}; choose from {', '.join(NORMAL_PARAMS)}")
        self.resolution, self.matting, self.normal_param = resolution, matting, normal
        self.layers = layers = Layers(norm, centre_input, z_act, kernels, decoder_convs)
        self.encoder = Encoder(resolution, code_dim, layers=layers)
        self.codes = CodeHeads(self.CODE_NAMES, code_dim)
        self.dec_bg = Decoder(3, resolution, code_dim, skips=True, layers=layers)  # Sec. 3.3: skips for bg, matte only
        self.dec_m = Decoder(1, resolution, code_dim, skips=True, layers=layers)
        self.build_foreground(resolution, code_dim)

    def build_foreground(self, resolution, code_dim):
        self.dec_N = Decoder(2 if self.normal_param == "xy" else 3, resolution, code_dim, layers=self.layers)
        self.dec_A = Decoder(3, resolution, code_dim, layers=self.layers)

    def decode_foreground(self, codes: dict) -> dict:
        return {
            "normal": decode_normal(self.dec_N(codes["Ne"]), self.normal_param),
            "albedo": torch.sigmoid(self.dec_A(codes["Ae"])),
        }

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

"""The implicit model, Fig. 2(b): normal and albedo live in face UV space.

Z_UV -> UV map in image space; Z_Ni, Z_Ai -> N_i, A_i in UV space through ONE decoder (the
N_i and A_i decoders share weights, Sec. 4.1); the image-space normal and albedo are N_i, A_i
sampled at the predicted UV (bilinear grid_sample).  Shading, formation and matting as in
:class:`~disent.models.explicit.Explicit`.

UV convention (that of the data): ``uv[:,0] = u`` is the horizontal coordinate and
``uv[:,1] = v`` the vertical one of the UV maps, both in [0,1] from the first to the last
texel centre (``align_corners=True``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from disent.models.explicit import Explicit, decode_normal
from disent.models.networks import Decoder
from disent.render import unit


def sample_uv(uv_map: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Look up ``uv_map [B,C,h,w]`` at ``uv [B,2,H,W]`` (in [0,1]) -> ``[B,C,H,W]``."""
    grid = uv.permute(0, 2, 3, 1) * 2 - 1
    return F.grid_sample(uv_map, grid, mode="bilinear", padding_mode="border", align_corners=True)


class Implicit(Explicit):
    CODE_NAMES = ("bg", "m", "L", "UV", "Ni", "Ai")

    def build_foreground(self, resolution, code_dim):
        self.dec_UV = Decoder(2, resolution, code_dim, layers=self.layers)
        self.dec_NA = Decoder(3, resolution, code_dim, layers=self.layers)  # shared by N_i and A_i

    def decode_foreground(self, codes: dict) -> dict:
        B = codes["Ni"].shape[0]
        uv = torch.sigmoid(self.dec_UV(codes["UV"]))
        na = self.dec_NA(torch.cat([codes["Ni"], codes["Ai"]]))  # one pass, shared weights
        normal_uv, albedo_uv = decode_normal(na[:B], self.normal_param), torch.sigmoid(na[B:])
        return {
            "uv": uv,
            "normal_uv": normal_uv,
            "albedo_uv": albedo_uv,
            "normal": unit(sample_uv(normal_uv, uv)),
            "albedo": sample_uv(albedo_uv, uv),
        }

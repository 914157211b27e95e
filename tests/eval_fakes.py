"""A tiny analytic stand-in for SynthFaces (same item keys) so evaluation code is tested on its own.

The "face" is the front cap (within 70 degrees of the head's forward axis) of a unit sphere
seen orthographically; yaw turns the head, so at profile the visible cap shrinks to a sliver
of normals.  Albedo is a per-identity colour with a horizontal ramp; lights come from a fixed
bank of directional lights (``light_id``) on the ``lightbank`` split.  The pseudo normals are
the true ones bent towards +z, as a coarse fit would be.
"""

import math

import torch

from disent.render import composite, sh_from_directions, sh_shading

N_LIGHTS, N_IDENT, POSES = 4, 3, (-20.0, 0.0, 20.0)


def _bank():
    g = torch.Generator().manual_seed(1)
    d = torch.randn(N_LIGHTS, 1, 3, generator=g)
    d[..., 2] = d[..., 2].abs() + 0.5  # from the camera side
    d[..., 1] = d[..., 1].abs()  # from above
    return sh_from_directions(d, torch.full((N_LIGHTS, 1, 3), 0.7), ambient=0.35)  # [K,3,9]


class FakeFaces(torch.utils.data.Dataset):
    def __init__(self, split="test", resolution=16, seed=0, size=None, effects=None):
        self.split, self.res, self.seed, self.effects = split, resolution, seed, dict(effects or {})
        self.bank = _bank()
        self.n = N_LIGHTS * N_IDENT * len(POSES) if split == "lightbank" else (size or 24)

    def __len__(self):
        return self.n

    def _params(self, index):
        if self.split == "lightbank":
            light, rest = divmod(index, N_IDENT * len(POSES))
            ident, pose = divmod(rest, len(POSES))
            return light, ident, POSES[pose]
        return -1, index % 7, float((index * 13) % 61 - 30)

    def __getitem__(self, index):
        return self.sample(index)

    def sample(self, index, pose=None, sh=None, effects=None):
        light, ident, yaw = self._params(index)
        if pose is not None:
            yaw = float(torch.as_tensor(pose)[0])
        g = torch.Generator().manual_seed(1000 * self.seed + index)
        if sh is None:
            sh = (
                self.bank[light] if light >= 0 else _bank()[index % N_LIGHTS] * (0.8 + 0.4 * torch.rand(1, generator=g))
            )
        H = W = self.res
        v, u = torch.meshgrid(torch.linspace(1, -1, H), torch.linspace(-1, 1, W), indexing="ij")
        r2 = u * u + v * v
        nz = (1 - r2).clamp_min(0).sqrt()
        normal = torch.stack([u, v, nz])
        a = math.radians(yaw)  # head forward axis after the yaw
        fwd = torch.tensor([math.sin(a), 0.0, math.cos(a)])
        matte = ((r2 < 0.95) & (torch.einsum("chw,c->hw", normal, fwd) > math.cos(math.radians(70)))).float()[None]
        normal = normal * matte
        bent = torch.nn.functional.normalize(normal + 0.3 * torch.tensor([0, 0, 1.0])[:, None, None], dim=0) * matte
        cg = torch.Generator().manual_seed(ident)
        albedo = (0.4 + 0.4 * torch.rand(3, 1, 1, generator=cg)) * (0.85 + 0.15 * u)[None].expand(3, -1, -1)
        shading = sh_shading(normal[None], sh[None].float())[0]
        bg = 0.2 + 0.6 * torch.rand(3, 1, 1, generator=g).expand(3, H, W)
        image = composite(matte, albedo * shading, bg)
        noise = (effects or self.effects).get("noise", 0.0)
        if noise:
            image = image + 0.1 * noise * torch.randn(image.shape, generator=g)
        return {
            "image": image.float(),
            "background": bg,
            "matte": matte,
            "normal": normal,
            "albedo": albedo * matte,
            "shading": shading * matte,
            "sh": sh.float(),
            "normal_pseudo": bent,
            "mask_pseudo": matte.clone(),
            "mask_face": matte * (r2 < 0.6),  # the skin a 3DMM covers: the head less its rim
            "sh_pseudo": sh.float(),
            "light_id": torch.tensor(light),
            "identity": torch.tensor(ident),
            "pose": torch.tensor([yaw, 0.0, 0.0]),
        }


class OracleModel(torch.nn.Module):
    """Returns ground truth rendered for the image's own item (looked up by pixel equality): a perfect model."""

    def __init__(self, dataset):
        super().__init__()
        self.items = [dataset[i] for i in range(len(dataset))]

    def forward(self, image):
        outs = []
        for im in image:
            it = next(i for i in self.items if torch.equal(i["image"], im))
            outs.append(
                {
                    "recon": it["image"],
                    "albedo": it["albedo"],
                    "normal": it["normal"],
                    "shading": it["shading"],
                    "sh": it["sh"],
                    "matte": it["matte"],
                }
            )
        return {k: torch.stack([o[k] for o in outs]) for k in outs[0]}

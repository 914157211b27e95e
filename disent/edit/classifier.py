"""A small CNN that reads what an edit should and should not change, trained on SynthFaces truth.

``MeasureNet(image)`` returns

* ``attr_logits [B,4]``: smiling, beard, eyeglasses, senior (edit **success**);
* ``sh [B,3,9]`` and ``pose [B,3]`` (yaw, pitch, roll in degrees): lighting and pose
  estimates in the data's units (edit **leakage**);
* ``embedding [B,E]``: unit-norm identity embedding, trained by a cosine classifier over the
  training identities (identity leakage); absent when trained without identities.

It is independent of the face models being measured: it never sees their codes.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from disent.edit.traversal import ATTRIBUTES


class MeasureNet(nn.Module):
    def __init__(self, resolution: int = 64, width: int = 16, n_identities: int = 0, embed_dim: int = 32):
        super().__init__()
        self.resolution, self.n_identities = resolution, n_identities
        chans = [3, width, 2 * width, 4 * width, 4 * width]
        layers = []
        for cin, cout in zip(chans[:-1], chans[1:]):  # four stride-2 blocks: 64 -> 4
            layers += [nn.Conv2d(cin, cout, 3, 2, 1), nn.BatchNorm2d(cout), nn.ReLU()]
        self.features = nn.Sequential(*layers, nn.AdaptiveAvgPool2d(2), nn.Flatten())
        F_dim = 4 * chans[-1]
        self.attrs = nn.Linear(F_dim, len(ATTRIBUTES))
        self.light_pose = nn.Linear(F_dim, 27 + 3)
        self.embed = nn.Linear(F_dim, embed_dim) if n_identities else None
        self.id_classes = nn.Parameter(torch.randn(n_identities, embed_dim) * 0.1) if n_identities else None
        # targets are standardised for training; outputs come back in the data's units
        self.register_buffer("target_mean", torch.zeros(30))
        self.register_buffer("target_std", torch.ones(30))

    def forward(self, image: torch.Tensor) -> dict:
        if image.dim() != 4 or image.shape[1] != 3:
            raise ValueError(f"image must be [B,3,H,W], got {tuple(image.shape)}")
        h = self.features(image)
        lp = self.light_pose(h) * self.target_std + self.target_mean
        out = {"attr_logits": self.attrs(h), "sh": lp[:, :27].reshape(-1, 3, 9), "pose": lp[:, 27:]}
        if self.embed is not None:
            out["embedding"] = F.normalize(self.embed(h), dim=1)
        return out


def fit_measure_net(images: torch.Tensor, attrs: torch.Tensor, sh: torch.Tensor, pose: torch.Tensor,
                    identity: torch.Tensor | None = None, steps: int = 1500, batch_size: int = 64,
                    lr: float = 2e-3, width: int = 16, seed: int = 0, log_every: int = 0) -> MeasureNet:
    """Train a :class:`MeasureNet` on ``images [N,3,H,W]`` with their true ``attrs [N,4]`` (0/1),
    ``sh [N,3,9]``, ``pose [N,3]`` and (optionally) ``identity [N]`` integer labels.

    Loss: BCE on the attributes + MSE on the standardised light and pose + cosine-softmax
    cross-entropy on the identities (scale 16).  Adam, cosine learning-rate decay, flips off
    (a flip would change the pose and light).
    """
    N = len(images)
    if not (len(attrs) == len(sh) == len(pose) == N):
        raise ValueError("images, attrs, sh and pose must have the same length")
    torch.manual_seed(seed)
    ids = None
    if identity is not None:
        _, ids = torch.unique(identity, return_inverse=True)
    net = MeasureNet(images.shape[-1], width, int(ids.max()) + 1 if ids is not None else 0)
    target = torch.cat([sh.reshape(N, 27), pose], 1).float()
    net.target_mean.copy_(target.mean(0))
    net.target_std.copy_(target.std(0).clamp_min(1e-6))
    z_target = (target - net.target_mean) / net.target_std
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    g = torch.Generator().manual_seed(seed)
    net.train()
    for step in range(steps):
        idx = torch.randint(0, N, (batch_size,), generator=g)
        h = net.features(images[idx])
        loss = F.binary_cross_entropy_with_logits(net.attrs(h), attrs[idx].float())
        loss = loss + F.mse_loss(net.light_pose(h), z_target[idx])
        if ids is not None:
            e = F.normalize(net.embed(h), dim=1)
            loss = loss + F.cross_entropy(16 * e @ F.normalize(net.id_classes, dim=1).T, ids[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if log_every and (step % log_every == 0 or step == steps - 1):
            print(f"measure-net step {step:5d}  loss {loss.item():.4f}", flush=True)
    return net.eval()


@torch.no_grad()
def measure_accuracy(net: MeasureNet, images, attrs, sh, pose, identity=None, batch_size: int = 128) -> dict:
    """Held-out quality of the measuring net: attribute accuracy, light RMSE, pose MAE (deg),
    and, with identities, the same-vs-different identity embedding distance gap."""
    outs = [net(images[i:i + batch_size]) for i in range(0, len(images), batch_size)]
    out = {k: torch.cat([o[k] for o in outs]) for k in outs[0]}
    acc = ((out["attr_logits"] > 0).float() == attrs.float()).float().mean(0)
    res = {f"acc_{a}": acc[i].item() for i, a in enumerate(ATTRIBUTES)}
    res["sh_rmse"] = (out["sh"] - sh).pow(2).mean().sqrt().item()
    res["sh_std"] = sh.std(0).pow(2).mean().sqrt().item()
    res["pose_mae_deg"] = (out["pose"] - pose).abs().mean().item()
    res["pose_std_deg"] = pose.std(0).mean().item()
    if identity is not None and "embedding" in out:
        d = torch.cdist(out["embedding"], out["embedding"])
        same = identity[:, None] == identity[None]
        off = ~torch.eye(len(identity), dtype=torch.bool)
        res["id_dist_same"] = d[same & off].mean().item() if (same & off).any() else math.nan
        res["id_dist_diff"] = d[~same].mean().item()
    return res


def save_measure_net(net: MeasureNet, path, info: dict | None = None) -> None:
    torch.save({"state": net.state_dict(), "resolution": net.resolution, "width": net.features[0].out_channels,
                "n_identities": net.n_identities, "embed_dim": net.embed.out_features if net.embed else 32,
                "info": info or {}}, path)


def load_measure_net(path) -> MeasureNet:
    ck = torch.load(path, map_location="cpu", weights_only=False)
    net = MeasureNet(ck["resolution"], ck["width"], ck["n_identities"], ck["embed_dim"])
    net.load_state_dict(ck["state"])
    return net.eval()

"""A small CNN that reads what an edit should and should not change, trained on SynthFaces truth.

``MeasureNet(image)`` returns

* ``attr_logits [B,4]``: smiling, beard, eyeglasses, senior (edit **success**);
* ``sh [B,3,9]`` and ``pose [B,3]`` (yaw, pitch, roll in degrees): lighting and pose
  estimates in the data's units (edit **leakage**);
* ``identity [B,D]``: the generator's identity parameters (face shape coefficients and skin
  colour), each standardised over the training set (identity leakage); absent when trained
  without them.

It is independent of the face models being measured: it never sees their codes.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from disent.edit.traversal import ATTRIBUTES


class MeasureNet(nn.Module):
    def __init__(self, resolution: int = 64, width: int = 24, identity_dim: int = 0):
        super().__init__()
        self.resolution, self.identity_dim = resolution, identity_dim
        chans = [width, width, 2 * width, 4 * width, 4 * width]
        layers = [nn.Conv2d(3, width, 3, 1, 1), nn.BatchNorm2d(width), nn.ReLU()]  # full-resolution stem
        for cin, cout in zip(chans[:-1], chans[1:]):  # four stride-2 blocks: 64 -> 4
            layers += [nn.Conv2d(cin, cout, 3, 2, 1), nn.BatchNorm2d(cout), nn.ReLU()]
        self.features = nn.Sequential(*layers, nn.AdaptiveAvgPool2d(4), nn.Flatten())
        F_dim = 16 * chans[-1]
        self.attrs = nn.Linear(F_dim, len(ATTRIBUTES))
        self.regress = nn.Linear(F_dim, 27 + 3 + identity_dim)  # light, pose, identity
        # targets are standardised for training; light and pose come back in the data's units
        self.register_buffer("target_mean", torch.zeros(30 + identity_dim))
        self.register_buffer("target_std", torch.ones(30 + identity_dim))

    def forward(self, image: torch.Tensor) -> dict:
        if image.dim() != 4 or image.shape[1] != 3:
            raise ValueError(f"image must be [B,3,H,W], got {tuple(image.shape)}")
        h = self.features(image)
        z = self.regress(h)
        lp = z[:, :30] * self.target_std[:30] + self.target_mean[:30]
        out = {"attr_logits": self.attrs(h), "sh": lp[:, :27].reshape(-1, 3, 9), "pose": lp[:, 27:30]}
        if self.identity_dim:
            out["identity"] = z[:, 30:]  # in standard deviations of the training set
        return out


def fit_measure_net(
    images: torch.Tensor,
    attrs: torch.Tensor,
    sh: torch.Tensor,
    pose: torch.Tensor,
    identity: torch.Tensor | None = None,
    steps: int = 1500,
    batch_size: int = 64,
    lr: float = 2e-3,
    width: int = 24,
    seed: int = 0,
    log_every: int = 0,
) -> MeasureNet:
    """Train a :class:`MeasureNet` on ``images [N,3,H,W]`` with their true ``attrs [N,4]`` (0/1),
    ``sh [N,3,9]``, ``pose [N,3]`` and (optionally) ``identity [N,D]`` identity parameters.

    Loss: 2 x BCE on the attributes + MSE on the standardised light, pose and identity.  Adam,
    cosine learning-rate decay, no flips (a flip would change the pose and light).
    """
    N = len(images)
    if not (len(attrs) == len(sh) == len(pose) == N) or (identity is not None and len(identity) != N):
        raise ValueError("images, attrs, sh, pose (and identity) must have the same length")
    torch.manual_seed(seed)
    parts = [sh.reshape(N, 27), pose] + ([identity.reshape(N, -1)] if identity is not None else [])
    target = torch.cat(parts, 1).float()
    net = MeasureNet(images.shape[-1], width, target.shape[1] - 30)
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
        loss = 2 * F.binary_cross_entropy_with_logits(net.attrs(h), attrs[idx].float())
        loss = loss + F.mse_loss(net.regress(h), z_target[idx])
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
    and the identity RMSE in training standard deviations (1 = no better than the mean)."""
    outs = [net(images[i : i + batch_size]) for i in range(0, len(images), batch_size)]
    out = {k: torch.cat([o[k] for o in outs]) for k in outs[0]}
    acc = ((out["attr_logits"] > 0).float() == attrs.float()).float().mean(0)
    res = {f"acc_{a}": acc[i].item() for i, a in enumerate(ATTRIBUTES)}
    res["sh_rmse"] = (out["sh"] - sh).pow(2).mean().sqrt().item()
    res["sh_std"] = sh.std(0).pow(2).mean().sqrt().item()
    res["pose_mae_deg"] = (out["pose"] - pose).abs().mean().item()
    res["pose_std_deg"] = pose.std(0).mean().item()
    if identity is not None and "identity" in out:
        z = (identity.reshape(len(identity), -1) - net.target_mean[30:]) / net.target_std[30:]
        res["identity_rmse_std"] = (out["identity"] - z).pow(2).mean().sqrt().item()
    return res


def save_measure_net(net: MeasureNet, path, info: dict | None = None) -> None:
    torch.save(
        {
            "state": net.state_dict(),
            "resolution": net.resolution,
            "width": net.features[0].out_channels,
            "identity_dim": net.identity_dim,
            "info": info or {},
        },
        path,
    )


def load_measure_net(path) -> MeasureNet:
    ck = torch.load(path, map_location="cpu", weights_only=False)
    net = MeasureNet(ck["resolution"], ck["width"], ck["identity_dim"])
    net.load_state_dict(ck["state"])
    return net.eval()

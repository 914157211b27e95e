"""Face editing by latent manifold traversal (Sec. 5.2 and the supplement).

An attribute is given by two pools of images, with (``positives``) and without it
(``negatives``), encoded to Z-codes.  A source code ``z0`` is moved on the chosen
manifolds only (``Z_UV``, ``Z_Ni``, ...); every other code is kept, so the decoder
renders the same pose, light and background.

Two traversals:

* **Deep Manifold Traversal** (Gardner et al. 2015, the method the paper cites)::

      z* = argmin_z  mean_s k(z, x_s) - mean_t k(z, x_t) + lam * |z - z0|^2 / (2 sigma^2)

  the MMD witness between the source set (the side ``z0`` starts on) and the target set,
  evaluated at the moving point, plus a pull back to ``z0``.  ``k`` is the RBF kernel
  ``exp(-|a - b|^2 / (2 sigma^2))`` with ``sigma`` chosen so that the mean kernel value
  over the pooled codes is 0.5 (the value Gardner et al. aim at).

  **Scale of lambda.**  The pull is written in kernel units, ``|z - z0|^2 / (2 sigma^2)``,
  so ``lam`` does not depend on how large a manifold's codes happen to be; a raw-unit
  penalty ``lam_raw |z - z0|^2`` (Gardner et al.'s form) is the same objective with
  ``lam_raw = lam / (2 sigma^2)``.  The paper's figures use lam = 0.01..0.07 without
  saying in which units its features were; we read them on this kernel scale, where the
  same range runs from "well into the target mode" (0.01) to "a small step" (0.07).
  Smaller ``lam`` moves further.
* **Barycenter traversal** (what the authors' public release does):
  ``z0 + alpha * (mean positives - mean negatives)``.

The defaults for which manifolds carry an attribute are the paper's (:data:`DEFAULT_MANIFOLDS`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from disent.data.attributes import ATTRIBUTES

# The paper's choice of manifolds per attribute (Sec. 5.2, supplement); explicit model: Ae, Ne.
DEFAULT_MANIFOLDS = {
    "implicit": {"smiling": ("UV", "Ni"), "beard": ("Ai",), "eyeglasses": ("Ai",), "senior": ("Ai", "Ni", "UV")},
    "explicit": {"smiling": ("Ae", "Ne"), "beard": ("Ae",), "eyeglasses": ("Ae",), "senior": ("Ae", "Ne")},
    "baseline": {a: ("z",) for a in ATTRIBUTES},
}
# Codes that describe the face itself (the ones a traversal may move); L, bg and m never are.
FACE_CODES = {"implicit": ("UV", "Ni", "Ai"), "explicit": ("Ne", "Ae"), "baseline": ("z",)}


def model_kind(codes: dict) -> str:
    """``implicit`` / ``explicit`` / ``baseline`` from the code names (see the models' contract)."""
    if "UV" in codes:
        return "implicit"
    if "Ae" in codes:
        return "explicit"
    if "z" in codes:
        return "baseline"
    raise ValueError(f"unknown code layout {sorted(codes)}: expected UV/Ni/Ai, Ae/Ne or z")


def default_manifolds(codes: dict, attribute: str) -> tuple[str, ...]:
    if attribute not in ATTRIBUTES:
        raise ValueError(f"unknown attribute {attribute!r}; choose from {ATTRIBUTES}")
    return DEFAULT_MANIFOLDS[model_kind(codes)][attribute]


# ----------------------------------------------------------------------------- kernel
def sq_dists(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Squared Euclidean distances ``[N,D] x [M,D] -> [N,M]`` (clamped at 0)."""
    return (x.pow(2).sum(1, keepdim=True) - 2 * x @ y.T + y.pow(2).sum(1)[None]).clamp_min(0)


def rbf_kernel(x: torch.Tensor, y: torch.Tensor, sigma: float) -> torch.Tensor:
    """``k(a, b) = exp(-|a - b|^2 / (2 sigma^2))`` for all pairs, ``[N,M]``."""
    return torch.exp(-sq_dists(x, y) / (2 * sigma**2))


def choose_bandwidth(codes: torch.Tensor, mean_kernel: float = 0.5, iters: int = 100) -> float:
    """``sigma`` with mean off-diagonal kernel value ``mean_kernel`` over ``codes [N,D]``.

    The mean kernel value rises monotonically with ``sigma``; bisection on ``log sigma``.
    """
    if codes.dim() != 2 or codes.shape[0] < 2:
        raise ValueError(f"choose_bandwidth needs codes [N>=2, D], got {tuple(codes.shape)}")
    if not 0 < mean_kernel < 1:
        raise ValueError(f"mean_kernel must lie in (0, 1), got {mean_kernel}")
    d2 = sq_dists(codes.double(), codes.double())
    d2 = d2[~torch.eye(len(codes), dtype=torch.bool)]
    if not (d2 > 0).any():
        raise ValueError("choose_bandwidth: all codes are identical")
    scale = d2[d2 > 0].median().sqrt().item()
    lo, hi = math.log(scale) - 20, math.log(scale) + 20
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if torch.exp(-d2 / (2 * math.exp(mid) ** 2)).mean() < mean_kernel:
            lo = mid
        else:
            hi = mid
    return math.exp(0.5 * (lo + hi))


def witness(z: torch.Tensor, source: torch.Tensor, target: torch.Tensor, sigma: float) -> torch.Tensor:
    """MMD witness at ``z [B,D]``: mean similarity to ``source`` minus mean to ``target``, ``[B]``."""
    return rbf_kernel(z, source, sigma).mean(1) - rbf_kernel(z, target, sigma).mean(1)


# ----------------------------------------------------------------------------- traversals
def dmt(
    z0: torch.Tensor,
    source: torch.Tensor,
    target: torch.Tensor,
    lam: float,
    sigma: float | None = None,
    max_iter: int = 200,
) -> torch.Tensor:
    """Deep Manifold Traversal of each row of ``z0 [B,D]`` from ``source`` towards ``target``.

    Minimises ``witness(z) + lam |z - z0|^2 / (2 sigma^2)`` by L-BFGS from ``z0`` (the rows are
    independent problems, solved jointly since the objective is their sum).  ``lam = inf``
    returns ``z0``.
    """
    if any(t.dim() != 2 for t in (z0, source, target)) or not (z0.shape[1] == source.shape[1] == target.shape[1]):
        raise ValueError(
            f"dmt needs z0 [B,D], source [N,D], target [M,D]; got {tuple(z0.shape)}, "
            f"{tuple(source.shape)}, {tuple(target.shape)}"
        )
    if not lam > 0:
        raise ValueError(f"lam must be > 0 (smaller moves further), got {lam}")
    if math.isinf(lam):
        return z0.clone()
    if sigma is None:
        sigma = choose_bandwidth(torch.cat([source, target]))
    S, T, Z0 = source.double(), target.double(), z0.detach().double()
    z = Z0.clone().requires_grad_(True)
    opt = torch.optim.LBFGS(
        [z],
        lr=1,
        max_iter=max_iter,
        tolerance_grad=1e-12,
        tolerance_change=1e-15,
        history_size=20,
        line_search_fn="strong_wolfe",
    )

    def closure():
        opt.zero_grad()
        loss = (witness(z, S, T, sigma) + lam * (z - Z0).pow(2).sum(1) / (2 * sigma**2)).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return z.detach().to(z0.dtype)


def barycenter(z0: torch.Tensor, positives: torch.Tensor, negatives: torch.Tensor, alpha: float) -> torch.Tensor:
    """``z0 + alpha (mean positives - mean negatives)``; rows of ``z0 [B,D]``."""
    return z0 + alpha * (positives.mean(0) - negatives.mean(0)).to(z0.dtype)


# ----------------------------------------------------------------------------- pools
@dataclass
class AttributePool:
    """Flattened codes of the images with (``positives``) and without (``negatives``) an attribute,
    one ``[N, D]`` tensor per manifold name, and each manifold's kernel bandwidth."""

    attribute: str
    positives: dict[str, torch.Tensor]
    negatives: dict[str, torch.Tensor]
    sigma: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        for name in self.positives:
            if name not in self.sigma:
                self.sigma[name] = choose_bandwidth(torch.cat([self.positives[name], self.negatives[name]]))


@torch.no_grad()
def encode_pool(
    model, images: torch.Tensor, labels: torch.Tensor, attribute: str, batch_size: int = 64, extra_codes=()
) -> AttributePool:
    """Encode ``images [N,3,H,W]`` with ``model.encode`` and split the face codes (and ``extra_codes``, e.g.
    ``("bg",)``) by ``labels [N]`` (0/1)."""
    labels = torch.as_tensor(labels).flatten() > 0.5
    if len(labels) != len(images):
        raise ValueError(f"{len(images)} images but {len(labels)} labels")
    if labels.all() or not labels.any():
        raise ValueError(f"pool for {attribute!r} needs both positive and negative examples")
    chunks = [model.encode(images[i : i + batch_size]) for i in range(0, len(images), batch_size)]
    names = (*FACE_CODES[model_kind(chunks[0])], *extra_codes)
    codes = {n: torch.cat([c[n].flatten(1) for c in chunks]).float() for n in names}
    return AttributePool(attribute, {n: c[labels] for n, c in codes.items()}, {n: c[~labels] for n, c in codes.items()})


def traverse(
    codes: dict, pool: AttributePool, manifolds=None, method: str = "dmt", strength: float = 0.03, add: bool = True
) -> dict:
    """Codes with ``manifolds`` moved towards (``add``) or away from ``pool``'s attribute.

    ``method="dmt"``: ``strength`` is lambda (smaller moves further); ``"barycenter"``: it is alpha.
    Each manifold is moved independently (as in the paper); all other codes are returned unchanged.
    """
    manifolds = tuple(manifolds or default_manifolds(codes, pool.attribute))
    unknown = [m for m in manifolds if m not in pool.positives]
    if unknown:
        raise ValueError(f"manifolds {unknown} not in the pool (has {sorted(pool.positives)})")
    out = dict(codes)
    for name in manifolds:
        pos, neg = pool.positives[name], pool.negatives[name]
        source, target = (neg, pos) if add else (pos, neg)
        z0 = codes[name].flatten(1).float()
        if method == "dmt":
            z = dmt(z0, source, target, strength, pool.sigma[name])
        elif method == "barycenter":
            z = barycenter(z0, target, source, strength)
        else:
            raise ValueError(f"method must be 'dmt' or 'barycenter', got {method!r}")
        out[name] = z.reshape(codes[name].shape).to(codes[name].dtype)
    return out

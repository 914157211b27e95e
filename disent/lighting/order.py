"""A lighting model no larger than the scene needs: SH order 0/1/2, gray or RGB light.

Candidates for an RGB image (constant albedo a_c absorbed into the light, as in L-hat),
from the smallest:

* ``order0``: ambient L1 per channel (3 coefficients);
* ``order1_gray``: ``L_c = g_c * l`` with ``l`` in R^4 and ``g_1 = 1`` (4 + 2);
* ``order2_gray``: the same with ``l`` in R^9 (9 + 2);
* ``order1_rgb``: ``L_c`` free in R^4 per channel (12);
* ``order2_rgb``: ``L_c`` free in R^9 per channel (27).

"Gray" light has one colour for every direction, so with a constant albedo each channel is
a scaled copy of one SH light (rank one); RGB light may change colour with direction.  For a
one-channel image the candidates are order0, order1 and order2 (1, 4, 9).

Each model is scored, with i.i.d. Gaussian noise of unknown sigma, by
* BIC = -2 log p(y | theta_hat, sigma_hat) + (d + 1) log N, and
* the log evidence by a Laplace approximation at the MAP of (theta, log sigma) with the
  priors of :mod:`disent.lighting.posterior` (coefficients ``N(0, prior_scale^2)``, gray gains
  ``N(1, 1)``, log sigma uniform on ``[log 1e-4, 0]``) and the Gauss-Newton Hessian; the
  positivity constraint is ignored here.

On pseudo geometry (the coarse fit's normals) the misfit is not i.i.d.: a normal off by ``delta n``
moves a pixel by ``a (grad_n S) . delta n``.  With ``normal_sigma`` (the per-axis std of the normal error
in the tangent plane, radians) each pixel's variance becomes ``sigma^2 + normal_sigma^2 |a P_t grad_n S|^2``,
evaluated at the candidate's own light (iteratively reweighted Gauss-Newton), so misfit that the geometry
error explains is not taken as evidence for more SH terms.  Default 0: the i.i.d. model.

The misfit that a texture model and pseudo geometry leave is also spatially correlated (a wrong brow or
nose moves neighbouring pixels together), so i.i.d. noise over ~2,000 pixels overstates the evidence that
a smooth extra SH term buys.  ``residual = (rho, ell)`` models it as a residual process: per channel the
noise covariance is ``sigma^2 (I + rho K)``, ``K(p, q) = exp(-|p - q| / ell)`` over pixel distance, and the
likelihood is computed after whitening with its Cholesky factor (:func:`residual_whitener`).  ``rho, ell``
come from maximum likelihood on training scenes' residuals at their true light
(:func:`disent.lighting.experiments.fit_residual_process`).

The choice is the smallest model whose score is within ``threshold`` (log units, default
log 20, "strong" evidence on Kass & Raftery's scale) of the best one.

With a constant albedo, textured albedo (eyes, brows, lips, hair, beard) leaves a structured
misfit that the i.i.d. noise model explains with extra SH terms (order 2 is chosen for most
scenes).  Without a known albedo, pass ``texture`` (:mod:`disent.lighting.texture`): each
candidate is then fitted with its own albedo from a PCA texture model (coefficients under
their PCA prior), so the texture is explained by the albedo and not by the light.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from disent.lighting.posterior import LOG_SIGMA_RANGE, N_COEFFS, LightingData

DEFAULT_THRESHOLD = math.log(20.0)


def candidates(n_channels: int) -> list[tuple[str, int, bool]]:
    """``(name, order, gray)`` from the smallest model to the largest."""
    if n_channels == 1:
        return [("order0", 0, False), ("order1", 1, False), ("order2", 2, False)]
    models = [
        ("order0", 0, False),
        ("order1_gray", 1, True),
        ("order2_gray", 2, True),
        ("order1_rgb", 1, False),
        ("order2_rgb", 2, False),
    ]
    return sorted(models, key=lambda m: n_params(m[1], m[2], n_channels))


def n_params(order: int, gray: bool, n_channels: int) -> int:
    K = N_COEFFS[order]
    return K + n_channels - 1 if gray and order > 0 else K * n_channels


def _predict(theta, A, gray):
    """Pixels ``[P, C]`` and the Jacobian ``[C*P, d]`` (channel-major rows) of a candidate.

    ``A [C, P, K]`` is the design (:meth:`LightingData.design`)."""
    C, P, K = A.shape
    if not gray:
        L = theta.reshape(C, K)
        J = np.zeros((C, P, C, K))
        for c in range(C):
            J[c, :, c] = A[c]
        return np.einsum("cpk,ck->pc", A, L), J.reshape(C * P, C * K)
    l, g = theta[:K], np.concatenate([[1.0], theta[K:]])
    s = A @ l  # [C, P]: the one light through each channel's design
    J = np.zeros((C, P, K + C - 1))
    for c in range(C):
        J[c, :, :K] = g[c] * A[c]
        if c > 0:
            J[c, :, K + c - 1] = s[c]
    return (s * g[:, None]).T, J.reshape(C * P, K + C - 1)


def sh_basis_gradient(n: np.ndarray, K: int = 9) -> np.ndarray:
    """``[P, K, 3]``: d Y_k / d n of :func:`disent.render.sh_basis` at unit normals ``n [P, 3]``."""
    from disent.render import C1, C2, C3

    nx, ny, nz = n.T
    z = np.zeros_like(nx)
    g = np.zeros((len(n), 9, 3))
    g[:, 1, 1] = g[:, 2, 2] = g[:, 3, 0] = 2 * C2
    g[:, 4] = np.stack([2 * C1 * ny, 2 * C1 * nx, z], 1)
    g[:, 5] = np.stack([z, 2 * C1 * nz, 2 * C1 * ny], 1)
    g[:, 6] = np.stack([z, z, 2 * C3 * nz], 1)
    g[:, 7] = np.stack([2 * C1 * nz, z, 2 * C1 * nx], 1)
    g[:, 8] = np.stack([2 * C1 * nx, -2 * C1 * ny, z], 1)
    return g[:, :K]


def geometry_variance(data: LightingData, light: np.ndarray, normal_sigma: float) -> np.ndarray:
    """``[C*P]`` (channel-major): the variance a normal error of per-axis std ``normal_sigma`` adds to each
    pixel under ``light [C, K]``: ``normal_sigma^2 |a P_t grad_n S(n; L_c)|^2``."""
    from disent.render import C2

    K = light.shape[1]
    albedo = data.albedo if data.albedo is not None else np.ones_like(data.y)
    n = data.basis[:, [3, 1, 2]] / (2 * C2)  # the basis holds 2 C2 (n_y, n_z, n_x) at indices 1-3
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    grad = np.einsum("pkj,ck->pcj", sh_basis_gradient(n, K), light) * albedo[:, :, None]  # [P, C, 3]
    tangent = grad - (grad * n[:, None]).sum(-1, keepdims=True) * n[:, None]
    return (normal_sigma**2 * (tangent**2).sum(-1)).T.reshape(-1)


def residual_whitener(data: LightingData, rho: float, ell: float):
    """``whiten(x)`` for ``x [P, ...]`` (pixels first): ``Lc^-1 x`` with ``Lc Lc^T = I + rho K``, the residual
    process's correlation over ``data``'s pixels (``K(p, q) = exp(-|p - q| / ell)``, distance in pixels), and
    ``log det(I + rho K)`` (per channel)."""
    from scipy.linalg import solve_triangular

    r, c = np.divmod(data.index, data.shape[1])
    dist = np.hypot(r[:, None] - r[None], c[:, None] - c[None])
    Lc = np.linalg.cholesky(np.eye(len(dist)) + rho * np.exp(-dist / ell))

    def whiten(x):
        return solve_triangular(Lc, x.reshape(len(x), -1), lower=True).reshape(x.shape)

    return whiten, 2 * np.log(np.diag(Lc)).sum()


def _initial(A, y, gray):
    """Least squares per channel; for gray light, channel 0's light and the channels' gains."""
    L = np.stack([np.linalg.lstsq(A[c], y[:, c], rcond=None)[0] for c in range(A.shape[0])])  # [C, K]
    if not gray:
        return L.reshape(-1)
    return np.concatenate([L[0], L[1:] @ L[0] / (L[0] @ L[0])])


def _light(theta, C, K, gray):
    if not gray:
        return theta.reshape(C, K)
    return np.concatenate([[1.0], theta[K:]])[:, None] * theta[None, :K]


def _fit(
    data: LightingData,
    order: int,
    gray: bool,
    prior_scale: float,
    iterations: int | None,
    normal_sigma: float = 0.0,
    whiten=None,
):
    """MAP of one candidate by (reweighted) Gauss-Newton, sigma at its conditional mode:
    ``(theta, pred, J, v, prior)`` with ``v [C*P]`` each value's noise variance.  With ``whiten``
    (:func:`residual_whitener`) the pixels and the design are whitened first, and ``pred``, ``J`` and ``v``
    are in whitened units."""
    A, y = data.design(order), data.y
    if whiten is not None:
        A, y = np.stack([whiten(a) for a in A]), whiten(y)
    N = y.size
    theta = _initial(A, y, gray)
    geometry = normal_sigma > 0
    iterations = iterations or (8 if gray or geometry else 2)  # linear i.i.d. models need one step per sigma update
    d = theta.size
    prior_mean = np.zeros(d)
    prior_prec = np.full(d, 1.0 / prior_scale**2)
    if gray:
        prior_mean[N_COEFFS[order] :], prior_prec[N_COEFFS[order] :] = 1.0, 1.0

    def variance(theta, r):
        if not geometry:
            return np.full(N, max(r @ r / N, 1e-300))
        extra = geometry_variance(data, _light(theta, A.shape[0], A.shape[2], gray), normal_sigma)
        lo, hi = 1e-300, max(r @ r / N, 1e-300)  # sigma^2 with sum (r^2 - v) / v^2 = 0 (the likelihood's stationarity)
        for _ in range(80):
            s2 = math.sqrt(lo * hi)
            v = s2 + extra
            lo, hi = (s2, hi) if ((r**2 - v) / v**2).sum() > 0 else (lo, s2)
        return s2 + extra

    for _ in range(iterations):  # Gauss-Newton on the log posterior, the noise at its conditional mode
        pred, J = _predict(theta, A, gray)
        r = (y - pred).T.reshape(-1)
        w = 1.0 / variance(theta, r)
        H = (J * w[:, None]).T @ J + np.diag(prior_prec)
        theta = theta + np.linalg.solve(H, (J * w[:, None]).T @ r - prior_prec * (theta - prior_mean))
    pred, J = _predict(theta, A, gray)
    r = (y - pred).T.reshape(-1)
    return theta, pred, J, variance(theta, r), (prior_mean, prior_prec)


def score(
    data: LightingData,
    order: int,
    gray: bool = False,
    prior_scale: float = 2.0,
    iterations: int | None = None,
    texture: tuple | None = None,
    texture_iterations: int = 10,
    normal_sigma: float = 0.0,
    residual: tuple | None = None,
    whitener: tuple | None = None,
) -> dict:
    """Maximised log-likelihood, BIC and Laplace log evidence of one candidate (``normal_sigma``: the
    geometry-error noise model of the module docstring; ``residual = (rho, ell)``: the residual process,
    whose ``residual_whitener(data, rho, ell)`` may be passed as ``whitener`` when already computed).

    ``texture = (pixels [1+J, P, C], variance [J])`` (:meth:`TextureModel.at_pixels` and
    its PCA variances): the albedo is ``T_0 + sum_j beta_j T_j`` with ``beta_j ~ N(0,
    variance_j)``, fitted by alternating least squares (``texture_iterations`` rounds); the
    evidence then adds beta's prior and its Laplace volume (block-diagonal Hessian).
    """
    C, K = data.n_channels, N_COEFFS[order]
    gray = gray and order > 0 and C > 1
    N = data.y.size
    if residual is not None and normal_sigma > 0:
        raise ValueError("choose one noise model: the residual process or the geometry noise (normal_sigma)")
    if residual is not None and whitener is None:
        whitener = residual_whitener(data, *residual)
    whiten, log_det = whitener if residual is not None else (None, 0.0)
    y = data.y if whiten is None else whiten(data.y)
    beta, extra = None, 0.0
    if texture is not None:
        tex, variance = texture
        if tex.shape[1:] != data.y.shape:
            raise ValueError(f"texture pixels {tex.shape[1:]} do not match the data {data.y.shape}")

        def albedo_of(beta):  # T_0 + sum_j beta_j T_j, kept positive
            return np.clip(tex[0] + np.einsum("j,jpc->pc", beta, tex[1:]), 1e-3, None)

        beta = np.zeros(len(variance))
        for _ in range(texture_iterations):
            albedo = albedo_of(beta)
            theta, pred, J, v, prior = _fit(
                replace(data, albedo=albedo), order, gray, prior_scale, iterations, normal_sigma, whiten
            )
            shading = data.basis[:, :K] @ _light(theta, C, K, gray).T  # [P, C]: the light through S(n, L_c)
            X, target = tex[1:] * shading[None], data.y - tex[0] * shading
            if whiten is not None:
                X, target = whiten(X.transpose(1, 0, 2)).transpose(1, 0, 2), whiten(target)
            X = X.reshape(len(variance), -1).T  # [P*C, J], pixel-major
            w = v.reshape(-1, data.n_pixels).T.reshape(-1)  # the noise variances in the same pixel-major order
            H_beta = (X / w[:, None]).T @ X + np.diag(1.0 / variance)
            beta = np.linalg.solve(H_beta, (X / w[:, None]).T @ target.reshape(-1))
        data = replace(data, albedo=albedo_of(beta))
        extra = (
            -0.5 * (beta**2 / variance).sum() - 0.5 * np.log(variance).sum() - 0.5 * np.linalg.slogdet(H_beta)[1]
        )  # log N(beta; 0, var) + J/2 log 2 pi - 1/2 log det H
    theta, pred, J, v, (prior_mean, prior_prec) = _fit(data, order, gray, prior_scale, iterations, normal_sigma, whiten)
    d = theta.size + (0 if beta is None else beta.size)
    r = (y - pred).T.reshape(-1)
    # i.i.d.: -N/2 (log 2 pi s2 + 1); whitened: the same less C/2 log det(I + rho K)
    loglik = -0.5 * (np.log(2 * math.pi * v) + r**2 / v).sum() - 0.5 * C * log_det
    H = (J / v[:, None]).T @ J + np.diag(prior_prec)
    log_prior = (
        -0.5 * (prior_prec * (theta - prior_mean) ** 2).sum()
        + 0.5 * np.log(prior_prec / (2 * math.pi)).sum()
        - math.log(LOG_SIGMA_RANGE[1] - LOG_SIGMA_RANGE[0])
    )
    # Laplace: log Z = log p(y, theta*, t*) + (d+1)/2 log 2 pi - 1/2 log det H; H_tt = 2N for t = log sigma
    log_evidence = (
        loglik
        + log_prior
        + 0.5 * (theta.size + 1) * math.log(2 * math.pi)
        - 0.5 * np.linalg.slogdet(H)[1]
        - 0.5 * math.log(2 * N)
        + extra
    )
    return {
        "order": order,
        "gray": gray,
        "n_params": d,
        "loglik": float(loglik),
        "sigma": float(math.sqrt(v.min())),
        "bic": float(-2 * loglik + (d + 1) * math.log(N)),
        "log_evidence": float(log_evidence),
        "light": _light(theta, C, K, gray).tolist(),
        "texture": None if beta is None else beta.tolist(),
    }


def select_order(
    data: LightingData,
    criterion: str = "evidence",
    threshold: float = DEFAULT_THRESHOLD,
    prior_scale: float = 2.0,
    texture: tuple | None = None,
    normal_sigma: float = 0.0,
    residual: tuple | None = None,
) -> dict:
    """Score every candidate; choose the smallest within ``threshold`` of the best.

    ``criterion``: ``"evidence"`` (Laplace log evidence) or ``"bic"`` (compared as -BIC/2,
    the same log units).  ``texture``: see :func:`score` (the albedo texture model, fitted per
    candidate); without it the albedo is constant (L-hat) or ``data``'s known albedo.
    Returns ``{"choice", "order", "gray", "scores"}``.
    """
    noise = {"normal_sigma": normal_sigma, "residual": residual}
    if residual is not None and normal_sigma == 0:  # one Cholesky factor for every candidate
        noise["whitener"] = residual_whitener(data, *residual)
    scores = {
        name: score(data, order, gray, prior_scale, texture=texture, **noise)
        for name, order, gray in candidates(data.n_channels)
    }
    return choose(scores, criterion, threshold)


def band2_share(light) -> float:
    """The energy of a light's order-2 SH coefficients over that of its orders 0 and 1 (``light [C, 9]``):
    what an order-2 fit puts in band 2, to set beside a true order-2 light's."""
    light = np.asarray(light, dtype=float)
    return float((light[:, 4:] ** 2).sum() / max((light[:, :4] ** 2).sum(), 1e-300))


def choose(scores: dict, criterion: str = "evidence", threshold: float = DEFAULT_THRESHOLD) -> dict:
    """The smallest candidate of ``scores`` (small-to-large, as :func:`select_order` builds it)
    whose score is within ``threshold`` of the best."""
    if criterion not in ("evidence", "bic"):
        raise ValueError(f"criterion must be 'evidence' or 'bic', got {criterion!r}")
    value = {k: s["log_evidence"] if criterion == "evidence" else -0.5 * s["bic"] for k, s in scores.items()}
    best = max(value.values())
    pick = next(k for k in scores if value[k] >= best - threshold)  # dicts keep the small-to-large order
    return {
        "choice": pick,
        "order": scores[pick]["order"],
        "gray": scores[pick]["gray"],
        "criterion": criterion,
        "scores": scores,
    }


__all__ = [
    "band2_share",
    "candidates",
    "n_params",
    "score",
    "select_order",
    "choose",
    "geometry_variance",
    "residual_whitener",
    "sh_basis_gradient",
    "DEFAULT_THRESHOLD",
]

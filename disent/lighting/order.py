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
noise correlation is ``R = (I + rho K) / (1 + rho)``, ``K(p, q) = exp(-|p - q| / ell)`` over pixel distance,
and the likelihood is computed after whitening with its Cholesky factor (:class:`Whitener`).  ``rho, ell``
come from maximum likelihood on training scenes' residuals at their true light
(:func:`disent.lighting.order_study.fit_residual_process`).

Both together: the covariance of channel ``c`` is ``V_c^1/2 R V_c^1/2`` with the marginal variances
``V = sigma^2 + normal_sigma^2 |a P_t grad_n S|^2`` (:func:`noise_variance`): the geometry sets how much each
pixel may miss, the residual process how the misses of neighbours go together.  Either alone is the special
case ``normal_sigma = 0`` or ``rho = 0``.

The misfit pseudo geometry leaves is also heavy-tailed: a misregistered eye or a wrong nose misses by far more than
the rest.  ``nu`` makes the whitened noise, in units of its scale, i.i.d. Student-t of ``nu`` degrees of freedom
(iteratively reweighted fit, Laplace evidence from the Fisher information), so that those pixels do not buy extra SH
terms.  Default None: Gaussian.

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
    """``[P, C]``: the variance a normal error of per-axis std ``normal_sigma`` adds to each
    pixel under ``light [C, K]``: ``normal_sigma^2 |a P_t grad_n S(n; L_c)|^2``."""
    from disent.render import C2

    K = light.shape[1]
    albedo = data.albedo if data.albedo is not None else np.ones_like(data.y)
    n = data.basis[:, [3, 1, 2]] / (2 * C2)  # the basis holds 2 C2 (n_y, n_z, n_x) at indices 1-3
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    grad = np.einsum("pkj,ck->pcj", sh_basis_gradient(n, K), light) * albedo[:, :, None]  # [P, C, 3]
    tangent = grad - (grad * n[:, None]).sum(-1, keepdims=True) * n[:, None]
    return normal_sigma**2 * (tangent**2).sum(-1)


class Whitener:
    """The residual process's correlation ``R = (I + rho K) / (1 + rho)`` over ``data``'s pixels (``K(p, q) =
    exp(-|p - q| / ell)``, distance in pixels) by its Cholesky factor ``Lc``: ``w(x)`` is ``Lc^-1 x`` for ``x [P, ...]``
    (pixels first), ``w.inverse(x)`` is ``R^-1 x`` and ``w.log_det`` is ``log det R``."""

    def __init__(self, data: LightingData, rho: float, ell: float):
        r, c = np.divmod(data.index, data.shape[1])
        dist = np.hypot(r[:, None] - r[None], c[:, None] - c[None])
        self.factor = np.linalg.cholesky((np.eye(len(dist)) + rho * np.exp(-dist / ell)) / (1 + rho))
        self.log_det = 2 * np.log(np.diag(self.factor)).sum()

    def _solve(self, x, trans: int):
        from scipy.linalg import solve_triangular

        return solve_triangular(self.factor, x.reshape(len(x), -1), lower=True, trans=trans).reshape(x.shape)

    def __call__(self, x):
        return self._solve(x, 0)

    def inverse(self, x):
        return self._solve(self._solve(x, 0), 1)


def noise_variance(r: np.ndarray, extra: np.ndarray | None = None, whiten: Whitener | None = None) -> np.ndarray:
    """``V [P, C]``: each value's marginal noise variance ``sigma^2 + extra`` for the residual ``r [P, C]``, with
    ``sigma^2`` at its maximum likelihood given the geometry's variance ``extra [P, C]`` (None: 0) and the residual
    process ``whiten`` (None: i.i.d.)."""
    mean_square = max(float((r**2).mean()), 1e-300)
    if extra is None:  # closed forms
        return np.full(r.shape, mean_square if whiten is None else max(float((whiten(r) ** 2).mean()), 1e-300))
    lo, hi = 1e-300, mean_square  # i.i.d.: sigma^2 with sum (r^2 - v) / v^2 = 0 (the likelihood's stationarity)
    for _ in range(80):
        s2 = math.sqrt(lo) * math.sqrt(hi)  # the geometric mean, without underflow
        v = s2 + extra
        lo, hi = (s2, hi) if ((r**2 - v) / v**2).sum() > 0 else (lo, s2)
    if whiten is None:
        return s2 + extra
    t = math.log(s2)  # correlated: Newton in log sigma^2 from the i.i.d. value, on
    for _ in range(20):  # f(t) = -1/2 sum log V - 1/2 |w(r / sqrt V)|^2, its curvature taken as i.i.d.'s
        v = math.exp(t) + extra
        curvature = 0.5 * ((math.exp(t) / v) ** 2).sum()
        if curvature == 0:  # sigma^2 vanishes beside the geometry's variance
            break
        grad = 0.5 * math.exp(t) * ((r / v**1.5 * whiten.inverse(r / np.sqrt(v))).sum() - (1 / v).sum())
        step = float(np.clip(grad / curvature, -1.0, 1.0))
        t += step
        if abs(step) < 1e-4:
            break
    return math.exp(t) + extra


def unit(x: np.ndarray, v: np.ndarray, whiten: Whitener | None = None) -> np.ndarray:
    """``x [P, C, ...]`` (residuals or their Jacobian) in units of its noise: divided by ``sqrt(v [P, C])`` and
    whitened by the residual process, so that the noise is i.i.d. N(0, 1)."""
    x = x / np.sqrt(v).reshape(v.shape + (1,) * (x.ndim - 2))
    return x if whiten is None else whiten(x)


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
    whiten: Whitener | None = None,
    nu: float | None = None,
):
    """MAP of one candidate by (reweighted) Gauss-Newton, sigma at its conditional mode:
    ``(theta, r, J, v, w, prior)``: the residual ``r [C*P]`` and its Jacobian ``J [C*P, d]`` (channel-major) in
    units of the noise (:func:`unit`: i.i.d. N(0, 1); with ``nu``, i.i.d. Student-t of ``nu`` degrees of freedom and
    unit scale), ``v [P, C]`` each value's marginal noise variance (scale squared) and ``w [C*P]`` each value's
    weight in the reweighted steps (1 for Gaussian noise)."""
    A, y = data.design(order), data.y
    C, P, K = A.shape
    theta = _initial(A, y, gray)
    geometry = normal_sigma > 0
    # linear i.i.d. models need one step per sigma update; reweighted ones (gray, geometry, Student-t) more
    iterations = iterations or (8 if gray or geometry or nu else 2)
    d = theta.size
    prior_mean = np.zeros(d)
    prior_prec = np.full(d, 1.0 / prior_scale**2)
    if gray:
        prior_mean[N_COEFFS[order] :], prior_prec[N_COEFFS[order] :] = 1.0, 1.0

    def linearised(theta):  # the residual, its Jacobian and the noise, all in units of the noise, channel-major
        pred, J = _predict(theta, A, gray)
        r = y - pred
        extra = geometry_variance(data, _light(theta, C, K, gray), normal_sigma) if geometry else None
        v = noise_variance(r, extra, whiten)
        J = J.reshape(C, P, d).transpose(1, 0, 2)  # [P, C, d]
        r, J = unit(r, v, whiten).T.reshape(-1), unit(J, v, whiten).transpose(1, 0, 2).reshape(C * P, d)
        if nu is None:
            return r, J, v, np.ones_like(r)
        scale = student_t_scale(r, nu)  # the t's scale, in units of the Gaussian noise
        r, J = r / scale, J / scale
        return r, J, v * scale**2, (nu + 1) / (nu + r**2)  # IRLS weights of the t likelihood

    for _ in range(iterations):  # (reweighted) Gauss-Newton on the log posterior, the noise at its conditional mode
        r, J, _, w = linearised(theta)
        Jw = J if nu is None else w[:, None] * J
        H = J.T @ Jw + np.diag(prior_prec)
        theta = theta + np.linalg.solve(H, Jw.T @ r - prior_prec * (theta - prior_mean))
    return theta, *linearised(theta), (prior_mean, prior_prec)


def student_t_scale(u: np.ndarray, nu: float, iterations: int = 30) -> float:
    """The maximum-likelihood scale ``s`` of i.i.d. Student-t values ``u`` (``nu`` degrees of freedom, location 0),
    by the EM fixed point ``s^2 = mean(w u^2)``, ``w = (nu + 1) / (nu + u^2 / s^2)``."""
    s2 = max(float((u**2).mean()), 1e-300)
    for _ in range(iterations):
        s2 = max(float(((nu + 1) / (nu + u**2 / s2) * u**2).mean()), 1e-300)
    return math.sqrt(s2)


def student_t_logpdf(u: np.ndarray, nu: float) -> np.ndarray:
    """``log t_nu(u)`` of the standard Student-t (location 0, scale 1)."""
    from scipy.special import gammaln

    return gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * math.log(nu * math.pi) - (nu + 1) / 2 * np.log1p(u**2 / nu)


def texture_albedo(tex: np.ndarray, beta) -> np.ndarray:
    """``[P, C]``: the texture model's albedo ``T_0 + sum_j beta_j T_j`` at the pixels ``tex [1+J, P, C]``
    (:meth:`~disent.lighting.texture.TextureModel.at_pixels`), kept positive."""
    return np.clip(tex[0] + np.einsum("j,jpc->pc", np.asarray(beta), tex[1:]), 1e-3, None)


def texture_coefficients(
    tex: np.ndarray,
    variance: np.ndarray,
    shading: np.ndarray,
    y: np.ndarray,
    v: np.ndarray,
    whiten=None,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(beta, H)``: the texture model's coefficients ``beta ~ N(0, variance)`` at their posterior mode for the image
    ``y [P, C] = (T_0 + sum_j beta_j T_j) * shading + noise`` (``tex [1+J, P, C]``, ``shading [P, C]``; noise of
    variance ``v [P, C]``, whitened by the residual process ``whiten``): ridge regression in units of the noise,
    each whitened value weighted by ``weights [P, C]`` where given (a Student-t's); and their posterior precision
    ``H``."""
    X = unit((tex[1:] * shading[None]).transpose(1, 2, 0), v, whiten).reshape(-1, len(variance))
    target = unit(y - tex[0] * shading, v, whiten).reshape(-1)
    if weights is not None:
        w = weights.reshape(-1)
        H = X.T @ (w[:, None] * X) + np.diag(1.0 / variance)
        return np.linalg.solve(H, X.T @ (w * target)), H
    H = X.T @ X + np.diag(1.0 / variance)
    return np.linalg.solve(H, X.T @ target), H


def _texture_fit(data, order, gray, prior_scale, iterations, texture, texture_iterations, normal_sigma, whiten, nu):
    """:func:`score`'s albedo from the texture model: ``beta`` by alternating least squares with the light, and
    what beta adds to the log evidence (its prior and its Laplace volume); returns ``(data with that albedo, beta,
    extra)``."""
    C, K = data.n_channels, N_COEFFS[order]
    tex, variance = texture
    if tex.shape[1:] != data.y.shape:
        raise ValueError(f"texture pixels {tex.shape[1:]} do not match the data {data.y.shape}")

    beta = np.zeros(len(variance))
    for _ in range(texture_iterations):
        albedo = texture_albedo(tex, beta)
        theta, _, _, v, w, _ = _fit(
            replace(data, albedo=albedo), order, gray, prior_scale, iterations, normal_sigma, whiten, nu
        )
        shading = data.basis[:, :K] @ _light(theta, C, K, gray).T  # [P, C]: the light through S(n, L_c)
        weights = None if nu is None else w.reshape(C, -1).T  # channel-major -> [P, C]
        beta, H_beta = texture_coefficients(tex, variance, shading, data.y, v, whiten, weights)
    if nu is not None:  # the Laplace volume from the Fisher information, as for the light below
        fisher = np.full(data.y.shape, (nu + 1) / (nu + 3))
        H_beta = texture_coefficients(tex, variance, shading, data.y, v, whiten, fisher)[1]
    data = replace(data, albedo=texture_albedo(tex, beta))
    extra = (
        -0.5 * (beta**2 / variance).sum() - 0.5 * np.log(variance).sum() - 0.5 * np.linalg.slogdet(H_beta)[1]
    )  # log N(beta; 0, var) + J/2 log 2 pi - 1/2 log det H
    return data, beta, extra


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
    whitener: Whitener | None = None,
    nu: float | None = None,
) -> dict:
    """Maximised log-likelihood, BIC and Laplace log evidence of one candidate (``normal_sigma``: the
    geometry-error noise model of the module docstring; ``residual = (rho, ell)``: the residual process,
    whose ``Whitener(data, rho, ell)`` may be passed as ``whitener`` when already computed; both: the
    two together; ``nu``: the noise, in units of its scale and whitened, i.i.d. Student-t of ``nu`` degrees of
    freedom instead of Gaussian, so that a few badly fitted pixels (a misregistered eye, a wrong nose) do not buy
    extra SH terms; fitted by iteratively reweighted Gauss-Newton, the Laplace Hessian from its Fisher information
    ``(nu + 1) / (nu + 3)`` per value).

    ``texture = (pixels [1+J, P, C], variance [J])`` (:meth:`TextureModel.at_pixels` and
    its PCA variances): the albedo is ``T_0 + sum_j beta_j T_j`` with ``beta_j ~ N(0,
    variance_j)``, fitted by alternating least squares (``texture_iterations`` rounds); the
    evidence then adds beta's prior and its Laplace volume (block-diagonal Hessian).
    """
    C, K = data.n_channels, N_COEFFS[order]
    gray = gray and order > 0 and C > 1
    N = data.y.size
    if residual is not None and whitener is None:
        whitener = Whitener(data, *residual)
    whiten = whitener if residual is not None else None
    beta, extra = None, 0.0
    if texture is not None:
        data, beta, extra = _texture_fit(
            data, order, gray, prior_scale, iterations, texture, texture_iterations, normal_sigma, whiten, nu
        )
    theta, r, J, v, _, (prior_mean, prior_prec) = _fit(
        data, order, gray, prior_scale, iterations, normal_sigma, whiten, nu
    )
    d = theta.size + (0 if beta is None else beta.size)
    # log N(y; pred, V^1/2 R V^1/2): r is in units of the noise; log det = sum log V + C log det R (i.i.d.: R = I)
    if nu is None:
        loglik = -0.5 * (r.size * math.log(2 * math.pi) + (r**2).sum() + np.log(v).sum())
        fisher, sigma_info = 1.0, 2 * N  # the information of theta per unit J^T J, and of log sigma
    else:  # the whitened values in units of the scale are standard Student-t
        loglik = float(student_t_logpdf(r, nu).sum()) - 0.5 * np.log(v).sum()
        fisher, sigma_info = (nu + 1) / (nu + 3), N * 2 * nu / (nu + 3)
    loglik -= 0.5 * C * (0.0 if whiten is None else whiten.log_det)
    H = (J.T @ J if nu is None else fisher * (J.T @ J)) + np.diag(prior_prec)
    log_prior = (
        -0.5 * (prior_prec * (theta - prior_mean) ** 2).sum()
        + 0.5 * np.log(prior_prec / (2 * math.pi)).sum()
        - math.log(LOG_SIGMA_RANGE[1] - LOG_SIGMA_RANGE[0])
    )
    # Laplace: log Z = log p(y, theta*, t*) + (d+1)/2 log 2 pi - 1/2 log det H; H_tt = sigma_info for t = log sigma
    log_evidence = (
        loglik
        + log_prior
        + 0.5 * (theta.size + 1) * math.log(2 * math.pi)
        - 0.5 * np.linalg.slogdet(H)[1]
        - 0.5 * math.log(sigma_info)
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


def fitted(data: LightingData, s: dict, texture: tuple | None = None) -> np.ndarray:
    """``[P, C]``: the image a scored candidate ``s`` (:func:`score`) predicts at ``data``'s pixels: its albedo (the
    texture model's at its fitted coefficients, else ``data``'s known albedo, else 1) times its light through the
    normals (Eq. 2)."""
    light = np.asarray(s["light"])
    shading = data.basis[:, : light.shape[1]] @ light.T
    if texture is not None:
        return texture_albedo(texture[0], s["texture"]) * shading
    return (data.albedo if data.albedo is not None else 1.0) * shading


def select_order(
    data: LightingData,
    criterion: str = "evidence",
    threshold: float = DEFAULT_THRESHOLD,
    prior_scale: float = 2.0,
    texture: tuple | None = None,
    normal_sigma: float = 0.0,
    residual: tuple | None = None,
    nu: float | None = None,
) -> dict:
    """Score every candidate; choose the smallest within ``threshold`` of the best (``nu``: Student-t noise, see
    :func:`score`).

    ``criterion``: ``"evidence"`` (Laplace log evidence) or ``"bic"`` (compared as -BIC/2,
    the same log units).  ``texture``: see :func:`score` (the albedo texture model, fitted per
    candidate); without it the albedo is constant (L-hat) or ``data``'s known albedo.
    Returns ``{"choice", "order", "gray", "scores"}``.
    """
    noise = {"normal_sigma": normal_sigma, "residual": residual, "nu": nu}
    if residual is not None:  # one Cholesky factor for every candidate
        noise["whitener"] = Whitener(data, *residual)
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
    "fitted",
    "select_order",
    "choose",
    "geometry_variance",
    "texture_albedo",
    "noise_variance",
    "unit",
    "Whitener",
    "sh_basis_gradient",
    "DEFAULT_THRESHOLD",
]

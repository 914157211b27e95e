"""How uncertain is the least-squares light L-hat: an emcee posterior over the SH lighting.

Model, per colour channel c and masked pixel p (Eq. 2 with a constant albedo a_c absorbed
into the light, so ``L_c = a_c * L``, as the paper's L-hat of Sec. 4.2 assumes; or, given a
known albedo map, ``I_c(p) = a_c(p) S(n_p, L_c) + e`` and L is the light itself):

    I_c(p) = S(n_p, L_c) + e,   S(n, L) = sum_k basis_k(n) L_k  (Eq. 4, linear in L)

* noise ``e``: Gaussian, or Student-t with ``nu`` degrees of freedom (robust to what the model
  lacks: specular highlights, cast shadows, a misfit mask), scale ``sigma`` shared by the
  channels and sampled as ``log sigma``;
* prior: shading non-negative at every face normal (a hard constraint, log-prior -inf
  outside), each coefficient ``N(0, prior_scale^2)`` (weak), ``log sigma`` uniform on
  ``[log 1e-4, log 1]`` (Jeffreys, bounded).

Sampled with ``emcee.EnsembleSampler`` (log-probability vectorised over walkers), started as
draws of the Gaussian approximation at the least-squares fit inside the constraint; the
stopping rule is emcee's: the chain is longer
than ``50 * tau`` (``tau`` the largest over the parameters) and the estimate of ``tau``
changed by less than 1 % since the last check.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import emcee
import numpy as np
import torch
from scipy.optimize import minimize
from scipy.special import gammaln

from disent.render import C4, sh_basis

N_COEFFS = {0: 1, 1: 4, 2: 9}  # SH coefficients up to each band (L1; L1..L4; L1..L9)
LOG_SIGMA_RANGE = (math.log(1e-4), 0.0)


# ----------------------------------------------------------------------------- data
@dataclass
class LightingData:
    """The masked pixels of one image, ready for a lighting fit."""

    basis: np.ndarray  # [P, 9] SH basis at each masked pixel's normal (float64)
    y: np.ndarray  # [P, C] pixel values
    index: np.ndarray  # [P] flat pixel index into H*W, to paint maps back
    shape: tuple  # (H, W)
    albedo: np.ndarray | None = None  # [P, C] a known albedo (else constant, absorbed into L)

    @property
    def n_pixels(self) -> int:
        return self.y.shape[0]

    @property
    def n_channels(self) -> int:
        return self.y.shape[1]

    def design(self, order: int = 2) -> np.ndarray:
        """``[C, P, K]``: d pixel / d L_k per channel, ``albedo * basis_k`` (Eqs. 2, 4)."""
        basis = self.basis[None, :, : N_COEFFS[order]]
        if self.albedo is None:
            return np.repeat(basis, self.n_channels, 0)
        return self.albedo.T[:, :, None] * basis


def prepare(
    image, normal, mask, albedo=None, *, gray: bool = False, threshold: float = 0.5, min_pixels: int = 16
) -> LightingData:
    """Masked pixels of one image: ``image [C,H,W]``, ``normal [3,H,W]``, ``mask [1,H,W]`` or ``[H,W]``.

    Pixels with ``mask > threshold`` are used (a matte's soft edge mixes in background).  With
    a known ``albedo [3,H,W]`` the model is ``image = albedo * S(n, L)`` (pixels with albedo below
    1e-3 dropped), so L is the light itself; without, a constant albedo is absorbed into L.
    ``gray=True`` averages the channels first (9 parameters).
    """
    image, normal = torch.as_tensor(image), torch.as_tensor(normal)
    if image.dim() != 3 or normal.dim() != 3 or normal.shape[0] != 3 or image.shape[1:] != normal.shape[1:]:
        raise ValueError(
            f"need image [C,H,W] and normal [3,H,W] of one size, got {tuple(image.shape)}, {tuple(normal.shape)}"
        )
    H, W = image.shape[1:]
    mask = torch.as_tensor(mask).reshape(H, W) > threshold
    target = image.double()
    if albedo is not None:
        albedo = torch.as_tensor(albedo).double()
        mask = mask & (albedo > 1e-3).all(0)
        albedo = albedo.mean(0, keepdim=True) if gray else albedo
    if gray:
        target = target.mean(0, keepdim=True)
    index = torch.nonzero(mask.flatten()).flatten()
    if index.numel() < min_pixels:
        raise ValueError(f"lighting fit needs at least {min_pixels} masked pixels, got {index.numel()}")
    y = target.flatten(1)[:, index].T
    if not torch.isfinite(y).all():
        raise ValueError("image has NaN or Inf inside the mask")
    basis = sh_basis(normal.double().flatten(1)[:, index], 0).T
    a = None if albedo is None else albedo.flatten(1)[:, index].T.numpy().copy()
    return LightingData(basis.numpy().copy(), y.numpy().copy(), index.numpy(), (H, W), a)


# ----------------------------------------------------------------------------- log posterior
@dataclass
class LogPosterior:
    """log p(L, log sigma | pixels) up to a constant, vectorised: ``theta [W, D] -> [W]``.

    ``theta`` holds the ``C * K`` coefficients (channel-major) and, unless ``known_sigma`` is
    given, ``log sigma`` last.
    """

    data: LightingData
    order: int = 2
    likelihood: str = "gaussian"  # or "student_t"
    nu: float = 4.0
    prior_scale: float = 2.0
    positivity: bool = True
    known_sigma: float | None = None

    def __post_init__(self):
        if self.likelihood not in ("gaussian", "student_t"):
            raise ValueError(f"likelihood must be 'gaussian' or 'student_t', got {self.likelihood!r}")
        self.A = self.data.design(self.order)  # [C, P, K]
        self.C, self.P, self.K = self.A.shape
        self.At = np.ascontiguousarray(self.A.transpose(0, 2, 1))  # [C, K, P]
        self.yT = np.ascontiguousarray(self.data.y.T)  # [C, P]
        self.yy = (self.yT**2).sum()
        self.Aty, self.AtA = np.einsum("cpk,cp->ck", self.A, self.yT), np.einsum("cpk,cpl->ckl", self.A, self.A)

    @property
    def ndim(self) -> int:
        return self.C * self.K + (self.known_sigma is None)

    def split(self, theta: np.ndarray):
        """``theta [W, D]`` -> ``(L [W, C, K], log_sigma [W])``."""
        L = theta[:, : self.C * self.K].reshape(-1, self.C, self.K)
        log_sigma = np.full(len(theta), math.log(self.known_sigma)) if self.known_sigma is not None else theta[:, -1]
        return L, log_sigma

    def shading(self, L: np.ndarray) -> np.ndarray:
        """Predicted pixels ``[W, C, P]`` for lights ``L [W, C, K]`` (Eqs. 2, 4); same sign as the shading."""
        shape = (len(L), self.C, 1, self.P)
        if getattr(self, "_buffer", np.empty(0)).shape != shape:  # reused: large temporaries are slow to map
            self._buffer = np.empty(shape)
        return np.matmul(L[:, :, None, :], self.At, out=self._buffer)[:, :, 0]

    def log_likelihood(self, L: np.ndarray, log_sigma: np.ndarray, pred: np.ndarray | None = None) -> np.ndarray:
        """Sum over pixels and channels; ``pred`` (= :meth:`shading`, overwritten) saves a product."""
        n = self.C * self.P
        s2 = np.exp(2 * log_sigma)
        if self.likelihood == "gaussian":  # sufficient statistics: |y - A l|^2 = y'y - 2 l'A'y + l'A'A l
            sse = self.yy - 2 * np.einsum("wck,ck->w", L, self.Aty) + np.einsum("wck,ckl,wcl->w", L, self.AtA, L)
            return -n * (log_sigma + 0.5 * math.log(2 * math.pi)) - 0.5 * sse / s2
        r = self.shading(L) if pred is None else pred
        np.subtract(r, self.yT, out=r)
        np.square(r, out=r)
        r /= (self.nu * s2)[:, None, None]
        t = np.log1p(r, out=r).sum((1, 2))
        nu = self.nu
        const = gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * math.log(nu * math.pi)
        return n * (const - log_sigma) - 0.5 * (nu + 1) * t

    def feasible(self, theta: np.ndarray) -> np.ndarray:
        """``[W]`` bool: shading non-negative at every face normal (the positivity prior's support)."""
        L, _ = self.split(np.atleast_2d(theta))
        return (L @ self.data.basis[:, : self.K].T).min((1, 2)) >= 0

    def log_prior(self, L: np.ndarray, log_sigma: np.ndarray) -> np.ndarray:
        lp = -0.5 * (L**2).sum((1, 2)) / self.prior_scale**2
        if self.known_sigma is None:
            lo, hi = LOG_SIGMA_RANGE
            lp = np.where((log_sigma > lo) & (log_sigma < hi), lp, -np.inf)
        return lp

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        L, log_sigma = self.split(theta)
        lp = self.log_prior(L, log_sigma)
        pred = None
        if self.positivity:
            pred = self.shading(L)
            lp = np.where(pred.min((1, 2)) >= 0, lp, -np.inf)
        out = np.full(len(theta), -np.inf)
        ok = np.isfinite(lp)
        if ok.any():
            out[ok] = lp[ok] + self.log_likelihood(L[ok], log_sigma[ok], None if pred is None else pred[ok])
        return out


# ----------------------------------------------------------------------------- starting point
def robust_fit(logpost: LogPosterior, iterations: int = 20, constrained: bool = True):
    """Least-squares (Gaussian) or IRLS/EM (Student-t) fit and its Gaussian approximation.

    Returns ``(mode [D], covariance [D, D])``: the fit (under the positivity prior and with
    ``constrained``, the constrained fit where the free one shades some face normal negative) and the inverse
    Hessian of the log-posterior there (Gauss-Newton; the constraint is ignored in it).
    """
    A, y, C, K = logpost.A, logpost.data.y, logpost.C, logpost.K
    P = A.shape[1]
    w = np.ones((P, C))
    for _ in range(iterations if logpost.likelihood == "student_t" else 1):
        AtWA = np.einsum("cpk,pc,cpl->ckl", A, w, A)
        AtWy = np.einsum("cpk,pc,pc->ck", A, w, y)
        L = np.linalg.solve(AtWA, AtWy[..., None])[..., 0]  # [C, K]
        r = y - np.einsum("cpk,ck->pc", A, L)
        if logpost.known_sigma is not None:
            s2 = logpost.known_sigma**2
        else:
            s2 = max((w * r**2).sum() / r.size, 1e-12)  # EM update of the scale
        if logpost.likelihood == "student_t":
            w = (logpost.nu + 1) / (logpost.nu + r**2 / s2)
    basis = logpost.data.basis[:, :K]
    if constrained and logpost.positivity and (basis @ L.T).min() < 0:
        L = np.stack([_nonnegative_fit(A[c], y[:, c], w[:, c], L[c], basis) for c in range(C)])
    # Gauss-Newton Hessian: A^T W A / s2 (+ prior) per channel; Fisher information of log sigma
    info = (
        np.einsum(
            "cpk,pc,cpl->ckl",
            A,
            w if logpost.likelihood == "gaussian" else np.full_like(w, (logpost.nu + 1) / (logpost.nu + 3)),
            A,
        )
        / s2
    )
    info += np.eye(K) / logpost.prior_scale**2
    cov_L = np.linalg.inv(info)  # [C, K, K]
    D = logpost.ndim
    cov = np.zeros((D, D))
    for c in range(C):
        cov[c * K : (c + 1) * K, c * K : (c + 1) * K] = cov_L[c]
    mode = L.reshape(-1)
    if logpost.known_sigma is None:
        fisher = 2.0 if logpost.likelihood == "gaussian" else 2 * logpost.nu / (logpost.nu + 3)
        cov[-1, -1] = 1.0 / (fisher * P * C)
        mode = np.append(mode, 0.5 * math.log(s2))
    return mode, cov


def _nonnegative_fit(A, y, w, start, basis):
    """Weighted least squares ``min sum w (y - A l)^2`` subject to shading ``basis l >= 0``
    (SLSQP), from a feasible point (``start`` with the ambient term L1 raised)."""
    start = start.copy()
    start[0] += max(0.0, -(basis @ start).min()) / C4 * 1.001  # basis of L1 is the constant c4
    Aw, yw = A * np.sqrt(w)[:, None], y * np.sqrt(w)
    res = minimize(
        lambda l: 0.5 * np.sum((Aw @ l - yw) ** 2),
        start,
        jac=lambda l: Aw.T @ (Aw @ l - yw),
        constraints=[{"type": "ineq", "fun": lambda l: basis @ l, "jac": lambda l: basis}],
        method="SLSQP",
        options={"maxiter": 200, "ftol": 1e-12},
    )
    l = res.x if (basis @ res.x).min() >= 0 else start
    return l


class TruncatedT:
    """A multivariate t (``df``, centre ``mean``, scale ``cov * inflate^2``) restricted to the set
    where ``feasible(theta)`` holds, drawn by rejection.

    Its log density is the untruncated one's up to the (unknown) normaliser, which cancels
    in a Metropolis-Hastings ratio; so an independence proposal from it is exact, and every
    proposal lies inside the positivity constraint (none wasted where the constraint binds).
    """

    def __init__(self, mean, cov, feasible=None, df: float = 30.0, inflate: float = 1.05, max_rounds: int = 8):
        self.mean, self.df, self.feasible, self.max_rounds = mean, df, feasible, max_rounds
        self.chol = np.linalg.cholesky(cov * inflate**2)
        self.chol_inv = np.linalg.inv(self.chol)

    def log_density(self, x):
        z = (x - self.mean) @ self.chol_inv.T
        return -0.5 * (self.df + len(self.mean)) * np.log1p((z * z).sum(1) / self.df)

    def draw(self, n: int, rng, fallback=None):
        """``n`` feasible draws; rows still infeasible after ``max_rounds`` rounds of ``2 n`` tries are
        ``fallback``'s rows (default: the centre).  Returns ``(x [n, D], drawn [n] bool)``."""
        out = np.array(np.broadcast_to(self.mean, (n, len(self.mean))) if fallback is None else fallback, dtype=float)
        todo = np.arange(n)
        for _ in range(self.max_rounds):
            z = rng.standard_normal((2 * len(todo), len(self.mean)))
            x = self.mean + (z / np.sqrt(rng.chisquare(self.df, size=len(z)) / self.df)[:, None]) @ self.chol.T
            x = x if self.feasible is None else x[self.feasible(x)]
            take = min(len(x), len(todo))
            out[todo[:take]], todo = x[:take], todo[take:]
            if not len(todo):
                break
        drawn = np.ones(n, bool)
        drawn[todo] = False
        return out, drawn


def independence_move(mean: np.ndarray, cov: np.ndarray, feasible=None, df: float = 30.0, inflate: float = 1.05):
    """An emcee Metropolis-Hastings move proposing independently from a (truncated) multivariate t.

    Centred on the Gaussian approximation of the posterior with its covariance inflated and
    restricted to the positivity constraint (:class:`TruncatedT`), it mixes in a few steps
    where the posterior is close to a (truncated) Gaussian; mixed with a DE move (which
    adapts to the ensemble's spread) the sampler stays correct when it is not.  A walker whose
    rejection sampling fails keeps its position (counted as a rejection, so a proposal that
    misses the constraint shows in the acceptance fraction and triggers the refit).
    """
    q = TruncatedT(mean, cov, feasible, df, inflate)

    def proposal(x, rng):
        new, drawn = q.draw(len(x), rng, fallback=x)
        log_ratio = np.where(drawn, q.log_density(x) - q.log_density(new), -np.inf)  # ln q(x) - ln q(x')
        return new, log_ratio

    return emcee.moves.MHMove(proposal)


def integrated_time(chain: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time ``[D]`` of ``chain [steps, walkers, D]``: emcee's estimator
    (``emcee.autocorr.integrated_time``: walker-averaged autocorrelation, Sokal's window with
    ``c``) in one FFT over every walker and parameter instead of one per pair."""
    n = chain.shape[0]
    x = chain - chain.mean(0)
    size = 2 ** int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(x, n=size, axis=0)
    acf = np.fft.irfft(f * np.conj(f), n=size, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):  # a walker that never moved: nan, as emcee
        rho = (acf / acf[0]).mean(1)  # [n, D]
    taus = 2.0 * np.cumsum(rho, 0) - 1.0
    below = np.arange(n)[:, None] >= c * taus
    window = np.where(below.any(0), below.argmax(0), n - 1)
    return taus[window, np.arange(taus.shape[1])]


# ----------------------------------------------------------------------------- sampler
@dataclass
class Posterior:
    """Samples of the lighting posterior of one image, and the sampler's diagnostics."""

    sh: np.ndarray  # [S, C, 9]; coefficients above the model order are zero
    log_sigma: np.ndarray  # [S]
    order: int
    likelihood: str
    diagnostics: dict = field(default_factory=dict)
    start: np.ndarray | None = None  # [C, 9], the least-squares (or IRLS) fit

    @property
    def mean(self) -> np.ndarray:
        return self.sh.mean(0)

    @property
    def std(self) -> np.ndarray:
        return self.sh.std(0)

    def interval(self, level: float = 0.68):
        """Equal-tailed credible interval ``(lo, hi)``, each ``[C, 9]``."""
        q = (1 - level) / 2
        lo, hi = np.quantile(self.sh, [q, 1 - q], axis=0)
        return lo, hi

    def light_direction(self) -> np.ndarray:
        """Dominant light direction per sample ``[S, 3]`` (unit, camera frame).

        The first-order part of the shading is ``2 c2 (L4 x + L2 y + L3 z)`` (Eq. 4), so the
        light points along ``(L4, L2, L3)``; channels are summed (the white-light direction).
        """
        v = self.sh[:, :, [3, 1, 2]].sum(1)
        return v / np.linalg.norm(v, axis=1, keepdims=True).clip(1e-12)

    def direction_summary(self, level: float = 0.68) -> dict:
        d = self.light_direction()
        m = d.mean(0)
        m = m / max(np.linalg.norm(m), 1e-12)
        angle = np.degrees(np.arccos(np.clip(d @ m, -1, 1)))
        return {
            "mean_direction": m.tolist(),
            f"angle_deg_q{int(level * 100)}": float(np.quantile(angle, level)),
            "angle_deg_q95": float(np.quantile(angle, 0.95)),
        }

    def shading_map(self, normal, max_samples: int = 1000, seed: int = 0):
        """Posterior mean and standard deviation of the shading at each pixel, ``[C, H, W]`` each."""
        normal = torch.as_tensor(normal).double()
        rng = np.random.default_rng(seed)
        pick = rng.choice(len(self.sh), size=min(max_samples, len(self.sh)), replace=False)
        B = sh_basis(normal, 0).flatten(1).numpy()  # [9, H*W]
        S = self.sh[pick] @ B  # [s, C, H*W]
        shape = (self.sh.shape[1], *normal.shape[1:])
        return S.mean(0).reshape(shape), S.std(0).reshape(shape)

    def summary(self) -> dict:
        lo68, hi68 = self.interval(0.68)
        lo95, hi95 = self.interval(0.95)
        return {
            "order": self.order,
            "likelihood": self.likelihood,
            "mean": self.mean.tolist(),
            "std": self.std.tolist(),
            "ci68": [lo68.tolist(), hi68.tolist()],
            "ci95": [lo95.tolist(), hi95.tolist()],
            "least_squares": None if self.start is None else self.start.tolist(),
            "sigma_median": float(np.exp(np.median(self.log_sigma))),
            "direction": self.direction_summary(),
            "diagnostics": self.diagnostics,
        }


def sample_posterior(
    data: LightingData,
    *,
    order: int = 2,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    prior_scale: float = 2.0,
    positivity: bool = True,
    known_sigma: float | None = None,
    n_walkers: int | None = None,
    check_every: int = 50,
    min_tau_factor: float = 50.0,
    tau_rtol: float = 0.01,
    max_steps: int = 3000,
    min_acceptance: float = 0.2,
    adapt_rounds: int = 6,
    seed: int = 0,
) -> Posterior:
    """Sample ``p(L, log sigma | data)`` with emcee, stopping by emcee's autocorrelation rule.

    Moves: a differential-evolution move (20 %) mixed with an independence proposal (80 %)
    from the Gaussian approximation at the free (IRLS) fit truncated to the positivity
    constraint (:class:`TruncatedT`); the walkers start as draws of that proposal.  Every ``check_every`` steps
    the integrated autocorrelation time is estimated; with ``tau`` its largest value over the
    parameters, sampling stops once the chain is longer than ``min_tau_factor * tau`` and
    ``tau`` changed by less than ``tau_rtol`` since the last check, or at ``max_steps`` (then
    ``diagnostics["converged"]`` is False).  The first ``2 * tau`` steps are discarded and the
    rest thinned by ``tau / 2``.  While the acceptance fraction of a chunk is below
    ``min_acceptance`` (the approximation misses the posterior; at most ``adapt_rounds``
    times) the proposal is refitted to the chunk's samples and a new chain started with it
    fixed (the old one is dropped).
    """
    if order not in N_COEFFS:
        raise ValueError(f"order must be 0, 1 or 2, got {order}")
    t0, c0 = time.perf_counter(), time.process_time()
    logpost = LogPosterior(data, order, likelihood, nu, prior_scale, positivity, known_sigma)
    mode, cov = robust_fit(logpost)
    rng = np.random.default_rng(seed)
    D = logpost.ndim
    n_walkers = n_walkers or max(D + 4, 32)  # the independence move does most of the work
    feasible = logpost.feasible if positivity else None
    # the proposal: the Gaussian approximation at the *free* fit, truncated to the constraint
    # (for a Gaussian likelihood with known sigma that is the posterior itself)
    centre, centre_cov = robust_fit(logpost, constrained=False) if positivity else (mode, cov)
    ball = mode + 0.1 * rng.standard_normal((n_walkers, D)) @ np.linalg.cholesky(cov).T  # a small ball
    if positivity:  # push infeasible walkers back with the ambient term, as robust_fit does
        L, _ = logpost.split(ball)
        deficit = np.clip(-(L @ logpost.data.basis[:, : logpost.K].T).min(2), 0, None)  # [W, C] shading
        ball[:, : logpost.C * logpost.K : logpost.K] += deficit / C4 * 1.001
    # walkers start as draws of the proposal (inside the constraint); the ball where that fails
    start = TruncatedT(centre, centre_cov, feasible).draw(n_walkers, rng, fallback=ball)[0]

    def new_sampler(mean, cov):
        moves = [(emcee.moves.DEMove(live_dangerously=True), 0.2), (independence_move(mean, cov, feasible), 0.8)]
        sampler = emcee.EnsembleSampler(n_walkers, D, logpost, moves=moves, vectorize=True)
        sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()  # seeded moves
        return sampler

    sampler = new_sampler(centre, centre_cov)
    state = sampler.run_mcmc(start, check_every, progress=False)
    adapted = 0
    while sampler.acceptance_fraction.mean() < min_acceptance and adapted < adapt_rounds:
        # the proposal misses the posterior (a binding positivity prior): refit it to the last
        # half chunk, start a new chain with it fixed and drop the old one
        flat = sampler.get_chain(discard=check_every // 2, flat=True)
        sampler, adapted = new_sampler(flat.mean(0), np.cov(flat.T) + 1e-12 * np.eye(D)), adapted + 1
        state = sampler.run_mcmc(state, check_every, progress=False)
    old_tau, converged, tau = np.inf, False, np.full(D, np.nan)
    while True:
        tau = integrated_time(sampler.get_chain())
        converged = bool(
            min_tau_factor * tau.max() < sampler.iteration and abs(old_tau - tau.max()) < tau_rtol * tau.max()
        )
        if converged or sampler.iteration >= max_steps:
            break
        old_tau = tau.max()
        state = sampler.run_mcmc(state, check_every, progress=False)
    tau_max = float(np.max(tau))
    if not np.isfinite(tau_max):  # some walker never moved: no estimate, keep the second half unthinned
        converged, tau_max = False, float(sampler.iteration)
    burn, thin = min(int(math.ceil(2 * tau_max)), sampler.iteration // 2), max(1, int(tau_max / 2))
    flat = sampler.get_chain(discard=burn, thin=thin, flat=True)
    L, log_sigma = logpost.split(flat)
    sh = np.zeros((len(flat), logpost.C, 9))
    sh[:, :, : logpost.K] = L
    n_kept = sampler.iteration - burn
    diagnostics = {
        "n_steps": int(sampler.iteration),
        "n_walkers": n_walkers,
        "ndim": D,
        "converged": converged,
        "adapted": adapted,
        "tau": tau.tolist(),
        "tau_max": tau_max,
        "acceptance_fraction": float(np.mean(sampler.acceptance_fraction)),
        "ess_min": float(n_walkers * n_kept / tau_max),
        "ess": np.nan_to_num(n_walkers * n_kept / tau).tolist(),
        "burn": burn,
        "thin": thin,
        "n_samples": len(flat),
        "n_pixels": data.n_pixels,
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }
    start_sh = np.zeros((logpost.C, 9))
    start_sh[:, : logpost.K] = mode[: logpost.C * logpost.K].reshape(logpost.C, logpost.K)
    return Posterior(sh, log_sigma, order, likelihood, diagnostics, start_sh)


def gaussian_posterior(data: LightingData, sigma: float, *, order: int = 2, prior_scale: float = math.inf):
    """Closed form of the linear-Gaussian case (known noise, no positivity constraint).

    ``L_c ~ N(mu_c, Sigma_c)`` with ``Sigma_c = (A_c^T A_c / sigma^2 + I / prior_scale^2)^-1`` and
    ``mu_c = Sigma_c A_c^T y_c / sigma^2``.  Returns ``(mu [C, K], Sigma [C, K, K])``.
    """
    A = data.design(order)
    prec = np.einsum("cpk,cpl->ckl", A, A) / sigma**2 + np.eye(A.shape[2]) / prior_scale**2
    cov = np.linalg.inv(prec)
    mu = np.einsum("ckl,cpl,pc->ck", cov, A, data.y) / sigma**2
    return mu, cov


__all__ = [
    "N_COEFFS",
    "LightingData",
    "prepare",
    "LogPosterior",
    "robust_fit",
    "independence_move",
    "TruncatedT",
    "integrated_time",
    "Posterior",
    "sample_posterior",
    "gaussian_posterior",
]

"""Mixtures of multivariate Student-t (or Gaussian) components fitted by EM; K chosen by BIC.

Density ``p(x) = sum_k pi_k t_nu_k(x; mu_k, Sigma_k)``.  EM after Peel & McLachlan (2000):
E step ``tau_ik ∝ pi_k t(x_i)``, ``u_ik = (nu_k + p) / (nu_k + delta_ik)`` with
``delta_ik`` the Mahalanobis distance; M step ``pi_k = mean tau``, ``mu_k = sum tau u x /
sum tau u``, ``Sigma_k = sum tau u (x - mu)(x - mu)^T / sum tau``; ``nu_k`` solves
``-psi(nu/2) + log(nu/2) + 1 + mean_tau(log u - u) + psi((nu+p)/2) - log((nu+p)/2) = 0``
(capped at NU_MAX: a Gaussian for practical purposes).  The number of components minimises
``BIC = -2 log L + k log n`` with ``k = (K - 1) + K (p + p (p + 1) / 2 + 1)``.
Data are standardised per column first; a ridge of RIDGE (in standard units) keeps a
component whose spread is nil in some direction (a fixed parameter) non-singular.
EM runs with BLAS on one thread (threadpoolctl): its products are (p, p) x (p, n), too small
for threads, and multi-threaded OpenBLAS made it ~6x slower in wall and CPU time here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.special import digamma, gammaln
from threadpoolctl import threadpool_limits

NU_MAX = 200.0
RIDGE = 1e-6


@dataclass
class Mixture:
    weights: np.ndarray  # (K,)
    means: np.ndarray  # (K, p) in data units
    covs: np.ndarray  # (K, p, p) in data units
    dof: np.ndarray  # (K,)
    loglik: float
    bic: float

    @property
    def K(self) -> int:
        return len(self.weights)


def _logpdf(Z: np.ndarray, mu: np.ndarray, S: np.ndarray, nu: float) -> tuple[np.ndarray, np.ndarray]:
    """log t_nu(z; mu, S) and the Mahalanobis distances delta (n,)."""
    p = Z.shape[1]
    L = np.linalg.cholesky(S)
    y = np.linalg.inv(L) @ (Z - mu).T  # one small inverse, then a matmul (a solve per column is slow)
    delta = (y * y).sum(axis=0)
    logdet = 2 * np.log(np.diag(L)).sum()
    lp = (gammaln((nu + p) / 2) - gammaln(nu / 2) - p / 2 * np.log(nu * np.pi) - logdet / 2
          - (nu + p) / 2 * np.log1p(delta / nu))
    return lp, delta


def _nu_update(tau: np.ndarray, u: np.ndarray, nu: float, p: int) -> float:
    n = tau.sum()
    if n < 1e-9:
        return nu
    c = 1 + (tau * (np.log(u) - u)).sum() / n + digamma((nu + p) / 2) - np.log((nu + p) / 2)

    def f(v: float) -> float:
        return float(-digamma(v / 2) + np.log(v / 2) + c)

    if f(NU_MAX) > 0:  # no root below the cap: as Gaussian as the cap allows
        return NU_MAX
    if f(1.01) < 0:
        return 1.01
    return float(brentq(f, 1.01, NU_MAX))


def _em(Z: np.ndarray, K: int, rng: np.random.Generator, iters: int, tol: float,
        heavy: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    n, p = Z.shape
    mu = _kmeanspp(Z, K, rng)
    S = np.repeat(np.cov(Z.T).reshape(1, p, p) + RIDGE * np.eye(p), K, axis=0)
    pi = np.full(K, 1.0 / K)
    nu = np.full(K, 10.0 if heavy else NU_MAX)
    prev = -np.inf
    ll = -np.inf
    for _ in range(iters):
        lps, deltas = zip(*(_logpdf(Z, mu[k], S[k], nu[k]) for k in range(K)), strict=True)
        logr = np.log(pi)[None] + np.stack(lps, axis=1)
        top = logr.max(axis=1)
        tot = top + np.log(np.exp(logr - top[:, None]).sum(axis=1))
        ll = float(tot.sum())
        tau = np.exp(logr - tot[:, None])
        for k in range(K):
            u = (nu[k] + p) / (nu[k] + deltas[k])
            w = tau[:, k] * u
            sw = max(w.sum(), 1e-300)
            mu[k] = w @ Z / sw
            d = Z - mu[k]
            S[k] = (d * w[:, None]).T @ d / max(tau[:, k].sum(), 1e-300) + RIDGE * np.eye(p)
            if heavy:
                nu[k] = _nu_update(tau[:, k], u, nu[k], p)
        pi = np.clip(tau.mean(axis=0), 1e-12, None)
        if ll - prev < tol * abs(ll):
            break
        prev = ll
    return pi, mu, S, nu, ll


def _kmeanspp(Z: np.ndarray, K: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding, then a few Lloyd steps: starting means for EM."""
    c = [Z[rng.integers(len(Z))]]
    for _ in range(1, K):
        d2 = np.min([((Z - m) ** 2).sum(axis=1) for m in c], axis=0)
        c.append(Z[rng.choice(len(Z), p=d2 / d2.sum())] if d2.sum() > 0 else Z[rng.integers(len(Z))])
    C = np.array(c)
    for _ in range(10):
        lab = np.argmin(((Z[:, None, :] - C[None]) ** 2).sum(axis=2), axis=1)
        C = np.array([Z[lab == k].mean(axis=0) if np.any(lab == k) else C[k] for k in range(K)])
    return C


def fit_mixture(X: np.ndarray, max_components: int = 4, seed: int = 0, heavy: bool = True,
                iters: int = 150, tol: float = 1e-7,
                restarts: int = 2, max_rows: int = 8000) -> tuple[Mixture, list[dict[str, float]]]:
    """The BIC-best mixture of 1..max_components components of rows X (n, p), and every
    candidate's K, log-likelihood and BIC."""
    with threadpool_limits(limits=1, user_api="blas"):  # module docstring: one thread is faster
        return _fit_mixture(X, max_components, seed, heavy, iters, tol, restarts, max_rows)


def _fit_mixture(X: np.ndarray, max_components: int, seed: int, heavy: bool, iters: int, tol: float,
                 restarts: int, max_rows: int) -> tuple[Mixture, list[dict[str, float]]]:
    X = np.asarray(X, dtype=float)
    rng = np.random.default_rng(seed)
    if len(X) > max_rows:  # a uniform subsample: EM's cost is linear in rows, its precision ~ 1/sqrt(rows)
        X = X[rng.choice(len(X), max_rows, replace=False)]
    n, p = X.shape
    loc, scale = X.mean(axis=0), X.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Z = (X - loc) / scale
    best: Mixture | None = None
    table = []
    for K in range(1, max_components + 1):
        if n < 5 * K * (p + 2):
            break
        runs = [_em(Z, K, rng, iters, tol, heavy) for _ in range(restarts if K > 1 else 1)]
        pi, mu, S, nu, ll = max(runs, key=lambda r: r[4])
        k_par = (K - 1) + K * (p + p * (p + 1) / 2 + (1 if heavy else 0))
        ll_x = ll - n * np.log(scale).sum()  # the density of X, not of the standardised Z
        bic = -2 * ll_x + k_par * np.log(n)
        table.append({"components": K, "loglik": ll_x, "bic": bic})
        m = Mixture(pi, loc + mu * scale, S * np.outer(scale, scale)[None], nu, ll_x, bic)
        if best is not None and bic >= best.bic:
            break  # BIC rose: more components only cost more
        best = m
    assert best is not None, "fit_mixture needs at least 5 (p + 2) rows"
    order = np.argsort(-best.weights)
    best = Mixture(best.weights[order], best.means[order], best.covs[order], best.dof[order], best.loglik, best.bic)
    return best, table

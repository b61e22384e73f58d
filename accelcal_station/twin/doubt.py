"""The twin's own doubt: how much a predicted yield moves when the fitted population moves as
much as fitting it on the lot's boards allows (a parametric bootstrap over the population).

Each replicate b perturbs every component as its fit on ``n`` boards (the rows EM saw) leaves
it uncertain: weights ``pi_b ~ Dirichlet(n pi)``; with ``n_k = n pi_k`` boards in component k,
the mean ``mu_b ~ N(mu, Sigma / n_k)`` and the covariance ``Sigma_b ~ Wishart(n_k, Sigma / n_k)``.
Rather than simulating and fitting a lot per replicate, the simulated boards are reweighted
(importance sampling): board i drawn from the fitted population p with parameter vector x_i
(the changes along the lot taken out, tailed quantities at Gaussian scale) weighs
``w_i = p_b(x_i) / p(x_i)``, and the replicate's yield is ``sum w_i pass_i / sum w_i``.  The
standard deviation over replicates is the yield's parameter uncertainty (its Monte Carlo part
included: it errs wide, not narrow).
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammaln, logsumexp
from scipy.stats import wishart

from ..sim.population import Population

REPLICATES = 100


def _logpdf(x: np.ndarray, mu: np.ndarray, S: np.ndarray, nu: float | None) -> np.ndarray:
    p = len(mu)
    L = np.linalg.cholesky(S)
    y = np.linalg.solve(L, (x - mu).T)
    d = (y * y).sum(axis=0)
    logdet = 2 * np.log(np.diag(L)).sum()
    if nu is None:
        return -0.5 * (d + logdet + p * np.log(2 * np.pi))
    return (gammaln((nu + p) / 2) - gammaln(nu / 2) - p / 2 * np.log(nu * np.pi) - logdet / 2
            - (nu + p) / 2 * np.log1p(d / nu))


def _density(x: np.ndarray, pi: np.ndarray, mus: list[np.ndarray], covs: list[np.ndarray],
             dofs: list[float | None]) -> np.ndarray:
    return logsumexp(np.stack([np.log(max(w, 1e-300)) + _logpdf(x, m, S, nu)
                               for w, m, S, nu in zip(pi, mus, covs, dofs, strict=True)], axis=1), axis=1)


def _active(pop: Population) -> np.ndarray:
    return np.any(np.array([c.sd > 0 for c in pop.components]), axis=0)


def yield_replicates(pop: Population, x: np.ndarray, boards: np.ndarray, passed: np.ndarray, n: int,
                     rng: np.random.Generator, replicates: int = REPLICATES) -> np.ndarray:
    """Yields (replicates,) of the simulated boards ``x`` (their lot indices ``boards``; ``passed``
    bool) under perturbed populations (module docstring)."""
    x = x.copy()
    for ch in pop.changes:
        x[:, pop.quantities.index(ch.quantity)] -= ch.shift(boards)
    for name, tail in pop.tails.items():  # the components live at Gaussian scale (sim/population.py)
        k = pop.names.index(name)
        x[:, k] = tail.to_gauss(x[:, k])
    a = _active(pop)
    if not a.any() or n < 2:
        return np.full(replicates, float(np.mean(passed)))
    xa = x[:, a]
    pi = np.array([c.weight for c in pop.components])
    mus = [c.mean[a] for c in pop.components]
    covs = []
    for c in pop.components:
        S = (c.correlation * np.outer(c.sd, c.sd))[np.ix_(a, a)]
        covs.append(S + np.diag(1e-6 * np.diag(S) + 1e-30))
    dofs = [c.dof for c in pop.components]
    base = _density(xa, pi, mus, covs, dofs)
    p = int(a.sum())
    out = np.empty(replicates)
    for b in range(replicates):
        pb = rng.dirichlet(np.maximum(n * pi, 1e-3))
        mb, cb = [], []
        for k in range(len(pi)):
            nk = max(n * pi[k], p + 2.0)
            mb.append(mus[k] + np.linalg.cholesky(covs[k]) @ rng.standard_normal(p) / np.sqrt(nk))
            Sb = wishart.rvs(df=nk, scale=covs[k] / nk, random_state=rng)
            cb.append(np.atleast_2d(Sb) + np.diag(1e-6 * np.diag(covs[k]) + 1e-30))
        lw = _density(xa, pb, mb, cb, dofs) - base
        w = np.exp(lw - lw.max())
        out[b] = float((w * passed).sum() / w.sum())
    return out

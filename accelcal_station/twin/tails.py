"""Tails per parameter: which fitted quantities have a heavy-tailed marginal, and their Student-t.

A multivariate t component carries one degrees-of-freedom figure for all its parameters: one
heavy-tailed process step (say the cross-axis terms) either makes every parameter heavy or is
approximated by several near-Gaussian components.  Here each quantity's marginal (the
reservoir's rows, changes taken out) is fitted three ways -- one Gaussian, one Student-t
(EM, mixture.fit_mixture with one component), a mixture of two Gaussians -- and a quantity is
given a t marginal when the t's BIC is below both others' by TAIL_BIC (a subpopulation's bump
is the two Gaussians' case, not a tail) and its dof is below DOF_MAX.  The mixture is then
fitted to the quantities mapped to Gaussian scale (population.Tail.to_gauss) and drawn back
through the t marginals (sim/population.py: a Gaussian copula with t marginals).
"""
from __future__ import annotations

import numpy as np

from ..sim.population import Tail
from .mixture import fit_mixture
from .records import TailCandidate

TAIL_BIC = 10.0  # a t marginal must beat a Gaussian and two Gaussians by this much BIC (strong evidence)
DOF_MAX = 30.0  # above this a t is a Gaussian for a lot's purposes
ROWS = 4000  # rows per marginal fit (EM's precision on dof ~ 1/sqrt(rows))


def fit_tails(X: np.ndarray, names: list[str], seed: int = 0) -> tuple[dict[str, Tail], list[TailCandidate]]:
    """The quantities with a t marginal (module docstring) and every quantity's BICs."""
    rng = np.random.default_rng(seed)
    if len(X) > ROWS:
        X = X[rng.choice(len(X), ROWS, replace=False)]
    tails: dict[str, Tail] = {}
    report: list[TailCandidate] = []
    for j, name in enumerate(names):
        col = X[:, j:j + 1]
        if len(col) < 30 or not np.std(col) > 0:
            continue
        t, tt = fit_mixture(col, max_components=1, seed=seed, heavy=True)
        g, tg = fit_mixture(col, max_components=2, seed=seed, heavy=False)
        b_gauss = tg[0]["bic"]
        b_two = min((r["bic"] for r in tg if r["components"] == 2), default=np.inf)
        nu = float(t.dof[0])
        heavy = bool(tt[0]["bic"] < min(b_gauss, b_two) - TAIL_BIC and nu < DOF_MAX)
        report.append({"quantity": name, "dof": nu, "bic_t": tt[0]["bic"], "bic_gaussian": b_gauss,
                       "bic_two_gaussians": b_two if np.isfinite(b_two) else None, "heavy": heavy})
        if heavy:
            tails[name] = Tail(round(nu, 3), float(t.means[0, 0]), float(np.sqrt(t.covs[0, 0, 0])))
    return tails, report


def to_gauss(X: np.ndarray, names: list[str], tails: dict[str, Tail]) -> np.ndarray:
    """The rows with each tailed quantity mapped to Gaussian scale."""
    Y = X.copy()
    for name, t in tails.items():
        j = names.index(name)
        Y[:, j] = t.to_gauss(X[:, j])
    return Y


def slope_at_centre(names: list[str], tails: dict[str, Tail]) -> np.ndarray:
    """d to_gauss / dx at each quantity's centre (1 without a tail): t_nu(0) / phi(0)."""
    from scipy.special import gammaln

    d = np.ones(len(names))
    for name, t in tails.items():
        nu = t.dof
        t0 = np.exp(gammaln((nu + 1) / 2) - gammaln(nu / 2)) / np.sqrt(nu * np.pi)
        d[names.index(name)] = t0 * np.sqrt(2 * np.pi)
    return d

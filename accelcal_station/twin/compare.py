"""Two-sample tests between a real and a simulated lot, with their false-alarm rate stated.

- per quantity: Anderson-Darling k-sample (scipy.stats.anderson_ksamp, Scholz & Stephens
  1987).  scipy floors its p-value at 0.001 and caps it at 0.25; below 0.001 the p-value
  here extends log p linearly in the statistic beyond scipy's last two critical values
  (0.005 and 0.001), so very different samples get a very small p, not 0.001;
- counts (verdict mix, failure reasons): Pearson chi-square on the 2 x k table;
- joint parameters: the energy distance (Szekely & Rizzo 2004) between standardised
  subsamples, p-value by a permutation test.

A test flags a gap when ``p < FAMILY_ALPHA / m`` (Bonferroni over the m tests of a check):
with a simulator that is the real line, a check flags anything with probability at most
FAMILY_ALPHA.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np

FAMILY_ALPHA = 0.01
_SIG = np.array([0.25, 0.1, 0.05, 0.025, 0.01, 0.005, 0.001])


def _summary(x: np.ndarray) -> dict[str, float]:
    q = np.percentile(x, [5, 50, 95]) if len(x) else [np.nan] * 3
    return {"n": int(len(x)), "mean": float(np.mean(x)) if len(x) else float("nan"),
            "sd": float(np.std(x)) if len(x) else float("nan"), "p05": float(q[0]), "median": float(q[1]),
            "p95": float(q[2])}


def anderson(real: np.ndarray, sim: np.ndarray) -> tuple[float, float]:
    """A-D k-sample statistic and p-value (module docstring); (0, 1) when both are one constant."""
    if len(np.unique(np.concatenate([real, sim]))) < 2:
        return 0.0, 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy warns that its p-value is floored or capped
        from scipy.stats import anderson_ksamp  # on first use: scipy.stats is ~50 MB and a second at start-up

        r = anderson_ksamp([real, sim])
    stat, crit = float(r.statistic), np.asarray(r.critical_values, dtype=float)
    if stat <= crit[-1]:
        return stat, float(r.pvalue)
    slope = (np.log(_SIG[-1]) - np.log(_SIG[-2])) / (crit[-1] - crit[-2])
    return stat, float(np.exp(np.log(_SIG[-1]) + slope * (stat - crit[-1])))


def energy(real: np.ndarray, sim: np.ndarray, rng: np.random.Generator, n_max: int = 400,
           permutations: int = 2999) -> tuple[float, float]:
    """Energy distance E = 2 E|X - Y| - E|X - X'| - E|Y - Y'| on standardised rows; permutation
    p = (1 + #{E_perm >= E}) / (1 + permutations), the permutations done as matrix products
    (l^T D m for label vectors l, m), so 2999 of them cost about one second."""
    real = real[rng.choice(len(real), min(n_max, len(real)), replace=False)]
    sim = sim[rng.choice(len(sim), min(n_max, len(sim)), replace=False)]
    Z = np.concatenate([real, sim])
    s = Z.std(axis=0)
    Z = (Z - Z.mean(axis=0)) / np.where(s > 0, s, 1.0)
    sq = (Z * Z).sum(1)
    D = np.sqrt(np.clip(sq[:, None] + sq[None] - 2 * Z @ Z.T, 0.0, None))
    n, N = len(real), len(Z)
    m = N - n
    total = D.sum()

    def stats(L: np.ndarray) -> np.ndarray:  # L (N, B): 1 for the first sample
        DL = D @ L
        xx = (L * DL).sum(axis=0)  # l^T D l
        xy = DL.sum(axis=0) - xx  # l^T D (1 - l)
        yy = total - xx - 2 * xy
        return 2 * xy / (n * m) - xx / (n * n) - yy / (m * m)

    e0 = float(stats((np.arange(N) < n).astype(float)[:, None])[0])
    exceed = 0
    for a in range(0, permutations, 500):
        B = min(500, permutations - a)
        L = (rng.random((N, B)).argsort(axis=0) < n).astype(float)
        exceed += int((stats(L) >= e0 - 1e-12).sum())
    return e0, (1 + exceed) / (1 + permutations)


def counts_test(real: dict[str, int], sim: dict[str, int]) -> tuple[float, float]:
    """Pearson chi-square of two count vectors over the union of their categories."""
    keys = sorted(set(real) | set(sim))
    table = np.array([[real.get(k, 0) for k in keys], [sim.get(k, 0) for k in keys]], dtype=float)
    table = table[:, table.sum(axis=0) > 0]
    if table.shape[1] < 2 or np.any(table.sum(axis=1) == 0):
        return 0.0, 1.0
    from scipy.stats import chi2_contingency  # on first use, as above

    chi2, p, _, _ = chi2_contingency(table)
    return float(chi2), float(p)


def flag(tests: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mark each test's ``gap`` at the Bonferroni level; returns the flagged ones."""
    level = FAMILY_ALPHA / max(len(tests), 1)
    for t in tests:
        t["gap"] = bool(t["p_value"] < level)
        t["level"] = level
    return [t for t in tests if t["gap"]]


def quantity_test(name: str, real: np.ndarray, sim: np.ndarray) -> dict[str, Any]:
    real, sim = real[np.isfinite(real)], sim[np.isfinite(sim)]
    stat, p = anderson(real, sim) if len(real) > 1 and len(sim) > 1 else (0.0, 1.0)
    return {"quantity": name, "test": "anderson_ksamp", "statistic": stat, "p_value": p,
            "real": _summary(real), "sim": _summary(sim)}

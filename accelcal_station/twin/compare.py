"""Two-sample tests between a real and a simulated lot, with their false-alarm rate stated.

- per quantity: Anderson-Darling k-sample (scipy.stats.anderson_ksamp, Scholz & Stephens
  1987).  scipy floors its p-value at 0.001 and caps it at 0.25; below 0.001 the p-value
  here extends log p linearly in the statistic beyond scipy's last two critical values
  (0.005 and 0.001), so very different samples get a very small p, not 0.001;
- counts (verdict mix, failure reasons): Pearson chi-square on the 2 x k table;
- joint parameters: the energy distance (Szekely & Rizzo 2004) between standardised
  subsamples, p-value by a permutation test.

A test *detects* a gap when ``p < FAMILY_ALPHA / m`` (Bonferroni over the m tests of a check):
with a simulator that is the real line, a check detects anything with probability at most
FAMILY_ALPHA.  A detected gap *matters* only when its effect, in the quantity's own units,
exceeds a margin tied to the acceptance limits (:func:`effect`):

- a quantity an acceptance limit judges (residual and leave-one-out RMS, W_ii against
  gain_error_max, W_ij against cross_axis_max, V_i against offset_max_mg, Gamma_i against
  cubic_max): the share of boards beyond the limit differs by more than YIELD_MARGIN (the
  yield change the gap implies at the current limits), or the 5th, 50th or 95th percentile
  moves by more than QUANTILE_MARGIN of the limit;
- a quantity no limit judges: the Wasserstein distance exceeds SPREAD_MARGIN of the real
  lot's standard deviation;
- counts (verdict mix, failure reasons): a category's share differs by more than YIELD_MARGIN;
- the joint parameters: the (standardised) energy distance exceeds ENERGY_MARGIN (in one
  dimension, about a 0.3 sd shift of the mean: E ~ 0.56 delta^2).
Below the margin a detected gap is "detectable but immaterial": it moves no verdict that matters.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from .records import DistributionTest, Effect, QuantityTest, Summary

FAMILY_ALPHA = 0.01
YIELD_MARGIN = 0.005  # half a percentage point of boards beyond a limit (or in a verdict category)
QUANTILE_MARGIN = 0.02  # a percentile moving by 2 % of the limit that judges it
SPREAD_MARGIN = 0.1  # Wasserstein distance over the real lot's sd, for a quantity no limit judges
ENERGY_MARGIN = 0.05
_SIG = np.array([0.25, 0.1, 0.05, 0.025, 0.01, 0.005, 0.001])


def _summary(x: np.ndarray) -> Summary:
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


def flag(tests: list[QuantityTest]) -> list[QuantityTest]:
    """Mark each test's ``detected`` (p below the Bonferroni level) and ``gap`` (detected and
    material: its effect beyond the margin); returns the gaps that matter."""
    level = FAMILY_ALPHA / max(len(tests), 1)
    for t in tests:
        t["detected"] = bool(t["p_value"] < level)
        t["gap"] = bool(t["detected"] and t["effect"].get("material", True))
        t["level"] = level
    return [t for t in tests if t["gap"]]


def verdict(tests: list[QuantityTest]) -> str:
    """gap (a detected gap that matters) | detectable but immaterial | no gap."""
    if any(t.get("gap") for t in tests):
        return "gap"
    return "detectable but immaterial" if any(t.get("detected") for t in tests) else "no gap"


def judged_by(name: str, limits: dict[str, float]
              ) -> tuple[str, float, Callable[[np.ndarray], np.ndarray]] | None:
    """The acceptance limit that judges a measured quantity: (limit key, limit, the quantity's
    value in the limit's units as a function of the quantity), or None."""
    if name in ("residual_rms_mg", "crossval_rms_mg"):
        key, fn = name, (lambda v: v)
    elif len(name) == 3 and name[0] == "W":
        key, fn = ("gain_error_max", lambda v: np.abs(v - 1.0)) if name[1] == name[2] else ("cross_axis_max", np.abs)
    elif name[:1] == "V" and name[1:].isdigit():
        key, fn = "offset_max_mg", (lambda v: 1e3 * np.abs(v))
    elif name.startswith("Gamma"):
        key, fn = "cubic_max", np.abs
    else:
        return None
    return (key, float(limits[key]), fn) if key in limits else None


def effect(name: str, real: np.ndarray, sim: np.ndarray, limits: dict[str, float] | None) -> Effect:
    """The gap's size in the quantity's own units (module docstring): Wasserstein distance,
    percentile shifts (sim - real), the yield change at the judging limit, and ``material``."""
    from scipy.stats import wasserstein_distance  # on first use, as above

    if len(real) < 2 or len(sim) < 2:
        return {"material": False}
    qr, qs = np.percentile(real, [5, 50, 95]), np.percentile(sim, [5, 50, 95])
    out: Effect = {"wasserstein": float(wasserstein_distance(real, sim)),
                           "shift_p05": float(qs[0] - qr[0]), "shift_median": float(qs[1] - qr[1]),
                           "shift_p95": float(qs[2] - qr[2])}
    j = judged_by(name, limits or {})
    if j is not None:
        key, lim, fn = j
        beyond_r, beyond_s = float(np.mean(fn(real) > lim)), float(np.mean(fn(sim) > lim))
        big_shift = float(np.max(np.abs(np.percentile(fn(sim), [5, 50, 95]) - np.percentile(fn(real), [5, 50, 95]))))
        out.update({"limit": key, "limit_value": lim, "beyond_limit_real": beyond_r, "beyond_limit_sim": beyond_s,
                    "yield_change": beyond_r - beyond_s,
                    "margin": f"|yield change| > {YIELD_MARGIN:g} or a percentile shift > {QUANTILE_MARGIN:g} x limit",
                    "material": bool(abs(beyond_r - beyond_s) > YIELD_MARGIN or big_shift > QUANTILE_MARGIN * lim)})
    else:
        sd = float(np.std(real))
        out.update({"margin": f"wasserstein > {SPREAD_MARGIN:g} x the real sd ({SPREAD_MARGIN * sd:.4g})",
                    "material": bool(out["wasserstein"] > SPREAD_MARGIN * sd)})
    return out


def counts_effect(real: dict[str, int], sim: dict[str, int], n_real: int, n_sim: int) -> Effect:
    """The largest difference of a category's share of boards (real - sim), against YIELD_MARGIN."""
    nr, ns = max(n_real, 1), max(n_sim, 1)
    diff = {k: real.get(k, 0) / nr - sim.get(k, 0) / ns for k in sorted(set(real) | set(sim))}
    worst = max(diff, key=lambda k: abs(diff[k]), default=None)
    return {"share_change": diff, "largest": worst, "margin": f"|share change| > {YIELD_MARGIN:g}",
            "material": bool(worst is not None and abs(diff[worst]) > YIELD_MARGIN)}


def quantity_test(name: str, real: np.ndarray, sim: np.ndarray, limits: dict[str, float] | None = None
                  ) -> DistributionTest:
    real, sim = real[np.isfinite(real)], sim[np.isfinite(sim)]
    stat, p = anderson(real, sim) if len(real) > 1 and len(sim) > 1 else (0.0, 1.0)
    return {"quantity": name, "test": "anderson_ksamp", "statistic": stat, "p_value": p,
            "real": _summary(real), "sim": _summary(sim), "effect": effect(name, real, sim, limits)}

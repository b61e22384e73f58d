"""`twin check`: a simulated lot of the same size and design against the real one, quantity by
quantity (compare.py's tests, Bonferroni over them at compare.FAMILY_ALPHA)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..acceptance.rules import Limits
from .compare import FAMILY_ALPHA, counts_test, energy, flag, quantity_test
from .simlot import load_device, simulate_like
from .stream import FITTED, MEASURES, LotStats

MAX_SIM_BOARDS = 50_000  # a real lot larger than this is compared through its reservoir sample


def _tests(real: LotStats, sim: LotStats, seed: int) -> list[dict[str, Any]]:
    tests = [quantity_test(q, real.column(q), sim.column(q)) for q in MEASURES]
    for name, r, s in (("verdict mix", real.verdicts, sim.verdicts), ("failure reasons", real.reasons, sim.reasons)):
        stat, p = counts_test(dict(r), dict(s))
        tests.append({"quantity": name, "test": "chi2_contingency", "statistic": stat, "p_value": p,
                      "real": dict(r), "sim": dict(s)})
    cols = [real.columns.index(q) for q in FITTED]
    Xr, Xs = real.rows[:, cols], sim.rows[:, cols]
    Xr, Xs = Xr[np.all(np.isfinite(Xr), axis=1)], Xs[np.all(np.isfinite(Xs), axis=1)]
    Xr, Xs = Xr[:, Xr.std(axis=0) + Xs.std(axis=0) > 0], Xs[:, Xr.std(axis=0) + Xs.std(axis=0) > 0]
    if len(Xr) > 2 and len(Xs) > 2:
        stat, p = energy(Xr, Xs, np.random.default_rng(seed))
        tests.append({"quantity": "fitted parameters (joint)", "test": "energy distance permutation",
                      "statistic": stat, "p_value": p, "real": {"n": len(Xr)}, "sim": {"n": len(Xs)}})
    return tests


def check_config(real: LotStats, config: str, seed: int = 1, limits: Limits | None = None) -> dict[str, Any]:
    """One config against the real lot: tests, the flagged ones, and a verdict."""
    if limits is None:
        limits = load_device(config)[3]
    boards = min(real.boards, MAX_SIM_BOARDS)
    sim, what = simulate_like(config, real, boards, seed, limits)
    tests = _tests(real, sim, seed)
    gaps = flag(tests)
    return {**what, "tests": tests, "gaps": [t["quantity"] for t in gaps],
            "verdict": "gap" if gaps else "no gap", "false_alarm_rate": FAMILY_ALPHA}


def check(real: LotStats, config: str, before: str | None, seed: int = 1, limits: Limits | None = None
          ) -> dict[str, Any]:
    """The gap before (``before``: e.g. the default config) and after (the twin ``config``)."""
    out: dict[str, Any] = {"boards": real.boards, "model": real.model, "false_alarm_rate": FAMILY_ALPHA,
                           "method": "Anderson-Darling k-sample per quantity, chi-square on verdict and reason "
                                     "counts, energy-distance permutation test on the joint fitted parameters; "
                                     f"Bonferroni: a test flags when p < {FAMILY_ALPHA:g} / (number of tests)"}
    after = check_config(real, config, seed, limits)
    if before is not None:
        b = check_config(real, before, seed, limits)
        out["before"] = {k: b[k] for k in ("config", "gaps", "verdict", "tests")}
    out.update({"config": config, "tests": after["tests"], "gaps": after["gaps"], "verdict": after["verdict"]})
    return out

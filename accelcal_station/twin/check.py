"""`twin check`: a simulated lot of the same size and design against the real one, quantity by
quantity (compare.py's tests, Bonferroni over them at compare.FAMILY_ALPHA), each with its
effect in the quantity's own units and whether it matters at the acceptance limits.

The simulated lot's seed is drawn at random unless given, and recorded in the output: two
checks of one twin draw different lots (a fixed seed would make every check of a twin test
the same simulated lot, and hide how much the verdict owes to that one draw)."""
from __future__ import annotations

import secrets

import numpy as np

from ..acceptance.rules import Limits
from .compare import ENERGY_MARGIN, FAMILY_ALPHA, counts_effect, counts_test, energy, flag, quantity_test, verdict
from .records import Before, CheckReport, ConfigCheck, CountsTest, JointTest, QuantityTest
from .simlot import TwinDevice, simulate_like
from .stream import FITTED, MEASURES, LotStats

MAX_SIM_BOARDS = 50_000  # a real lot larger than this is compared through its reservoir sample


def new_seed() -> int:
    """A fresh random seed (recorded by the caller, so the draw can be repeated)."""
    return secrets.randbelow(2**31)


def compare_stats(real: LotStats, sim: LotStats, seed: int, limits: dict[str, float] | None
                  ) -> list[QuantityTest]:
    """Every test of a check (module docstring), with effects; ``gap`` and ``detected`` marked."""
    tests: list[QuantityTest] = [quantity_test(q, real.column(q), sim.column(q), limits) for q in MEASURES]
    for name, r, s in (("verdict mix", real.verdicts, sim.verdicts), ("failure reasons", real.reasons, sim.reasons)):
        stat, p = counts_test(dict(r), dict(s))
        counts: CountsTest = {"quantity": name, "test": "chi2_contingency", "statistic": stat, "p_value": p,
                              "real": dict(r), "sim": dict(s),
                              "effect": counts_effect(dict(r), dict(s), real.boards, sim.boards)}
        tests.append(counts)
    cols = [real.columns.index(q) for q in FITTED]
    Xr, Xs = real.rows[:, cols], sim.rows[:, cols]
    Xr, Xs = Xr[np.all(np.isfinite(Xr), axis=1)], Xs[np.all(np.isfinite(Xs), axis=1)]
    Xr, Xs = Xr[:, Xr.std(axis=0) + Xs.std(axis=0) > 0], Xs[:, Xr.std(axis=0) + Xs.std(axis=0) > 0]
    if len(Xr) > 2 and len(Xs) > 2:
        stat, p = energy(Xr, Xs, np.random.default_rng(seed))
        joint: JointTest = {"quantity": "fitted parameters (joint)", "test": "energy distance permutation",
                            "statistic": stat, "p_value": p, "real": {"n": len(Xr)}, "sim": {"n": len(Xs)},
                            "effect": {"energy_distance": stat, "margin": f"energy distance > {ENERGY_MARGIN:g}",
                                       "material": bool(stat > ENERGY_MARGIN)}}
        tests.append(joint)
    flag(tests)
    return tests


def check_config(real: LotStats, device: TwinDevice, seed: int | None = None, limits: Limits | None = None
                 ) -> ConfigCheck:
    """One twin config (read once: simlot.twin_device) against the real lot: tests, the gaps that
    matter, the detected ones, a verdict; ``limits``: the config's own unless given."""
    limits = device.limits if limits is None else limits
    seed = new_seed() if seed is None else seed
    boards = min(real.boards, MAX_SIM_BOARDS)
    sim, what = simulate_like(device, real, boards, seed, limits)
    tests = compare_stats(real, sim, seed, limits.values)
    return {**what, "seed": seed, "tests": tests, "gaps": [t["quantity"] for t in tests if t.get("gap")],
            "detected": [t["quantity"] for t in tests if t.get("detected")],
            "verdict": verdict(tests), "false_alarm_rate": FAMILY_ALPHA}


METHOD = ("Anderson-Darling k-sample per quantity, chi-square on verdict and reason counts, energy-distance "
          "permutation test on the joint fitted parameters; Bonferroni: a test detects a gap when p < "
          f"{FAMILY_ALPHA:g} / (number of tests); a detected gap matters when its effect (Wasserstein distance, "
          "percentile shift, yield change at the acceptance limits) exceeds the stated margin")


def check(real: LotStats, device: TwinDevice, before: TwinDevice | None, seed: int | None = None,
          limits: Limits | None = None) -> CheckReport:
    """The gap before (``before``: e.g. the default config) and after (the twin config ``device``)."""
    seed = new_seed() if seed is None else seed
    config = device.path
    after = check_config(real, device, seed, limits)
    if before is None:
        return {"boards": real.boards, "model": real.model, "false_alarm_rate": FAMILY_ALPHA, "seed": seed,
                "method": METHOD, "config": config, "tests": after["tests"], "gaps": after["gaps"],
                "detected": after["detected"], "verdict": after["verdict"]}
    b = check_config(real, before, seed, limits)
    gone: Before = {"config": b["config"], "gaps": b["gaps"], "detected": b["detected"], "verdict": b["verdict"],
                    "tests": b["tests"]}
    return {"boards": real.boards, "model": real.model, "false_alarm_rate": FAMILY_ALPHA, "seed": seed,
            "method": METHOD, "before": gone, "config": config, "tests": after["tests"], "gaps": after["gaps"],
            "detected": after["detected"], "verdict": after["verdict"]}

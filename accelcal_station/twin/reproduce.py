"""Does a fitted twin reproduce the lot it was fitted on?  `twin fit`'s own check of the residual
and leave-one-out RMS distributions, and its warnings.

A lot is simulated from the finished twin (its population, physics and noise; a seed of its
own) and each of residual RMS and leave-one-out RMS is compared with the lot's by the check's
Anderson-Darling test (compare.quantity_test, Bonferroni over the two at FAMILY_ALPHA).  A
detected gap is a warning naming the quantity, its percentiles in the lot and in the twin, the
Wasserstein distance and whether it matters at the acceptance limits: no physics the twin
offers reproduces the lot's residuals then, and a what-if at a tighter residual limit will
not be trusted (whatif.py compares with the lot's own yield).

Tried and left out: a residual model per non-main component searched to match the residual
and leave-one-out distributions (a pose scatter of its own; a quadratic term of its own, the
next unmodelled nonlinearity).  On a lot whose 10 % subpopulation carries a cubic on the
whole reading (offset included), neither lowered the Anderson-Darling statistics against the
lot's below the twin's without them (10,000 boards), and the search cost ~10 simulated lots
per fit; the warning names the gap instead.
"""
from __future__ import annotations

from ..acceptance.rules import Limits
from ..jsontypes import JsonObject
from .compare import FAMILY_ALPHA, quantity_test
from .records import DistributionTest
from .simlot import simulate_cfg
from .stream import LotStats

COLUMNS = ("residual_rms_mg", "crossval_rms_mg")
MAX_BOARDS = 20_000


def residual_check(cfg: JsonObject, like: LotStats, seed: int, limits: Limits
                   ) -> tuple[list[DistributionTest], list[str]]:
    """The two tests (module docstring) and a warning per detected gap."""
    sim = simulate_cfg(cfg, like, min(max(like.boards, 2000), MAX_BOARDS), seed)
    tests = [quantity_test(c, like.column(c), sim.column(c), limits.values) for c in COLUMNS]
    level = FAMILY_ALPHA / len(tests)
    warnings = []
    for t in tests:
        t["detected"] = bool(t["p_value"] < level)
        if not t["detected"]:
            continue
        e, r, s = t["effect"], t["real"], t["sim"]
        where = "no limit judges it" if "limit" not in e else (
            f"at the current limit {e['limit']} {e['limit_value']:g}: boards beyond it lot "
            f"{e['beyond_limit_real']:.4f}, twin {e['beyond_limit_sim']:.4f}")
        warnings.append(f"{t['quantity']}: the twin does not reproduce the lot's distribution (Anderson-Darling "
                        f"p {t['p_value']:.2g}): p95 lot {r['p95']:.4g}, twin {s['p95']:.4g}; sd lot {r['sd']:.4g}, "
                        f"twin {s['sd']:.4g}; Wasserstein {e['wasserstein']:.3g} mg; "
                        f"{'a gap that matters' if e['material'] else 'detectable but immaterial'} ({where}); "
                        "a what-if at a tighter limit on it is not to be trusted")
    return tests, warnings



"""`twin whatif`: yield under changed acceptance limits, predicted from a lot simulated by the twin.

Each simulated board is fitted and judged twice: as measured (first pass) and, if it failed,
measured again with fresh noise (one retest; final yield = passed either time).  The
interval is for the yield a real lot of ``real_boards`` boards would show: a binomial
proportion estimated from ``n_sim`` simulated boards and observed on ``n_real`` real ones,
``p +- z sqrt(p (1 - p) (1 / n_sim + 1 / n_real))`` with ``p`` shrunk by half a board
(Agresti-Coull style) so an all-pass simulation still has a width; z = Z (99.7 %).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..acceptance.rules import LIMIT_KEYS, Limits
from ..errors import DataError
from .simlot import load_device, sim_chunks
from .stream import LotStats, collect

Z = 3.0


def parse_limits(items: tuple[str, ...], base: Limits) -> Limits:
    """``NAME=VALUE`` overrides of the config's limits (one-line errors naming what is allowed)."""
    values = dict(base.values)
    for it in items:
        name, sep, val = it.partition("=")
        if not sep or name not in LIMIT_KEYS:
            raise DataError(f"--limit {it!r}; allowed: NAME=VALUE with NAME one of {', '.join(LIMIT_KEYS)}")
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not (np.isfinite(v) and v >= 0):
            raise DataError(f"--limit {it!r}: {val!r} is not a non-negative number")
        values[name] = v
    return Limits(values)


def interval(passed: int, n_sim: int, n_real: int) -> tuple[float, float, float]:
    p = (passed + 0.5) / (n_sim + 1.0)
    half = float(Z * np.sqrt(p * (1 - p) * (1.0 / n_sim + 1.0 / max(n_real, 1))))
    return passed / n_sim, max(0.0, p - half), min(1.0, p + half)


def _reason_rates(stats: LotStats) -> dict[str, float]:
    return {k: v / max(stats.boards, 1) for k, v in stats.reasons.items()}


def whatif(config: str, like: LotStats, limits: Limits, boards: int = 20_000, seed: int = 3) -> dict[str, Any]:
    """Predicted first-pass and final yield under ``limits`` and the reasons that grow."""
    model, pop, range_g, base_limits = load_device(config)
    cpg = model.chip.counts_per_g(range_g)
    rng = np.random.default_rng(seed)
    x = None if pop is None else pop.draw(np.arange(boards), rng)
    runs = []
    for k, lim in enumerate((limits, limits, base_limits)):
        s = collect(sim_chunks(model, pop, boards, like, range_g, seed + 1 + (k == 1), x=x), like.model, cpg,
                    "counts", lim, reservoir=boards, seed=seed)
        runs.append(s)
    first, retest, base = runs
    ok1 = np.array([v == "PASS" for v, _ in first.codes])
    ok2 = np.array([v == "PASS" for v, _ in retest.codes])
    y, lo, hi = interval(int(ok1.sum()), boards, like.boards)
    yf, lof, hif = interval(int((ok1 | ok2).sum()), boards, like.boards)
    now, grow = _reason_rates(base), _reason_rates(first)
    grows = [{"reason": k, "before": now.get(k, 0.0), "after": v}
             for k, v in sorted(grow.items(), key=lambda kv: now.get(kv[0], 0.0) - kv[1]) if v > now.get(k, 0.0)]
    return {"config": config, "simulated_boards": boards, "real_boards": like.boards, "limits": limits.values,
            "first_pass_yield": {"value": y, "interval": [lo, hi]},
            "yield_after_one_retest": {"value": yf, "interval": [lof, hif]},
            "yield_now": base.verdicts.get("PASS", 0) / boards, "reasons_grow": grows,
            "interval_note": f"z = {Z:g} over a binomial of the simulated and the real lot's size"}

"""`twin whatif`: yield under changed acceptance limits, predicted from a lot simulated by the twin.

Each simulated board is fitted and judged twice: as measured (first pass) and, if it failed,
measured again with fresh noise (one retest; final yield = passed either time).  A failure
that passes the retest is noise-like; one that fails both times is systematic (the board
itself is beyond the limit) -- reported apart, as a retest only recovers the first kind.

The interval is for the yield a real lot of ``real_boards`` boards would show, with the
twin's own doubt: ``p +- z sqrt(s_param^2 + p (1 - p) (1 / n_sim + 1 / n_real))``, with
``s_param`` the yield's spread over populations perturbed as much as fitting them on the lot
allows (doubt.yield_replicates, a parametric bootstrap), the binomial term for the simulated
and the real lot's sampling, ``p`` shrunk by half a board (Agresti-Coull style) so an all-pass
simulation still has a width; z = Z (99.7 %).  Given the lot's own yield under the same
limits, a warning says when it falls outside the interval (the twin misses what these limits
judge).  The seed is drawn at random unless given, and recorded.
"""
from __future__ import annotations

import numpy as np

from ..acceptance.rules import LIMIT_KEYS, Limits
from ..errors import DataError
from .check import new_seed
from .doubt import yield_replicates
from .fit import MIXTURE_ROWS
from .records import ReasonGrowth, WhatIfReport
from .simlot import TwinDevice, sim_chunks
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


def interval(passed: int, n_sim: int, n_real: int, sd_param: float = 0.0) -> tuple[float, float, float]:
    p = (passed + 0.5) / (n_sim + 1.0)
    half = float(Z * np.sqrt(sd_param**2 + p * (1 - p) * (1.0 / n_sim + 1.0 / max(n_real, 1))))
    return passed / n_sim, max(0.0, p - half), min(1.0, p + half)


def _reason_rates(stats: LotStats) -> dict[str, float]:
    return {k: v / max(stats.boards, 1) for k, v in stats.reasons.items()}


def whatif(device: TwinDevice, like: LotStats, limits: Limits, boards: int = 20_000, seed: int | None = None,
           real_yield: float | None = None) -> WhatIfReport:
    """Predicted first-pass and final yield under ``limits``, the reasons that grow, the failures
    split noise-like / systematic, and (``real_yield``: the lot's own under ``limits``) a warning
    when the lot's yield lies outside the prediction."""
    seed = new_seed() if seed is None else seed
    model, pop, range_g, base_limits = device.model, device.population, device.range_g, device.limits
    cpg = model.chip.counts_per_g(range_g)
    rng = np.random.default_rng(seed)
    idx = np.arange(boards)
    x = None if pop is None else pop.draw(idx, rng)
    runs = []
    for k, lim in enumerate((limits, limits, base_limits)):
        s = collect(sim_chunks(model, pop, boards, like, range_g, seed + 1 + (k == 1), x=x), like.model, cpg,
                    "counts", lim, reservoir=boards, seed=seed)
        runs.append(s)
    first, retest, base = runs
    ok1 = np.array([v == "PASS" for v, _ in first.codes])
    ok2 = np.array([v == "PASS" for v, _ in retest.codes])
    n_fit = min(like.boards, MIXTURE_ROWS)
    sd1 = sdf = 0.0
    if pop is not None and x is not None:
        sd1 = float(np.std(yield_replicates(pop, x, idx, ok1, n_fit, rng)))
        sdf = float(np.std(yield_replicates(pop, x, idx, ok1 | ok2, n_fit, rng)))
    y, lo, hi = interval(int(ok1.sum()), boards, like.boards, sd1)
    yf, lof, hif = interval(int((ok1 | ok2).sum()), boards, like.boards, sdf)
    now, grow = _reason_rates(base), _reason_rates(first)
    grows: list[ReasonGrowth] = [{"reason": k, "before": now.get(k, 0.0), "after": v}
             for k, v in sorted(grow.items(), key=lambda kv: now.get(kv[0], 0.0) - kv[1]) if v > now.get(k, 0.0)]
    out: WhatIfReport = {
        "config": device.path, "seed": seed, "simulated_boards": boards, "real_boards": like.boards,
        "limits": limits.values,
        "first_pass_yield": {"value": y, "interval": [lo, hi], "parameter_sd": sd1},
        "yield_after_one_retest": {"value": yf, "interval": [lof, hif], "parameter_sd": sdf},
        "failures": {"noise_like": float(np.mean(~ok1 & ok2)), "systematic": float(np.mean(~ok1 & ~ok2)),
                     "note": "noise-like: failed, passed the retest; systematic: failed both times"},
        "yield_now": base.verdicts.get("PASS", 0) / boards, "reasons_grow": grows,
        "interval_note": f"z = {Z:g} over the twin's parameter uncertainty (bootstrap over the fitted population, "
                         f"{n_fit} boards) and a binomial of the simulated and the real lot's size",
        "warnings": []}
    if real_yield is not None:
        out["real_yield"] = real_yield
        if not lo <= real_yield <= hi:
            out["warnings"].append(
                f"the lot's own first-pass yield under these limits, {real_yield:.4f}, lies outside the prediction "
                f"[{lo:.4f}, {hi:.4f}]: the twin does not reproduce what these limits judge (see twin check and "
                "twin fit's warnings); do not trust this prediction or its retest figure")
    return out

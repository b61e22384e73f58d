"""Sim-to-real gap diagnosis: where real data leave the simulator, which catalog effect explains it.

1. Floor.  Fixed before any candidate is tried: the data's own within-pose spread
   (poses' std and n, or raw samples' first differences) where the data have it, else
   the simulator's noise and quantization, for a mean of n samples (fixed_floor).
2. Gap.  The configuration's deterministic effects (offset, gain, cross_axis, ...) are
   fitted on training folds (gap_effects.evaluate); the headline ``gap`` is the held-out
   residual RMS over the floor's RMS, so only residuals can move it (1.0: at the floor).
   Where it lies: where.breakdown.
3. Which (deterministic).  Each candidate term (candidates) is added and refitted; the best-scored
   candidate (held-out Gaussian log predictive density with the fixed floor) is taken
   when it passes a one-sided paired test (selection.p_greater) at ALPHA, Bonferroni over the
   step's candidates, shrinks the held-out residual RMS and at least MIN_GAP_SHRINK of
   the log gap, and passes its own rule (settling: amplitudes follow the step
   direction).  When it fails, the next candidate is tried (a failed best does not end
   the search).
4. Which (stochastic).  noise, pose_error, quantization and a random-walk drift change
   only the variance of what is left: each is judged by its own signature
   (diagnosis/effects) and reported under ``stochastic``; they never move the gap.
5. Verdict.  explained / partly explained / accounted for / unexplained / nothing to explain
   (verdict: "explained" needs the held-out gap within EXPLAINED_GAP_MAX of the floor), with the
   shape of what is left (shape), read from every view: axis, input level, temperature and
   acquisition order.  Confounding with acquisition order is judged by competition (order.py): every
   static candidate must beat the order trend (a change over the session) too; a selected effect's
   terms that follow order are named in ``confounded`` and it keeps the rest; one the trend explains
   as well, or whose evidence rests on its order-like terms, is ``confounded`` alone (confounding.py).
6. Headline.  `accelcal fit`'s held-out RMS for the same file and model terms over the floor (headline.py).

The record and its JSON are in result; the self-check is in selftest; loading in loading.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..errors import ConfigError, UnderdeterminedError
from ..jsontypes import JsonObject
from .candidates import candidates
from .confounding import resolve
from .effects.catalog import STOCHASTIC
from .effects.design import describe_design, static_design
from .effects.jig_rotation import jig_rotation
from .effects.order_trend import NAME as ORDER_TREND
from .evaluation import Evaluation
from .gap_data import GapData, TimeData, time_data
from .gap_effects import evaluate
from .headline import headline
from .loading import Simulator
from .noise_floor import Floor, sigma_from_within
from .order import trend_basis
from .order_trend import order_trend_json
from .result import Diagnosis
from .selection import ALPHA, select
from .shape import leftover_shape
from .verdict import verdict
from .where import breakdown


def fixed_floor(data: GapData, sim: Simulator, td: TimeData | None) -> Floor:
    """The floor every model is judged against, fixed before any candidate (module doc, step 1)."""
    fl = sim.floor(data.rate_hz)
    if data.site_g is not None:  # the site the data state is the gravity they are judged against (site.py)
        fl = replace(fl, gamma=data.site_g)
    n1 = np.maximum(data.n - 1.0, 1.0)
    if td is not None and np.any(np.isfinite(td.diff_var)):
        ok = np.isfinite(td.diff_var)
        w2 = np.array([np.sum(n1[ok[:, a]] * td.diff_var[ok[:, a], a]) / np.sum(n1[ok[:, a]]) for a in range(3)])
        lsb = td.lsb_g(np.ones(data.P, bool))  # the data's own value grid, when they sit on one
        q = lsb if lsb > 0 else fl.q_g
        return Floor(sigma_from_within(w2, q), q, fl.scatter_rad, fl.gamma, fl.sigma_g,
                     "within-capture spread of the raw samples (half the mean squared first difference) "
                     "and their value grid", fl.q_g)
    elif data.std_g is not None:
        w2 = np.sum(n1[:, None] * data.std_g**2, axis=0) / np.sum(n1)
        src = "within-pose spread of the data (std and n)"
    else:
        return Floor(fl.sigma_g, fl.q_g, fl.scatter_rad, fl.gamma, fl.sigma_g, "simulator noise and quantization")
    return Floor(sigma_from_within(w2, fl.q_g), fl.q_g, fl.scatter_rad, fl.gamma, fl.sigma_g, src)


def _stochastic(data: GapData, floor: Floor, final: Evaluation, td: TimeData | None, why: dict[str, str],
                alpha: float, ev_pose: Callable[[], Evaluation]) -> tuple[dict[str, JsonObject], list[str]]:
    """Each stochastic effect's own signature (module doc, step 4); those that pass, by evidence."""
    out: dict[str, JsonObject] = {}
    p_named: dict[str, float] = {}  # the signatures that passed, by p-value
    order = ["quantization"] + [n for n in STOCHASTIC if n != "quantization"]
    for name in order:
        eff = STOCHASTIC[name]
        ok, reason = eff.testable(data, td)
        if name == "pose_error" and ok and final.r_static is None:
            ok, reason = False, "the static view is unavailable"
        q = out.get("quantization", {})
        lsb_mg = q.get("lsb_mg")  # quantization's evidence (effects/quantization.py): a number when it passed
        if name == "noise" and q.get("passed") and isinstance(lsb_mg, float) \
                and lsb_mg > 2e3 * float(np.max(floor.simulator_sigma_g)):
            ok, reason = False, (f"the samples sit on a {lsb_mg:.3g} mg grid, over twice the simulated noise: "
                                 "the grid sets the within-pose spread, so the noise cannot be measured")
        if not ok:
            out[name] = {"testable": False, "reason": reason}
            continue
        sig = eff.signature(data, floor, ev_pose() if name == "pose_error" else final, td, alpha)
        out[name] = {"testable": True, **sig.to_json()}
        why.pop(name, None)
        if sig.passed:
            p_named[name] = sig.p_value
    return out, sorted(p_named, key=lambda n: p_named[n])


def diagnose(data: GapData, sim: Simulator, alpha: float = ALPHA) -> Diagnosis:
    """Floor, gap, where, which (deterministic, stochastic), verdict (module doc)."""
    if data.exclude:  # fit's model for these data has no terms for them (loading.fit_ground)
        sim = replace(sim, exclude=tuple(data.exclude))
    _check_sim(data, sim)
    td = time_data(data)
    floor = fixed_floor(data, sim, td)
    testable, why, static_ok, static_why = candidates(data, sim, td)
    if not static_ok and td is None:
        raw_no_rate = any("no sample rate" in n for n in data.notes)
        more = ("give --rate HZ for the time view within captures, or revisit the poses" if raw_no_rate
                else "give references, more poses, or raw logs with --raw")
        raise UnderdeterminedError(f"nothing to diagnose: {data.P} static poses found "
                                   f"({', '.join(data.names[:12])}{' ...' if data.P > 12 else ''}), and no gap "
                                   f"can be measured: {static_why}, and there are no raw captures ({more})")

    centres: list[np.ndarray | None] = [None]

    def ev(added: list[str]) -> Evaluation:
        """Held-out evaluation; a cubic or square term centred at 0 g or at the zero-g reading (a sensor's
        nonlinearity acts on its response to force), whichever fits the whole data better in-sample."""
        outs = []
        for z in (centres if {"cubic", "quadratic"} & set(added) else [None]):
            data.zero_g = z
            outs.append(evaluate(data, floor, sim.baseline, tuple(added), td, static_ok))
        data.zero_g = None
        return min(outs, key=lambda e: 0.0 if e.fitted_static is None else float(np.sum(e.fitted_static**2)))

    base = ev([])
    centres.append(_zero_g(base))
    why_no_trend = _order_competes(data, sim.baseline, static_ok)
    sel = select(ev, data, sim, base, testable, td, alpha, None if why_no_trend else ORDER_TREND)
    res = resolve(ev, data, base, sel, alpha)  # per-term confounds with acquisition order (confounding.py)
    final, selected, steps, confounded = res.final, res.selected, res.steps, res.confounded
    stoch, passed = _stochastic(data, floor, final, td, why, alpha, lambda: ev(selected + ["pose_error"]))
    if "pose_error" in stoch:
        stoch["pose_error"]["jig_rotation"] = jig_rotation(data, base, sim.baseline, floor.gamma, alpha)
    where = breakdown(data, sim, floor, base, final, td)
    d = Diagnosis(data, sim, floor, base, final, sel.ranking, steps,
                  selected + [p for p in passed if p not in selected], why, static_ok, static_why, where, alpha, stoch,
                  sel.tried)
    d.leftover = leftover_shape(data, final, td, alpha)
    d.confounded_with = confounded
    d.order_trend = order_trend_json(sel.order, why_no_trend, base, alpha)
    d.headline = headline(data, sim.baseline, base)
    d.verdict, d.verdict_text = verdict(d)
    d.identifiability = describe_design(data, sim.baseline + tuple(selected))
    return d


def _order_competes(data: GapData, base: tuple[str, ...], static_ok: bool) -> str:
    """Why the order trend cannot compete on these data ('' when it can): it needs the static view and
    training rows to spare beyond the baseline's and its own coefficients."""
    if not static_ok:
        return "the static view is unavailable"
    B, _ = trend_basis(data)
    if B.shape[1] == 0:
        return "too few poses in each file for a trend (four a coefficient)"
    p_train = data.P - math.ceil(data.P / data.n_folds)
    rows = p_train * (1 if data.norm_only else 3)
    n_base = len(static_design(set(base), data.g, data.ref, None, None, data.norm_only, data.n_temps)[3])
    if rows <= n_base + 3 * B.shape[1]:
        return (f"{data.P} poses are too few to fit the baseline and a trend over the session "
                f"({n_base} + {3 * B.shape[1]} coefficients) with poses held out")
    return ""


def _zero_g(base: Evaluation) -> np.ndarray:
    """The reading at zero force, -W^-1 V, of the baseline's whole-data fit (0 without an offset term)."""
    p = base.params
    ax = "xyz"
    V = np.array([p.get(f"offset:V_{a}", 0.0) for a in ax])
    W = np.eye(3)
    for i in range(3):
        for j in range(3):
            for e in ("gain", "cross_axis"):
                if f"{e}:W_{ax[i]}{ax[j]}" in p:
                    W[i, j] = p[f"{e}:W_{ax[i]}{ax[j]}"]
                    if i != j and f"{e}:W_{ax[j]}{ax[i]}" not in p:  # norm-only: symmetric W
                        W[j, i] = W[i, j]
    try:
        return -np.linalg.solve(W, V)
    except np.linalg.LinAlgError:
        return np.zeros(3)


def _check_sim(data: GapData, sim: Simulator) -> None:
    floor = sim.floor(data.rate_hz)
    if floor.q_g <= 0 and np.any(floor.sigma_g <= 0):
        # a zero floor makes every held-out ratio 0/0: there is nothing to compare the data with
        raise ConfigError(f"{sim.source}: the simulator predicts no noise on some axis (no noise density and no "
                          "quantization), so it claims exact readings; enable noise (and quantization) under "
                          "simulator.effects")
    # strict=False: counts_per_g may be left empty (GapData's default) when no file gave counts
    for src, cpg in zip(data.sources, data.counts_per_g, strict=False):
        if cpg is not None and abs(cpg / sim.counts_per_g - 1) > 0.05:
            data.notes.append(f"{src}: {cpg:.6g} counts/g, the simulator's board has {sim.counts_per_g:g} counts/g "
                              f"({sim.range_g} g range): another range or sensitivity; the analysis works in g, "
                              "so only the simulator's LSB in g may not hold")

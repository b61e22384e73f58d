"""Which deterministic candidate explains the gap: the paired test, the rules a candidate must pass,
the stopping rule and greedy forward selection (engine's module doc, step 3)."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeAlias, TypedDict

import numpy as np

from .evaluation import Evaluation
from .gap_data import GapData, TimeData
from .loading import Simulator

ALPHA = 0.01
MIN_GAP_SHRINK = 0.1  # an added effect must remove this fraction of log(gap) too


class Ranked(TypedDict):
    """A candidate of the first step, in score order (``ranking`` of diagnose --json)."""

    effect: str
    held_out_gap: float
    score: float
    p_value: float
    params: int
    rms_mg: float


class Tried(TypedDict):
    """A candidate tried at a step: accepted, or the rules it failed (``tried``)."""

    step: int
    effect: str
    accepted: bool
    failed: list[str]


# an added effect's fitted parameters, in the configuration's units where there is one
Fitted: TypeAlias = dict[str, float | list[float]]


class Step(TypedDict):
    """An effect added by the selection (``steps``): gap and RMS before and after, its test, its fit."""

    added: str
    gap_before: float
    gap_after: float
    rms_mg_before: float
    rms_mg_after: float
    p_value: float
    level: float
    fitted: Fitted  # the effect's own parameters (names and shapes differ per effect)
    order_trend_gap: float | None  # the competitor's held-out gap at this step (None: no competitor)
    p_value_vs_order: float | None  # the paired test of the effect against the order trend


class OrderLoss(TypedDict):
    """A candidate that beat the baseline but not the order trend (diagnosis/order.py): its figures and the
    competitor's at that step."""

    step: int
    held_out_gap: float
    rms_mg: float
    order_trend_gap: float
    order_trend_rms_mg: float
    p_value_vs_order: float

Evaluator = Callable[[list[str]], Evaluation]  # held-out evaluation of the baseline plus these candidates


def p_greater(d: np.ndarray) -> float:
    """One-sided paired p-value that per-pose score differences d tend to be > 0.

    The smaller of a t-test (power with few poses and a consistent effect) and a Wilcoxon
    signed-rank test (power with many poses and heavy tails), doubled: a Bonferroni union
    of the two, so the level holds whichever of them the data suit.
    """
    d = np.asarray(d, float)
    if len(d) < 2 or not np.any(d != d[0]):
        return 1.0 if len(d) < 2 or d[0] <= 0 else 0.0
    from scipy import stats  # on first use: scipy.stats costs a second at every command's start-up

    p_t = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue)
    p_w = float(stats.wilcoxon(d, alternative="greater").pvalue)
    return min(1.0, 2 * min(p_t, p_w))


def explained(e: Evaluation, alpha: float = ALPHA) -> bool:
    """Whether every view's held-out residuals lie in the two-sided 1 - alpha/views range of chi^2_N / N.

    Standardised by floor + the fit's own prediction variance (both fixed by the design):
    a model that explains the data leaves a mean square of chi^2_N / N.
    """
    from scipy import stats

    views = [(r, v) for r, v in ((e.r_static, e.v_static), (e.r_time, e.v_time)) if r is not None]
    for r, v in views:
        a = alpha / len(views)  # Bonferroni over the views
        lo, hi = stats.chi2.ppf([a / 2, 1 - a / 2], r.size) / r.size
        if not lo <= np.sum(r**2 / v) / r.size <= hi:
            return False
    return True


def _settling_rule(ev: Evaluation, td: TimeData | None, alpha: float) -> tuple[bool, float]:
    """A settling transient follows the step that caused it: its amplitudes a (per capture and axis)
    have a consistent sign relative to the step direction (two-sided Wilcoxon on a * sign(step))."""
    a = ev.params.get("_settling_a_g")
    if a is None or td is None:
        return False, 1.0
    m = np.abs(td.step_unit) > 0.3
    x = (np.asarray(a) * np.sign(td.step_unit))[m]
    if len(x) < 6 or not np.any(x != 0):
        return False, 1.0
    from scipy import stats

    p = float(stats.wilcoxon(x).pvalue)
    return p < alpha, p


def _rules(cur: Evaluation, new: Evaluation, p: float, level: float, effect: str, td: TimeData | None,
           alpha: float) -> list[str]:
    """The rules a candidate must pass to be added (engine's module doc, step 3); the failed ones."""
    failed = []
    if p >= level:
        failed.append(f"paired test p = {p:.3g} >= {level:.3g}")
    if new.rms_g >= cur.rms_g:
        failed.append(f"held-out RMS did not shrink ({1e3 * cur.rms_g:.4g} -> {1e3 * new.rms_g:.4g} mg)")
    shrinks = []
    for view in ("static", "time"):  # a term may act in one view only (settling: within captures)
        a, b = cur.floor_gap(view), new.floor_gap(view)
        if a is not None and b is not None:
            shrinks.append(abs(math.log(max(b, 1e-300))) <= (1 - MIN_GAP_SHRINK) * abs(math.log(max(a, 1e-300))))
    if not any(shrinks):
        failed.append(f"gap {cur.gap:.3g} -> {new.gap:.3g}: no view loses {MIN_GAP_SHRINK:.0%} of its log gap")
    elif new.gap >= cur.gap:  # one view better, the headline worse: it explains nothing overall
        failed.append(f"held-out gap grew ({cur.gap:.3g} -> {new.gap:.3g} x the floor)")
    if effect == "settling":
        ok, ps = _settling_rule(new, td, alpha)
        if not ok:
            failed.append(f"transient amplitudes do not follow the step direction (p = {ps:.3g})")
    return failed


def _fitted(e: Evaluation, effect: str, sim: Simulator, data: GapData) -> Fitted:
    """The fitted values of an added effect, in the configuration's units where there is one."""
    p = e.params
    if effect == "noise":
        enbw = sim.model.chip.enbw_hz(data.rate_hz or sim.odr_hz, sim.dlpf)
        return {"density_ug_per_rthz": [1e6 * s / math.sqrt(enbw) for s in _per_axis(p["sigma_g"])]}
    if effect == "quantization":
        lsb = _number(p["lsb_g"])
        return {"lsb_counts": lsb * sim.counts_per_g, "lsb_mg": 1e3 * lsb}
    if effect == "pose_error":
        return {"scatter_deg": _number(p["scatter_deg"])}
    out = {k.split(":", 1)[1]: _as_json(v) for k, v in p.items() if k.startswith(effect + ":")}
    out.update({k: _as_json(v) for k, v in p.items() if k.startswith(effect)})
    return out


def _number(v: float | list[float] | np.ndarray) -> float:
    if not isinstance(v, float | int):
        raise TypeError("a per-axis value where one number is fitted")
    return v


def _per_axis(v: float | list[float] | np.ndarray) -> list[float]:
    if isinstance(v, float | int):
        raise TypeError("one number where a per-axis value is fitted")
    return v if isinstance(v, list) else v.tolist()


def _as_json(v: float | list[float] | np.ndarray) -> float | list[float]:
    return v.tolist() if isinstance(v, np.ndarray) else v


@dataclass
class Competitor:
    """The order trend (diagnosis/order.py) at one step: its evaluation, and the candidates it explains as well."""

    ev: Evaluation | None
    lost: dict[str, OrderLoss] = field(default_factory=dict)
    first: Evaluation | None = None  # the order trend on the baseline alone (the first step's)


def _vs_order(comp: Competitor, new: Evaluation, units: np.ndarray, alpha: float) -> float | None:
    """One-sided paired p-value that ``new`` beats the order trend (None: no competitor).  At alpha, not
    Bonferroni-divided: one comparison per candidate, and a lower bar here only keeps an effect selected."""
    return None if comp.ev is None else p_greater((comp.ev.nll_unit - new.nll_unit)[units])


@dataclass(frozen=True)
class _Search:
    """What every greedy step works with: the evaluator, the data and the simulator, the units the paired
    test counts (``units``), the time view, the level and the order-trend competitor (updated per step)."""

    ev: Evaluator
    data: GapData
    sim: Simulator
    units: np.ndarray
    td: TimeData | None
    alpha: float
    comp: Competitor


def _step(search: _Search, current: Evaluation, remaining: list[str], selected: list[str],
          ) -> tuple[Evaluation | None, Step | None, list[Ranked], list[Tried]]:
    """One greedy step: candidates in score order, the first that passes every rule (or None)."""
    ev, data, sim, units, td, alpha, comp = (search.ev, search.data, search.sim, search.units, search.td,
                                             search.alpha, search.comp)
    evs = {c: ev(selected + [c]) for c in remaining}
    pv = {c: p_greater((current.nll_unit - evs[c].nll_unit)[units]) for c in remaining}
    order = sorted(remaining, key=lambda c: evs[c].score)
    best = order[0]
    tied = [c for c in order if c == best or p_greater((evs[c].nll_unit - evs[best].nll_unit)[units]) >= alpha]
    choice = min(tied, key=lambda c: (evs[c].n_params, evs[c].score))
    order.remove(choice)
    order.insert(0, choice)
    level = alpha / len(remaining)
    ranking: list[Ranked] = [{"effect": c, "held_out_gap": evs[c].gap, "score": evs[c].score, "p_value": pv[c],
                "params": evs[c].n_params, "rms_mg": 1e3 * evs[c].rms_g} for c in order]
    tried: list[Tried] = []
    for c in order:
        failed = _rules(current, evs[c], pv[c], level, c, td, alpha)
        p_o = None if failed or c in ORDER_EXEMPT else _vs_order(comp, evs[c], units, alpha)
        if p_o is not None and p_o >= alpha and comp.ev is not None:
            failed.append(f"a smooth change over the session (order trend) explains the gap as well: held-out gap "
                          f"{evs[c].gap:.3g} against the order trend's {comp.ev.gap:.3g}, p = {p_o:.3g} >= {alpha:g}")
            comp.lost[c] = {"step": len(selected) + 1, "held_out_gap": evs[c].gap, "rms_mg": 1e3 * evs[c].rms_g,
                            "order_trend_gap": comp.ev.gap, "order_trend_rms_mg": 1e3 * comp.ev.rms_g,
                            "p_value_vs_order": p_o}
        tried.append({"step": len(selected) + 1, "effect": c, "accepted": not failed, "failed": failed})
        if not failed:
            step: Step = {"added": c, "gap_before": current.gap, "gap_after": evs[c].gap,
                    "rms_mg_before": 1e3 * current.rms_g, "rms_mg_after": 1e3 * evs[c].rms_g,
                    "p_value": pv[c], "level": level, "fitted": _fitted(evs[c], c, sim, data),
                    "order_trend_gap": None if comp.ev is None else comp.ev.gap, "p_value_vs_order": p_o}
            return evs[c], step, ranking, tried
    return None, None, ranking, tried


# time effects are changes over the session themselves, and temperature is measured per pose (temp_c) and
# stepped set point after set point by any thermal plan: they never compete with the order trend
ORDER_EXEMPT = ("drift", "settling", "temperature")


@dataclass
class Selection:
    """What select found: the final evaluation, the selected effects, their steps, the first step's ranking,
    every candidate tried, and the order trend (its last evaluation, the candidates it explained as well)."""

    final: Evaluation
    selected: list[str]
    steps: list[Step]
    ranking: list[Ranked]
    tried: list[Tried]
    order: Competitor


def select(ev: Evaluator, data: GapData, sim: Simulator, base: Evaluation, testable: list[str],
           td: TimeData | None, alpha: float, order_trend: str | None = None) -> Selection:
    """Greedy forward selection of deterministic candidates (engine's module doc, step 3); ``order_trend``:
    the name of the competitor every static candidate must beat too (None: none can be fitted)."""
    # a norm-only static view scores one unit per pose: its structural zeros would inflate the test's n
    units = base.nll_unit != 0
    current = base
    selected: list[str] = []
    steps: list[Step] = []
    tried: list[Tried] = []
    ranking: list[Ranked] | None = None
    remaining = list(testable)
    comp = Competitor(None)
    search = _Search(ev, data, sim, units, td, alpha, comp)
    if order_trend is not None and explained(current, alpha):
        comp.first = ev([order_trend])  # reported even when nothing is left to explain
    while remaining and not explained(current, alpha):
        comp.ev = None if order_trend is None else ev(selected + [order_trend])
        comp.first = comp.first or comp.ev
        new, step, rank, tr = _step(search, current, remaining, selected)
        ranking = ranking or rank
        tried += tr
        if new is None or step is None:
            break
        selected.append(step["added"])
        steps.append(step)
        current = new
        remaining.remove(step["added"])
        comp.lost = {k: v for k, v in comp.lost.items() if k != step["added"]}
    return Selection(current, selected, steps, ranking or [], tried, comp)

"""Sim-to-real gap diagnosis: where real data leave the simulator, which catalog effect explains it.

1. Floor.  Fixed before any candidate is tried: the data's own within-pose spread
   (poses' std and n, or raw samples' first differences) where the data have it, else
   the simulator's noise and quantization, for a mean of n samples (fixed_floor).
2. Gap.  The configuration's deterministic effects (offset, gain, cross_axis, ...) are
   fitted on training folds (gap_effects.evaluate); the headline ``gap`` is the held-out
   residual RMS over the floor's RMS, so only residuals can move it (1.0: at the floor).
3. Which (deterministic).  Each candidate term is added and refitted; the best-scored
   candidate (held-out Gaussian log predictive density with the fixed floor) is taken
   when it passes a one-sided paired test (_p_greater) at ALPHA, Bonferroni over the
   step's candidates, shrinks the held-out residual RMS and at least MIN_GAP_SHRINK of
   the log gap, and passes its own rule (settling: amplitudes follow the step
   direction).  When it fails, the next candidate is tried (a failed best does not end
   the search).
4. Which (stochastic).  noise, pose_error, quantization and a random-walk drift change
   only the variance of what is left: each is judged by its own signature
   (accelcal_station.effects) and reported under ``stochastic``; they never move the gap.
5. Verdict.  explained / partly explained / unexplained / nothing to explain, with the
   shape of what is left (diagnose_shape).

The self-check is in diagnose_selftest; loading in diagnose_load.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .diagnose_load import FITTED, Simulator, gap_data, load_data, load_simulator, raw_part  # noqa: F401  (API)
from .diagnose_shape import leftover_shape
from .effects import DETERMINISTIC, STOCHASTIC, Saturation
from .effects.jig_rotation import jig_rotation
from .errors import ConfigError, UnderdeterminedError
from .gap_effects import (Evaluation, Floor, GapData, TimeData, describe_design, design_rank_ok, evaluate,
                          random_var, sigma_from_within, static_design, time_data)
from .sensor_model import EFFECT_NAMES

ALPHA = 0.01
MIN_GAP_SHRINK = 0.1  # an added effect must remove this fraction of log(gap) too


# -- candidates ------------------------------------------------------------------------------------

def candidates(data: GapData, sim: Simulator, td: TimeData | None) -> tuple[list[str], dict[str, str], bool, str]:
    """(testable candidates, {effect: why not}, static view usable, why not)."""
    base = sim.baseline
    why: dict[str, str] = {}
    static_ok, static_why = True, ""
    ok, cond = design_rank_ok(base, data, data.norm_only)
    p_train = data.P - math.ceil(data.P / data.n_folds)

    def dof(effects) -> int:
        A_cols = len(_labels(effects, data))
        return p_train - (A_cols if data.norm_only else math.ceil(A_cols / 3))

    if not ok:
        words = describe_design(data, base).get("text", f"condition {cond:.3g}")
        static_ok, static_why = False, f"these poses do not determine the baseline ({', '.join(base)}): {words}"
    elif dof(base) < 0:
        static_ok = False
        static_why = (f"{data.P} poses are too few to fit the baseline ({len(_labels(base, data))} parameters"
                      f"{' on the norm' if data.norm_only else ' over 3 channels'}) with a pose held out")
    testable = []
    for e in EFFECT_NAMES:
        if e in base or e not in DETERMINISTIC:
            continue  # stochastic only: judged by its own signature (_stochastic), never by the gap
        eff = DETERMINISTIC[e]
        ok, reason = eff.testable(data, td)
        if eff.static_columns and not eff.time_columns and not static_ok:
            why[e] = f"the static view is unavailable: {static_why}"
        elif not ok:
            why[e] = Saturation.reason(data, sim.clip_g) if isinstance(eff, Saturation) else reason
        elif eff.time_columns:
            testable.append(e)  # judged in the time view too: the static view's rank does not gate it
        else:
            why_not = _static_why_not(data, base, eff, dof)
            if why_not:
                why[e] = why_not
            else:
                testable.append(e)
    return testable, why, static_ok, static_why


def _static_why_not(data: GapData, base: tuple[str, ...], eff, dof) -> str:
    """Why the static view cannot fit ``eff`` on top of the baseline ('' when it can)."""
    ok, cond = design_rank_ok(base + (eff.name,), data, data.norm_only)
    if not ok:
        words = describe_design(data, base + (eff.name,)).get("text", f"condition {cond:.3g}")
        return f"{eff.degenerate} ({words})"
    if dof(base + (eff.name,)) < 0:
        return f"{data.P} poses are too few to fit its parameters with a pose held out"
    return ""


def _labels(effects, data: GapData):
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    return static_design(set(effects), data.g, data.ref, dT, dh, data.norm_only, data.n_temps)[3]


# -- the diagnosis ---------------------------------------------------------------------------------

@dataclass
class Diagnosis:
    data: GapData
    sim: Simulator
    floor: Floor
    base: Evaluation
    final: Evaluation
    ranking: list[dict]
    steps: list[dict]
    selected: list[str]
    untestable: dict[str, str]
    static_ok: bool
    static_why: str
    where: dict
    alpha: float = ALPHA
    stochastic: dict = field(default_factory=dict)
    tried: list[dict] = field(default_factory=list)
    verdict: str = ""
    verdict_text: str = ""
    leftover: dict = field(default_factory=dict)
    identifiability: dict = field(default_factory=dict)

    @property
    def gap_before(self) -> float:
        return self.base.gap

    @property
    def gap_after(self) -> float:
        return self.final.gap


def _p_greater(d: np.ndarray) -> float:
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


def fixed_floor(data: GapData, sim: Simulator, td: TimeData | None) -> Floor:
    """The floor every model is judged against, fixed before any candidate (module doc, step 1)."""
    fl = sim.floor(data.rate_hz)
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


def _rules(cur: Evaluation, new: Evaluation, p: float, level: float, effect: str, td, alpha) -> list[str]:
    """The rules a candidate must pass to be added (module doc, step 3); the failed ones."""
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
    if effect == "settling":
        ok, ps = _settling_rule(new, td, alpha)
        if not ok:
            failed.append(f"transient amplitudes do not follow the step direction (p = {ps:.3g})")
    return failed


def _step(ev, data, sim, current, remaining, selected, units, td, alpha):
    """One greedy step: candidates in score order, the first that passes every rule (or None)."""
    evs = {c: ev(selected + [c]) for c in remaining}
    pv = {c: _p_greater((current.nll_unit - evs[c].nll_unit)[units]) for c in remaining}
    order = sorted(remaining, key=lambda c: evs[c].score)
    best = order[0]
    tied = [c for c in order if c == best or _p_greater((evs[c].nll_unit - evs[best].nll_unit)[units]) >= alpha]
    choice = min(tied, key=lambda c: (evs[c].n_params, evs[c].score))
    order.remove(choice)
    order.insert(0, choice)
    level = alpha / len(remaining)
    ranking = [{"effect": c, "held_out_gap": evs[c].gap, "score": evs[c].score, "p_value": pv[c],
                "params": evs[c].n_params, "rms_mg": 1e3 * evs[c].rms_g} for c in order]
    tried = []
    for c in order:
        failed = _rules(current, evs[c], pv[c], level, c, td, alpha)
        tried.append({"step": len(selected) + 1, "effect": c, "accepted": not failed, "failed": failed})
        if not failed:
            step = {"added": c, "gap_before": current.gap, "gap_after": evs[c].gap,
                    "rms_mg_before": 1e3 * current.rms_g, "rms_mg_after": 1e3 * evs[c].rms_g,
                    "p_value": pv[c], "level": level, "fitted": _fitted(evs[c], c, sim, data)}
            return evs[c], step, ranking, tried
    return None, None, ranking, tried


def _select(ev, data, sim, base, testable, td, alpha):
    """Greedy forward selection of deterministic candidates (module doc, step 3)."""
    # a norm-only static view scores one unit per pose: its structural zeros would inflate the test's n
    units = base.nll_unit != 0
    current, selected, steps, tried, ranking = base, [], [], [], None
    remaining = list(testable)
    while remaining and not explained(current, alpha):
        new, step, rank, tr = _step(ev, data, sim, current, remaining, selected, units, td, alpha)
        ranking = ranking or rank
        tried += tr
        if new is None:
            break
        selected.append(step["added"])
        steps.append(step)
        current = new
        remaining.remove(step["added"])
    return current, selected, steps, ranking or [], tried


def _stochastic(data, floor, final, td, why, alpha, ev_pose=None) -> tuple[dict, list[str]]:
    """Each stochastic effect's own signature (module doc, step 4); those that pass, by evidence."""
    out: dict = {}
    order = ["quantization"] + [n for n in STOCHASTIC if n != "quantization"]
    for name in order:
        eff = STOCHASTIC[name]
        ok, reason = eff.testable(data, td)
        if name == "pose_error" and ok and final.r_static is None:
            ok, reason = False, "the static view is unavailable"
        q = out.get("quantization", {})
        if name == "noise" and q.get("passed") and q["lsb_mg"] > 2e3 * float(np.max(floor.sim_sigma_g)):
            ok, reason = False, (f"the samples sit on a {q['lsb_mg']:.3g} mg grid, over twice the simulated noise: "
                                 "the grid sets the within-pose spread, so the noise cannot be measured")
        if not ok:
            out[name] = {"testable": False, "reason": reason}
            continue
        sig = eff.signature(data, floor, ev_pose() if name == "pose_error" else final, td, alpha)
        out[name] = {"testable": True, **sig.to_json()}
        why.pop(name, None)
    passed = sorted((n for n, v in out.items() if v.get("passed")), key=lambda n: out[n]["p_value"])
    return out, passed


def final_effects(ev: Evaluation) -> set[str]:
    return {k.split(":", 1)[0] for k in ev.params if ":" in k}


def diagnose(data: GapData, sim: Simulator, alpha: float = ALPHA) -> Diagnosis:
    """Floor, gap, where, which (deterministic, stochastic), verdict (module doc)."""
    _check_sim(data, sim)
    td = time_data(data)
    floor = fixed_floor(data, sim, td)
    testable, why, static_ok, static_why = candidates(data, sim, td)
    if not static_ok and td is None:
        raise UnderdeterminedError(f"nothing to diagnose: {static_why}, and there are no raw captures "
                                   "(give references, more poses, or raw logs with --raw)")

    centres = [None]

    def ev(added):
        """Held-out evaluation; a cubic or square term centred at 0 g or at the zero-g reading (a sensor's
        nonlinearity acts on its response to force), whichever fits the whole data better in-sample."""
        outs = []
        for z in (centres if {"cubic", "quadratic"} & set(added) else [None]):
            data.zero_g = z
            outs.append(evaluate(data, floor, sim.baseline, tuple(added), td, static_ok))
        data.zero_g = None
        return min(outs, key=lambda e: 0.0 if e.fitted_static is None else float(np.sum(e.fitted_static**2)))

    base = ev(())
    centres.append(_zero_g(base))
    final, selected, steps, ranking, tried = _select(ev, data, sim, base, testable, td, alpha)
    stoch, passed = _stochastic(data, floor, final, td, why, alpha, lambda: ev(selected + ["pose_error"]))
    if "pose_error" in stoch:
        stoch["pose_error"]["jig_rotation"] = jig_rotation(data, base, sim.baseline, floor.gamma, alpha)
    where = breakdown(data, sim, floor, base, final, td)
    d = Diagnosis(data, sim, floor, base, final, ranking, steps, selected + [p for p in passed if p not in selected], why, static_ok, static_why,
                  where, alpha, stoch, tried)
    d.leftover = leftover_shape(data, final, td, alpha)
    d.verdict, d.verdict_text = verdict(d)
    d.identifiability = describe_design(data, sim.baseline + tuple(selected))
    return d


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
    for src, cpg in zip(data.sources, data.counts_per_g):
        if cpg is not None and abs(cpg / sim.counts_per_g - 1) > 0.05:
            data.notes.append(f"{src}: {cpg:.6g} counts/g, the simulator's board has {sim.counts_per_g:g} counts/g "
                              f"({sim.range_g} g range): another range or sensitivity; the analysis works in g, "
                              "so only the simulator's LSB in g may not hold")


def at_floor(e: Evaluation, alpha: float = ALPHA) -> bool:
    """Whether no view's mean squared standardised held-out residual lies above the 1 - alpha/views
    quantile of chi^2_N / N (one-sided: residuals below their prediction leave nothing to explain)."""
    from scipy import stats

    views = [(r, v) for r, v in ((e.r_static, e.v_static), (e.r_time, e.v_time)) if r is not None]
    return all(np.sum(r**2 / v) <= stats.chi2.ppf(1 - alpha / len(views), r.size) for r, v in views)


def verdict(d: Diagnosis) -> tuple[str, str]:
    """explained / partly explained / unexplained / nothing to explain (module doc, step 5)."""
    base_ok, final_ok = at_floor(d.base, d.alpha), at_floor(d.final, d.alpha)
    stoch = [n for n in d.selected if n in STOCHASTIC]
    shape = d.leftover.get("summary", "")
    if base_ok and not d.selected:
        return "nothing to explain", "the held-out residuals are at the floor: the simulator describes these data"
    if final_ok:
        return "explained", f"{', '.join(d.selected)} explain{'s' if len(d.selected) == 1 else ''} the gap"
    if stoch and not _excess_beyond(d, stoch):
        return "explained", (f"{', '.join(d.selected)}: the residual left above the floor has the signature of "
                             f"{', '.join(stoch)} (reported under stochastic; it does not lower the gap)")
    if d.steps and d.final.rms_g < d.base.rms_g:
        return "partly explained", (f"{', '.join(d.selected)} shrink the held-out residual "
                                    f"({1e3 * d.base.rms_g:.3g} -> {1e3 * d.final.rms_g:.3g} mg); what is left: {shape}")
    return "unexplained", f"no catalog effect explains the gap; what is left: {shape}"


def _excess_beyond(d: Diagnosis, stoch: list[str]) -> bool:
    """Whether the final residuals exceed the floor by more than the named stochastic effects account for.

    The floor already holds the data's own within-pose spread and value grid, so noise and
    quantization cannot account for residuals above it; a pose error accounts for an excess of
    the static view only, when the time view (if any) is at its floor.
    """
    if "pose_error" not in stoch:
        return True
    if d.final.r_time is None:
        return False
    N = d.final.r_time.size
    from scipy import stats

    return float(np.sum(d.final.r_time**2 / d.final.v_time)) > stats.chi2.ppf(1 - d.alpha, N)


def _fitted(e: Evaluation, effect: str, sim: Simulator, data: GapData) -> dict:
    """The fitted values of an added effect, in the configuration's units where there is one."""
    p = e.params
    if effect == "noise":
        enbw = sim.model.chip.enbw_hz(data.rate_hz or sim.odr_hz, sim.dlpf)
        return {"density_ug_per_rthz": [1e6 * s / math.sqrt(enbw) for s in p["sigma_g"]]}
    if effect == "quantization":
        return {"lsb_counts": p["lsb_g"] * sim.counts_per_g, "lsb_mg": 1e3 * p["lsb_g"]}
    if effect == "pose_error":
        return {"scatter_deg": p["scatter_deg"]}
    out = {k.split(":", 1)[1]: v for k, v in p.items() if k.startswith(effect + ":")}
    out.update({k: v for k, v in p.items() if k.startswith(effect)})
    return out


# -- where -----------------------------------------------------------------------------------------

def _ratio(r, v) -> float | None:
    r, v = np.asarray(r), np.asarray(v)
    return float(np.sqrt(np.sum(r**2) / np.sum(v))) if r.size and np.sum(v) > 0 else None


def allan(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of one axis at octave cluster sizes: (tau_s, adev)."""
    n = len(x)
    c = np.concatenate([[0.0], np.cumsum(x)])
    ms = 2 ** np.arange(0, max(1, int(np.log2(max(n // 4, 1))) + 1))
    out = []
    for m in ms:
        avg = (c[m:] - c[:-m]) / m
        d = avg[m:] - avg[:-m]
        out.append(np.sqrt(0.5 * np.mean(d**2)) if len(d) else np.nan)
    return ms / rate_hz, np.array(out)


def breakdown(data: GapData, sim: Simulator, floor: Floor, base: Evaluation, after: Evaluation,
              td: TimeData | None) -> dict:
    """Where the baseline's held-out gap lies (module doc, step 2)."""
    w: dict = {"views": {"static": base.view_gap("static"), "time": base.view_gap("time")}}
    if base.r_static is not None:
        r, v = base.r_static, base.v_static
        z = np.sqrt(np.mean(r**2 / v, axis=1))
        w["by_pose"] = [{"pose": data.names[i], "z_rms": float(z[i]), "residual_mg": (1e3 * r[i]).tolist()}
                        for i in np.argsort(-z)[:5]]
        if not data.norm_only:
            w["by_axis"] = {a: _ratio(r[:, c], v[:, c]) for c, a in enumerate("xyz")}
        edges = np.array([-1.5, -0.6, -0.2, 0.2, 0.6, 1.5])
        lv = []
        for c, a in enumerate("xyz"):
            rc = r[:, c] if not data.norm_only else r[:, 0]
            vc = v[:, c] if not data.norm_only else v[:, 0]
            b = np.digitize(data.g[:, c], edges[1:-1])
            for k in range(len(edges) - 1):
                m = b == k
                if m.any():
                    lv.append({"axis": a, "level_g": [float(edges[k]), float(edges[k + 1])], "poses": int(m.sum()),
                               "mean_residual_mg": float(1e3 * rc[m].mean()), "gap": _ratio(rc[m], vc[m])})
        w["by_level"] = lv
        if data.temp_c is not None and data.n_temps >= 2:
            tk = np.round(data.temp_c / 2.0)
            w["by_temperature"] = [{"temp_c": float(np.mean(data.temp_c[tk == t])), "gap": _ratio(r[tk == t], v[tk == t]),
                                    "mean_residual_mg": (1e3 * r[tk == t].mean(axis=0)).tolist()}
                                   for t in np.unique(tk)]
    if td is not None and base.r_time is not None:
        blk = np.round(td.t_in / max(np.max(td.t_in), 1e-9) * 7).astype(int)
        proj = np.sign(td.step_unit[td.unit, td.axis]) * base.r_time
        w["by_time_in_capture"] = [{"t_s": float(np.mean(td.t_in[blk == k])), "gap": _ratio(base.r_time[blk == k],
                                    base.v_time[blk == k]), "toward_step_mg": float(1e3 * np.mean(proj[blk == k]))}
                                   for k in np.unique(blk)]
        w["by_axis_time"] = {a: _ratio(base.r_time[td.axis == c], base.v_time[td.axis == c])
                             for c, a in enumerate("xyz")}
    sim_sig = floor.sim_sigma_g if floor.sim_sigma_g is not None else floor.sigma_g
    sim_rand = np.sqrt(random_var(sim_sig, floor.q_g))
    meas = None
    if td is not None:
        meas = np.sqrt(np.nanmean(td.diff_var, axis=0))
    elif data.std_g is not None:
        meas = np.sqrt(np.mean(data.std_g**2, axis=0))
    if meas is not None:
        w["noise"] = {"sigma_mg": (1e3 * meas).tolist(), "simulator_sigma_mg": (1e3 * sim_rand).tolist(),
                      "ratio": (meas / np.where(sim_rand > 0, sim_rand, np.nan)).tolist(),
                      "rate_hz": data.rate_hz or sim.odr_hz}
    if data.captures is not None and data.rate_hz and td is not None:  # td: None when captures are too short
        longest = max(data.captures, key=lambda c: len(c.t))
        x = longest.x / longest.per_g
        taus, ad = zip(*[allan(x[:, a], data.rate_hz) for a in range(3)])
        white = np.sqrt(np.nanmean(td.diff_var, axis=0))[:, None] / np.sqrt(taus[0] * data.rate_hz)[None]
        w["allan"] = {"tau_s": taus[0].tolist(), "adev_mg": (1e3 * np.array(ad)).tolist(),
                      "white_mg": (1e3 * white).tolist(),
                      "ratio_at_longest_tau": (np.array(ad)[:, -1] / white[:, -1]).tolist()}
    w["max_reading_g"] = float(np.max(np.abs(data.g)))
    return w


# -- JSON --------------------------------------------------------------------------------------------

def to_json(d: Diagnosis) -> dict:
    data, fl = d.data, d.floor
    floor_rms = [float(np.sqrt(np.mean(x))) for x in (d.base.floor_static, d.base.floor_time) if x is not None]
    return {
        "verdict": d.verdict, "verdict_text": d.verdict_text,
        "gap_before": d.gap_before, "gap_after": d.gap_after,
        "rms_mg_before": 1e3 * d.base.rms_g, "rms_mg_after": 1e3 * d.final.rms_g,
        "floor_mg": 1e3 * float(np.sqrt(np.mean(np.square(floor_rms)))),
        "floor": {"source": fl.source, "sigma_mg": (1e3 * np.asarray(fl.sigma_g)).tolist(), "lsb_mg": 1e3 * fl.q_g,
                  "pose_scatter_deg": math.degrees(fl.scatter_rad)},
        "selected": d.selected, "steps": d.steps, "tried": d.tried, "ranking": d.ranking,
        "stochastic": d.stochastic, "left": d.leftover, "identifiability": d.identifiability,
        "untestable": [{"effect": e, "reason": r} for e, r in d.untestable.items()],
        "baseline": list(d.sim.baseline), "config": d.sim.source, "config_effects": list(d.sim.enabled),
        "test": {"gap": "held-out residual RMS over the floor's RMS; the floor is fixed before any candidate, so "
                        "only residuals move the gap",
                 "name": "one-sided paired test (min of t-test and Wilcoxon signed-rank, doubled) on per-(pose, axis) "
                         "held-out log predictive density (fixed floor + the fit's prediction variance), "
                         "Bonferroni over the candidates of each step; a candidate must also shrink the held-out RMS "
                         "and min_gap_shrink of some view's log(gap); stop when every view's mean squared standardised residual "
                         "lies in the two-sided 1-alpha range of chi2_N/N",
                 "alpha": d.alpha, "min_gap_shrink": MIN_GAP_SHRINK},
        "data": {"sources": data.sources, "poses": data.P, "references": not data.norm_only,
                 "samples_per_pose_known": data.n_known, "temperatures": data.n_temps,
                 "raw_captures": data.captures is not None, "rate_hz": data.rate_hz, "counts_per_g": data.counts_per_g,
                 "static_view": d.static_ok, "static_view_note": d.static_why or None, "notes": data.notes},
        "where": d.where,
    }

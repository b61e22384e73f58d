"""What `accelcal diagnose` says: the human summary and the self-test table (the files of --report, figures
and markdown, are figures.py's).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..sim.sensor_model import EffectValue
from .result import Diagnosis
from .selection import MIN_GAP_SHRINK, Fitted

if TYPE_CHECKING:

    from .selftest import SelfTestResult  # type only: the self-test's simulation is not imported for a report

FIGURES = {"sphere": "residuals over the sphere of orientations", "level": "residual against input level",
           "temperature": "residual against temperature", "time": "residual against time in capture"}


# -- text ---------------------------------------------------------------------------------------------

def fmt_g(x: float | None) -> str:
    """A ratio to the floor, short ("n/a" when there is none)."""
    return "n/a" if x is None or not np.isfinite(x) else (f"{x:.3g}" if x < 100 else f"{x:.0f}")


def config_hint(effect: str, fitted: Fitted) -> dict[str, EffectValue | None] | None:
    """The fitted effect as simulator-configuration parameters (approximate where W is not I)."""
    f = fitted

    def n(key: str) -> float:  # a fitted number (a per-axis list where one is named is the caller's error)
        v = f[key]
        if isinstance(v, list):
            raise TypeError(f"fitted {key}: a list where a number was fitted")
        return v

    try:
        if effect == "cubic":
            return {"cubic_per_g2": [-n(f"Gamma_{a}") for a in "xyz"]}  # AN4399 Eqn 67: Gamma = -c
        if effect == "quadratic":
            return {"quadratic_per_g": [-n(f"Q_{a}") for a in "xyz"]}
        if effect == "offset":
            return {"offset_mg": [-1e3 * n(f"V_{a}") for a in "xyz"]}
        if effect == "gain":
            return {"gain": [1.0 / n(f"W_{a}{a}") for a in "xyz"]}
        if effect == "temperature":
            return {"offset_mg_per_c": [-1e3 * n(f"offset_{a}_per_25C") / 25.0 for a in "xyz"],
                    "gain_ppm_per_c": [-1e6 * n(f"gain_{a}_per_25C") / 25.0 for a in "xyz"]}
        if effect == "noise":
            return {"density_ug_per_rthz": f["density_ug_per_rthz"]}
        if effect == "quantization":
            return {"lsb_counts": int(round(n("lsb_counts")))}
        if effect == "pose_error":
            return {"scatter_deg": f["scatter_deg"]}
        if effect == "settling":
            return {"tau_s": f["settling_tau_s"]}
        if effect == "drift":
            return {"warmup_mg": [1e3 * n(f"warmup_{a}") for a in "xyz"], "warmup_tau_s": f["drift_tau_s"]} \
                if "drift_tau_s" in f else {"warmup_tau_s": f.get("drift_tau_s_time")}
    except KeyError:
        return None
    return None


def _yaml_inline(d: Mapping[str, object]) -> str:
    def v(x: Any) -> str:
        if isinstance(x, list):
            return "[" + ", ".join(v(y) for y in x) + "]"
        return f"{x:.4g}" if isinstance(x, float) else str(x)
    return "{" + ", ".join(f"{k}: {v(x)}" for k, x in d.items()) + "}"


def _where_lines(d: Diagnosis) -> list[str]:
    """Where the baseline's held-out gap lies (where.breakdown) as text."""
    data = d.data
    out = ["WHERE (held-out ratio to the floor, baseline model)"]
    w = d.where
    if "by_axis" in w:
        out.append("  by axis: " + ", ".join(f"{a} {fmt_g(v)}" for a, v in w["by_axis"].items()))
    if "by_pose" in w:
        odd = [p for p in w["by_pose"] if p["stands_out"]][:4]
        out.append("  poses that stand out (standardised held-out residual): "
                   + (", ".join(f"{p['pose']} {fmt_g(p['z_rms'])}" for p in odd) if odd else "none"))
    if w.get("by_level"):
        rows: dict[str, list[str]] = {}
        for r in w["by_level"]:
            rows.setdefault(r["axis"], []).append(f"{r['level_g'][0]:+.1f}..{r['level_g'][1]:+.1f} g: "
                                                  f"{r['mean_residual_mg']:+.3g} mg")
        label = "channel" if not data.norm_only else "norm residual vs channel"
        for a, rr in rows.items():
            out.append(f"  by input level ({label} {a}, mean residual): " + "; ".join(rr))
    if w.get("by_temperature"):
        out.append("  by temperature: "
                   + ", ".join(f"{t['temp_c']:.0f} C {fmt_g(t['gap'])}" for t in w["by_temperature"]))
    if w.get("by_time_in_capture"):
        tt = w["by_time_in_capture"]
        out.append("  by time in capture: " + ", ".join(f"{t['t_s']:.1f} s {fmt_g(t['gap'])}" for t in tt)
                   + f" (first block leans {tt[0]['toward_step_mg']:+.3g} mg along the last move)")
    if "noise" in w:
        nz = w["noise"]
        out.append("  noise: per-sample sigma " + "/".join(f"{x:.3g}" for x in nz["sigma_mg"]) + " mg against the "
                   f"simulator's {np.mean(nz['simulator_sigma_mg']):.3g} mg (ratio "
                   + "/".join(fmt_g(x) for x in nz["ratio"]) + ")")
    if "allan" in w:
        al = w["allan"]
        out.append(f"  Allan deviation at {al['tau_s'][-1]:.3g} s: "
                   + "/".join(fmt_g(x) for x in al["ratio_at_longest_tau"])
                   + " x white noise (x, y, z; 1 = white, more = drift or flicker)")
    return out


def summary_lines(d: Diagnosis) -> list[str]:
    """The human summary: gap, where, which, how far, and what to do."""
    out = _gap_lines(d) + [""] + _where_lines(d) + [""] + _which_lines(d)
    out += _stochastic_lines(d) + _verdict_lines(d)
    return out


def _gap_lines(d: Diagnosis) -> list[str]:
    """The data, the simulator and its floor, and the headline gap."""
    data, sim, b = d.data, d.sim, d.base
    kind = ("references" if not data.norm_only else "norm only (no references)") + \
        (f", raw captures at {data.rate_hz:g} Hz" if data.captures is not None else "")
    n_txt = f"{np.median(data.n):.0f} samples/pose" + ("" if data.n_known else " (assumed)")
    temps = "" if data.temp_c is None else f", {data.n_temps} temperature(s)"
    fl = d.floor
    out = [f"accelcal diagnose: {data.P} poses from {', '.join(data.sources)} ({kind}; {n_txt}{temps})",
           f"simulator {sim.source}: {', '.join(sim.enabled) or 'no effects'}; fitted baseline: "
           f"{', '.join(sim.baseline) or 'nothing (W = I)'}; floor from the {fl.source}: "
           f"{1e3 * float(np.mean(fl.sigma_g)):.3g} mg/sample at {data.rate_hz or sim.odr_hz:g} Hz"
           f" and a {1e3 * fl.q_g:.3g} mg LSB"]
    out += [f"note: {n}" for n in data.notes]
    if not d.static_ok:
        out.append(f"note: no static view: {d.static_why}")
    out.append("")
    h = d.headline
    if h is not None and h["held_out_rms_mg"] is not None:
        out.append(f"GAP  held-out residual {h['held_out_rms_mg']:.4g} mg RMS ({h['source']}): {fmt_g(h['gap'])} x the "
                   f"floor of a pose mean ({h['floor_mg']:.3g} mg RMS, fixed before any candidate; 1.0 = at the floor)")
        out.append(f"     at the floor with this design's own fit uncertainty it would be {h['expected_mg']:.4g} mg; "
                   f"{h['note']}")
    else:
        out.append(f"GAP  held-out gap {fmt_g(d.gap_before)} x the floor fixed before any candidate (time view; "
                   f"held-out residual {1e3 * b.rms_g:.4g} mg RMS)")
    w = d.where.get("views", {})
    views = [f"{v} view {fmt_g(g)}" for v, g in w.items() if g is not None]
    if len(views) > 1:
        out.append("     selection's held-out gap by view: " + "; ".join(views)
                   + f" (their RMS {fmt_g(d.gap_before)} is the gap the selection below judges)")
    return out


def _which_lines(d: Diagnosis) -> list[str]:
    """Every candidate's held-out gap and p, the untestable ones with why, and how far the gap fell."""
    out: list[str] = []
    out.append(f"WHICH (each candidate added to the model, refitted on training folds, scored on held-out poses;\n"
               f"       selected while a one-sided paired test (t or Wilcoxon, doubled) on per-pose held-out log "
               "density\n"
               f"       beats alpha = {d.alpha:g} / candidates, the held-out RMS shrinks, some view loses "
               f"{MIN_GAP_SHRINK:.0%} of its log gap,\n       the gap is outside its chance range, and it beats a "
               "change over the session (the order trend)\n       in the same test; when the best fails a rule the "
               "next is tried)")
    for i, r in enumerate(d.ranking):
        mark = "  <- selected" if r["effect"] in d.selected else ""
        out.append(f"  {i + 1:2d}. {r['effect']:<13} held-out gap {fmt_g(r['held_out_gap']):>7}   "
                   f"p {r['p_value']:.2g}{mark}")
    if not d.ranking:
        out.append("  (no catalog effect can be tested on these data)")
    for e, why in d.untestable.items():
        out.append(f"  not testable: {e}: {why}")
    out.append("")
    out.append("HOW FAR (held-out gap; held-out residual RMS)")
    txt = f"  baseline {fmt_g(d.gap_before)} ({1e3 * d.base.rms_g:.3g} mg)"
    for s in d.steps:
        txt += f" -> + {s['added']} {fmt_g(s['gap_after'])} ({s['rms_mg_after']:.3g} mg)"
    out.append(txt)
    ot = d.order_trend
    if ot is not None:
        out.append(f"  order trend (a change over the session) on the baseline: {fmt_g(ot['held_out_gap'])} "
                   f"({fmt_g(ot['rms_mg'])} mg)" if ot["fitted"] else f"  order trend: not fitted ({ot['why_not']})")
    out.append("")
    return out


def _stochastic_lines(d: Diagnosis) -> list[str]:
    """Each stochastic effect's signature test, and the jig rotation."""
    out: list[str] = []
    out.append("STOCHASTIC (each judged by its own signature; never lowers the gap)")
    for name, st in d.stochastic.items():
        if st.get("testable"):
            out.append(f"  {name}: {'NAMED' if st['passed'] else 'no'}: {st['reason']}")
        else:
            out.append(f"  {name}: not testable: {st['reason']}")
    jig = d.stochastic.get("pose_error", {}).get("jig_rotation")
    if jig and isinstance(jig, dict):  # engine.diagnose: jig_rotation's report under pose_error
        state = ("FITTED" if jig["passed"] else "no") if jig["testable"] else "not testable"
        out.append(f"  jig rotation (deterministic, 3 parameters): {state}: {jig['reason']}")
    out.append("")
    return out


def _verdict_lines(d: Diagnosis) -> list[str]:
    """The verdict and the configuration hints that follow from it."""
    data = d.data
    out: list[str] = []
    out.append(f"VERDICT: {d.verdict}: {d.verdict_text}")
    if d.steps and d.verdict in ("explained", "partly explained"):  # only what the selection kept
        out.append("  add to the simulator configuration:")
        for s in d.steps:
            hint = config_hint(s["added"], s["fitted"])
            out.append(f"  {s['added']}: {_yaml_inline(hint)}" if hint else f"  {s['added']}: (see --json steps)")
    if not data.n_known:
        out.append(f"  (the floor assumes {np.median(data.n):.0f} sample(s) per pose: with more, the true gap is "
                   "larger)")
    return out


def selftest_lines(r: SelfTestResult) -> list[str]:
    out = [f"accelcal diagnose --selftest: {r['design']} boards ({r['physics']}), seed {r['seed']}, "
           f"alpha {r['alpha']:g}",
           f"{'case':<19}{'expect':<12}{'named':<26}{'verdict':<19}{'rms mg before':>14}{'after':>8}  result"]
    for c in r["cases"]:
        res = "ok" if c["pass"] else "FAIL"
        if not c["revealable"]:
            res += " (not revealable: see below)"
        out.append(f"{c['case']:<19}{c['kind']:<12}{', '.join(c['selected']) or '-':<26}{c['verdict']:<19}"
                   f"{c['rms_mg_before']:>14.3g}{c['rms_mg_after']:>8.3g}  {res}")
    if "coverage" in r:
        out.append("")
        out.append("effects the data cannot reveal, and why:")
        for effect, row in r["coverage"].items():
            for kind, st in row.items():
                if not st.startswith("testable"):
                    out.append(f"  {effect} / {kind}: {st}")
    out.append("")
    out.append("self-test " + ("passed" if r["passed"] else "FAILED"))
    return out

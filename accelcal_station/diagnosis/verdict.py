"""The verdict of a diagnosis (engine's module doc, step 5), words that keep their word:

  explained          a deterministic effect was selected and the held-out gap after it is at the floor
                     (every view's standardised residual within its chi^2 range) AND at most
                     EXPLAINED_GAP_MAX (1.5) times the floor
  partly explained   a deterministic effect shrinks the held-out residual but the gap left is above that:
                     the text gives the gap left and the shape of what is left
  accounted for      only stochastic effects (noise, pose error, quantization, random-walk drift) are
                     named and nothing is left beyond them: they account for the spread; a deterministic
                     fix cannot lower it, and the held-out residual is what it was
  unexplained        nothing named; the shape of what is left
  nothing to explain the held-out residuals are at the floor with nothing added

EXPLAINED_GAP_MAX = 1.5: the gap is the held-out residual RMS over the floor's RMS, so at 1.5 what is
left above the floor is sqrt(1.5^2 - 1) = 1.1 floor RMS, as large as the noise itself; beyond that
an unmodelled residue as large as the noise remains, which "explained" must not hide.  Chance alone
keeps a fit at its floor below it: the upper 1 % point of sqrt(chi^2_N / N) is 1.29 at N = 24 held-out
residuals (8 poses x 3 axes) and less with more.  The chi^2 test (at_floor) is kept beside it: a few
large residuals can fail it while the RMS ratio is small.  A drift fit that takes the gap from 19.75
to 17.76 is therefore "partly explained", not "explained".

Confounding with acquisition order (diagnosis/order.py, confounding.py): the terms of a selected effect a
change over the session could stand in for are said in words after the verdict; an effect confounded alone
is not selected, and with nothing else the verdict is "unexplained" naming it as the leading candidate.
"Accounted for" holds whenever only stochastic effects are named and no residue is left beyond them
(_excess_beyond); "partly explained" names the rule "explained" failed (the gap, the chi-square test).
"""
from __future__ import annotations

import numpy as np

from .effects.catalog import STOCHASTIC
from .evaluation import Evaluation
from .order import order_words
from .result import Diagnosis
from .selection import ALPHA


def at_floor(e: Evaluation, alpha: float = ALPHA) -> bool:
    """Whether no view's mean squared standardised held-out residual lies above the 1 - alpha/views
    quantile of chi^2_N / N (one-sided: residuals below their prediction leave nothing to explain)."""
    from scipy import stats

    views = [(r, v) for r, v in ((e.r_static, e.v_static), (e.r_time, e.v_time)) if r is not None]
    return all(np.sum(r**2 / v) <= stats.chi2.ppf(1 - alpha / len(views), r.size) for r, v in views)


def verdict(d: Diagnosis) -> tuple[str, str]:
    """The verdict word and text (module doc); the terms of a selected effect a change over the session could
    stand in for, and the effects confounded alone (diagnosis/order.py), are said in words."""
    word, text = _verdict(d)
    if d.confounded_with:
        text += "; " + order_words(d.confounded_with)
    return word, text


EXPLAINED_GAP_MAX = 1.5  # module doc: the most held-out gap over the floor "explained" may leave


def chi2_words(e: Evaluation, alpha: float) -> str:
    """The chi-square test at the floor in words: which view fails it and by how much ('' when none)."""
    from scipy import stats

    views = [(n, r, v) for n, r, v in (("static", e.r_static, e.v_static), ("time", e.r_time, e.v_time))
             if r is not None and v is not None]
    out = []
    for name, r, v in views:
        x, lim = float(np.sum(r**2 / v)), float(stats.chi2.ppf(1 - alpha / len(views), r.size))
        if x > lim:
            out.append(f"the {name} view's standardised held-out residuals sum to {x:.4g} against the "
                       f"{1 - alpha / len(views):.4g} point {lim:.4g} of chi^2 on {r.size}")
    return "; ".join(out)


def _why_not_explained(d: Diagnosis) -> str:
    """The rule 'explained' failed, named: the gap above EXPLAINED_GAP_MAX, the chi-square test, or both."""
    parts = []
    if d.gap_after > EXPLAINED_GAP_MAX:
        parts.append(f"above the {EXPLAINED_GAP_MAX:g} 'explained' needs")
    chi = chi2_words(d.final, d.alpha)
    if chi:
        parts.append(f"failing the chi-square test at the floor ({chi})")
    return " and ".join(parts)


def _stochastic_figures(d: Diagnosis, stoch: list[str]) -> str:
    """The named stochastic effects' own figures (the noise ratio, the pose scatter), '; '-joined."""
    out = []
    for n in stoch:
        ev = d.stochastic.get(n, {})
        ratio, scatter = ev.get("ratio"), ev.get("scatter_deg")
        if n == "noise" and isinstance(ratio, list):
            out.append("within-pose sigma " + "/".join(f"{r:.2f}" for r in ratio if isinstance(r, float))
                       + " x the simulator's on x/y/z")
        elif n == "pose_error" and isinstance(scatter, float):
            out.append(f"pose scatter {scatter:.3g} deg")
    return "; ".join(out)


def _verdict(d: Diagnosis) -> tuple[str, str]:
    base_ok, final_ok = at_floor(d.base, d.alpha), at_floor(d.final, d.alpha)
    stepped = {s["added"] for s in d.steps}  # taken by the held-out selection: deterministic columns
    det = [n for n in d.selected if n in stepped]
    stoch = [n for n in d.selected if n not in stepped and n in STOCHASTIC]
    shape = d.leftover.get("summary", "")
    if base_ok and not d.selected and not d.confounded_with:
        return "nothing to explain", ("the held-out residuals are at the floor (chi-square test on the floor plus the "
                                      "fit's own prediction variance): the simulator describes these data")
    verb = "accounts" if len(stoch) == 1 else "account"
    figs = _stochastic_figures(d, stoch)
    spread = (f"; {', '.join(stoch)} {verb} for the spread (a deterministic fix cannot lower it"
              + (f": {figs})" if figs else ")")) if stoch else ""
    gaps = f"held-out gap {d.gap_before:.3g} -> {d.gap_after:.3g} x the floor"
    if det and final_ok and d.gap_after <= EXPLAINED_GAP_MAX:
        return "explained", (f"{', '.join(det)} explain{'s' if len(det) == 1 else ''} the gap ({gaps}, within "
                             f"the {EXPLAINED_GAP_MAX:g} x the floor 'explained' allows){spread}")
    if det and d.final.rms_g < d.base.rms_g:
        return "partly explained", (f"{', '.join(det)} shrink{'s' if len(det) == 1 else ''} the held-out residual "
                                    f"({1e3 * d.base.rms_g:.3g} -> {1e3 * d.final.rms_g:.3g} mg; {gaps}, "
                                    f"{_why_not_explained(d)}){spread}; what is left: {shape}")
    alone = [e for e, c in d.confounded_with.items() if c["alone"]]
    if stoch and not det and not alone and not _excess_beyond(d, stoch, final_ok):
        figs = figs + "; " if figs else ""
        return "accounted for", (f"{', '.join(stoch)} {verb} for the spread; a deterministic fix cannot lower it "
                                 f"({figs}held-out residual {1e3 * d.final.rms_g:.3g} mg, {gaps})")
    if alone:
        lead = next((r for r in d.ranking if r["effect"] == alone[0]), None)
        ot = d.order_trend["held_out_gap"] if d.order_trend else None
        how = "" if lead is None else f", which lowers the held-out gap to {lead['held_out_gap']:.3g} x the floor" + (
            f" where a change over the session (order trend) lowers it to {ot:.3g}" if ot is not None else "")
        return "unexplained", (f"no catalog effect can be told from a change over the session ({gaps}); the leading "
                               f"candidate is {alone[0]}{how}{spread}; what is left: {shape}")
    return "unexplained", f"no catalog effect explains the gap ({gaps}){spread}; what is left: {shape}"


def _excess_beyond(d: Diagnosis, stoch: list[str], final_ok: bool) -> bool:
    """Whether the final residuals exceed the floor by more than the named stochastic effects account for.

    A residue beyond them is both: the chi-square test at the floor fails and the gap is above
    EXPLAINED_GAP_MAX (the floor already holds the data's own within-pose spread and value grid, so a
    gap within it is the fit's own scatter, which a noisier board only scales).  A pose error accounts
    for an excess of the static view, when the time view (if any) is at its floor.
    """
    if final_ok or d.gap_after <= EXPLAINED_GAP_MAX:
        return False
    if "pose_error" not in stoch:
        return True
    r, v = d.final.r_time, d.final.v_time
    if r is None or v is None:
        return False
    from scipy import stats

    return float(np.sum(r**2 / v)) > stats.chi2.ppf(1 - d.alpha, r.size)

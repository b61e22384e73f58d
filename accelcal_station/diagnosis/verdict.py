"""The verdict of a diagnosis: explained / partly explained / unexplained / nothing to explain
(engine's module doc, step 5)."""
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
    """explained / partly explained / unexplained / nothing to explain (module doc); a selected effect
    confounded with acquisition order (diagnosis/order.py) is never "explained", and the text says why."""
    word, text = _verdict(d)
    if d.confounded_with:
        word = "partly explained" if word == "explained" else word
        text += "; but " + order_words(d.confounded_with)
    return word, text


def _verdict(d: Diagnosis) -> tuple[str, str]:
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
                                    f"({1e3 * d.base.rms_g:.3g} -> {1e3 * d.final.rms_g:.3g} mg); "
                                    f"what is left: {shape}")
    return "unexplained", f"no catalog effect explains the gap; what is left: {shape}"


def _excess_beyond(d: Diagnosis, stoch: list[str]) -> bool:
    """Whether the final residuals exceed the floor by more than the named stochastic effects account for.

    The floor already holds the data's own within-pose spread and value grid, so noise and
    quantization cannot account for residuals above it; a pose error accounts for an excess of
    the static view only, when the time view (if any) is at its floor.
    """
    if "pose_error" not in stoch:
        return True
    r, v = d.final.r_time, d.final.v_time
    if r is None or v is None:
        return False
    from scipy import stats

    return float(np.sum(r**2 / v)) > stats.chi2.ppf(1 - d.alpha, r.size)

"""The order trend's report (``order_trend`` of diagnose --json): how far a smooth change over the session
alone lowers the held-out gap, the paired test against the baseline, and the candidates it explained as well
(diagnosis/order.py's module doc; the columns are effects/order_trend.py)."""
from __future__ import annotations

from typing import TypedDict

from .evaluation import Evaluation
from .selection import Competitor, OrderLoss, p_greater


class OrderTrendJson(TypedDict):
    """The competitor of every static candidate: fitted or why not, and its held-out figures on the baseline."""

    fitted: bool
    why_not: str | None
    basis: str
    held_out_gap: float | None
    rms_mg: float | None
    p_value: float | None  # one-sided paired test against the baseline (per pose and axis log density)
    beats_baseline: bool
    explains_as_well: dict[str, OrderLoss]


BASIS = ("per file, an offset per channel following Legendre P1..P3 of the pose's position in the file "
         "(a cubic in row number; P1..P(n//4) below 12 poses) and a mean per file: the basis restarts in every file")


def order_trend_json(comp: Competitor, why_not: str, base: Evaluation, alpha: float) -> OrderTrendJson:
    """The order trend's figures on the baseline (``first``), and whether it beats the baseline at alpha."""
    e = comp.first
    if why_not or e is None:
        return {"fitted": False, "why_not": why_not or "nothing was left to compare it on", "basis": BASIS,
                "held_out_gap": None, "rms_mg": None, "p_value": None, "beats_baseline": False,
                "explains_as_well": {}}
    units = base.nll_unit != 0
    p = p_greater((base.nll_unit - e.nll_unit)[units])
    beats = bool(p < alpha and e.rms_g < base.rms_g)
    return {"fitted": True, "why_not": None, "basis": BASIS, "held_out_gap": e.gap, "rms_mg": 1e3 * e.rms_g,
            "p_value": p, "beats_baseline": beats, "explains_as_well": dict(comp.lost)}


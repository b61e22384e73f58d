"""The board page's time-budget table from a run's stored ``fit_summary.time_budget`` (station/time_budget.py,
docs/timing.md): each part in seconds with its share, the total, the floor and their ratio."""
from __future__ import annotations

from typing import TypedDict

from ..jsontypes import JsonObject

# the parts in the order the budget adds them, with the words the page shows
PARTS = (("warmup_s", "warm-up"), ("self_test_s", "self-test"), ("sampling_s", "sampling at the fit poses"),
         ("stillness_s", "waiting for stillness"), ("verification_s", "verification poses"),
         ("jig_moves_s", "jig moves"), ("eeprom_s", "EEPROM writes"), ("host_compute_s", "host compute"),
         ("operator_s", "operator"))


class BudgetRow(TypedDict):
    key: str
    label: str
    seconds: float
    share: float  # of the total, 0..1


class TimeBudgetView(TypedDict):
    rows: list[BudgetRow]
    total_s: float
    floor_s: float | None
    ratio: float | None
    boards: int | None  # a panel board's share: the panel's boards


def _num(v: object) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def time_budget_view(fit_summary: JsonObject | None) -> TimeBudgetView | None:
    """The table's rows (parts that took time), or None when the run kept no budget (older runs)."""
    b = fit_summary.get("time_budget") if isinstance(fit_summary, dict) else None
    total = _num(b.get("total_s")) if isinstance(b, dict) else None
    if not isinstance(b, dict) or total is None:
        return None
    rows: list[BudgetRow] = []
    for key, label in PARTS:
        s = _num(b.get(key))
        if s:
            rows.append({"key": key, "label": label, "seconds": s, "share": s / total if total > 0 else 0.0})
    boards = _num(b.get("boards"))
    return {"rows": rows, "total_s": total, "floor_s": _num(b.get("floor_s")), "ratio": _num(b.get("ratio_to_floor")),
            "boards": None if boards is None else int(boards)}

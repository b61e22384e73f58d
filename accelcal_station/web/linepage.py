"""The line page, light at any size: summaries first, details on demand.

The page holds only counts grouped in SQL: each station's card (latest run, yield, first-pass yield,
runs, its latest Gage R&R result: msa_line.py), the yield per station and shift as one row per
station, the lots of the window with their yield, the failure reasons and the newest runs.  The run
charts of a station are its own page (``/station``), the runs of a lot or a reason the lot and
reason pages, a page at a time (paging.py).  So its size grows with the number of stations, shifts
and lots in the window, never with the number of runs (docs/web.md: the budget at 100,000 runs).
"""
from __future__ import annotations

from typing import TypedDict

from ..store.reader import StoreReader as Store
from ..store.records import iso
from . import queries
from .charts import Chart, RunPoint, run_chart
from .msa_line import MsaBadge, cached_msa
from .pages import Window, pick_window
from .views import LotYield, RunView, ShiftYield, StationRow

# a station's run charts: fit_summary.measured key, title, unit, acceptance limit key
KEY_PARAMS = [("gain_error_max", "Gain error, max |Wii − 1|", "g/g", "gain_error_max"),
              ("offset_max_mg", "Offset, max |Vi|", "mg", "offset_max_mg"),
              ("cross_axis_max", "Cross-axis, max |Wij|", "g/g", "cross_axis_max"),
              ("residual_rms_mg", "Fit residual RMS", "mg", "residual_rms_mg")]
RECENT_RUNS = 10


class ShiftGrid(TypedDict):
    """The yield per station (rows) and shift (columns) of the window."""

    shifts: list[str]
    rows: list[tuple[str | None, list[ShiftYield | None]]]


def shift_grid(rows: list[ShiftYield]) -> ShiftGrid:
    shifts = sorted({r["shift"] for r in rows})
    stations: dict[str | None, dict[str, ShiftYield]] = {}
    for r in rows:
        stations.setdefault(r["station_id"], {})[r["shift"]] = r
    return {"shifts": shifts, "rows": [(st, [cells.get(s) for s in shifts]) for st, cells in stations.items()]}


class LineContext(TypedDict):
    """The line page (line.html, line_body.html)."""

    empty: bool
    window: Window | None
    window_from: str | None
    window_to: str | None
    day: str
    shift: str
    stations: list[StationRow]
    msa: dict[str | None, MsaBadge]
    grid: ShiftGrid
    lots: list[LotYield]
    reasons: list[tuple[str, int]]
    recent: list[RunView]


def line_context(store: Store, day: str = "", shift: str = "") -> LineContext:
    """Stations, yields per station and shift, lots, reasons and the newest runs (aggregate queries only)."""
    w = pick_window(store, day, shift)
    if w is None:
        return {"empty": True, "stations": [], "msa": {}, "grid": {"shifts": [], "rows": []}, "lots": [],
                "reasons": [], "recent": [], "window": None, "window_from": None, "window_to": None, "day": day,
                "shift": shift}
    stations = queries.station_rows(store, w.t0, w.t1)
    msa = {s["station_id"]: cached_msa(store, str(store.path), s["station_id"], s["latest"]["id"]) for s in stations}
    return {"empty": False, "window": w, "window_from": iso(w.t0), "window_to": iso(w.t1), "day": w.day,
            "shift": w.shift, "stations": stations, "msa": msa,
            "grid": shift_grid(queries.shift_rows(store, w.t0, w.t1)), "lots": queries.lot_yields(store, w.t0, w.t1),
            "reasons": queries.reason_counts(store, w.t0, w.t1), "recent": queries.recent(store, RECENT_RUNS)}


def station_charts(store: Store, station: str | None, w: Window) -> list[Chart]:
    """One station's run charts over the window, each run against its own limits."""
    series = queries.station_series(store, station, w.t0, w.t1)
    charts = []
    for key, title, unit, lkey in KEY_PARAMS:
        pts = [RunPoint(s["t"], s["measured"][key], s["limits"].get(lkey), None, f"run {s['id']}")
               for s in series if key in s["measured"]]
        charts.append(run_chart(title, unit, pts, nonneg=True))
    return charts


class StationContext(TypedDict):
    """A station's page (station.html): its run charts over the line page's window."""

    station: str | None
    window: Window | None
    day: str
    shift: str
    charts: list[Chart]


def station_context(store: Store, station: str | None, day: str = "", shift: str = "") -> StationContext:
    w = pick_window(store, day, shift)
    return {"station": station, "window": w, "day": day, "shift": shift,
            "charts": [] if w is None else station_charts(store, station, w)}

"""What the board, lot and reason pages show, as plain values for the templates, and the line
page's window (the line page and a station's charts: linepage.py).

Every chart draws each run against the limits that run was judged by (its stored
``limits``; an older run: its own config's acceptance section), never the limits of the
config ``serve`` was started with.  The window is the day before the newest run, or a
production day / shift picked by the engineer; the lot page groups in SQL, reads one JSON
column of the lot's runs for its first page's charts, and shows its runs a page at a time
(paging.py), as the reason page does.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import TypedDict

import numpy as np

from ..acceptance.rules import LIMIT_KEYS
from ..errors import AccelcalError, DataError
from ..jsontypes import JsonObject, JsonValue
from ..store.reader import StoreReader as Store
from ..store.records import RunRecord, iso
from . import queries
from .charts import Chart, RunPoint, residual_chart, run_chart
from .paging import PAGE_SIZE, RunsPage, page_of
from .settings import WebSettings, open_store
from .time_budget_view import TimeBudgetView, time_budget_view
from .views import LotCalibration, LotCounts, LotRow, RunFilters, RunView

# the lot page's parameters: name, index in calibration.param_vector, scale to the unit, unit, limit key, centre
LOT_PARAMS = ([(f"W{i}{i}", 4 * i, 1.0, "g/g", "gain_error_max", 1.0) for i in range(3)]
              + [(f"V{i}", 9 + i, 1e3, "mg", "offset_max_mg", 0.0) for i in range(3)]
              + [(f"W{a}{b}", 3 * a + b, 1.0, "g/g", "cross_axis_max", 0.0) for a, b in ((0, 1), (0, 2), (1, 2))])
LOT_CHART_RUNS = 200  # a lot chart draws the newest this many runs (the table's statistics use every run)
SHIFTS = "ABC"


@dataclass(frozen=True)
class Window:
    """The line page's window [t0, t1) in unix s and how it is named."""

    t0: float
    t1: float
    label: str
    day: str = ""
    shift: str = ""


def limit_unit(key: str) -> str:
    """The unit of a limit or measured figure, from its key (acceptance.rules.LIMIT_KEYS)."""
    if key.endswith("_mg"):
        return "mg"
    if key.startswith("cubic"):
        return "1/g²"
    return "g/g" if key in LIMIT_KEYS else ""


def pick_window(store: Store, day: str, shift: str) -> Window | None:
    """The window to show: a production day (06:00 UTC to 06:00 the next day) or one of its shifts
    (A 06-14, B 14-22, C 22-06 UTC); by default the day before the newest run.  None: no runs."""
    if day:
        try:
            d = datetime.strptime(day, "%Y-%m-%d").replace(tzinfo=UTC) + timedelta(hours=6)
        except ValueError:
            raise DataError(f"day {day[:20]!r}: allowed a date YYYY-MM-DD") from None
        k = SHIFTS.index(shift) if shift else 0
        t0 = d.timestamp() + k * queries.SHIFT_S
        t1 = t0 + (queries.SHIFT_S if shift else 3 * queries.SHIFT_S)
        return Window(t0, t1, f"{day} shift {shift}" if shift else f"production day {day}", day, shift)
    newest = queries.newest_start(store)
    if newest is None:
        return None
    return Window(newest - queries.WINDOW_S, newest + 1e-3, "the day before the newest run")


class ReasonContext(TypedDict):
    """The FAIL runs of one reason code (reason.html), a page at a time."""

    code: str
    window: Window | None
    runs_page: RunsPage
    station: str | None
    day: str
    shift: str
    window_from: str | None
    window_to: str | None


def reason_context(store: Store, code: str, day: str, shift: str, station: str | None, cursor: str = "",
                   limit: int = PAGE_SIZE) -> ReasonContext:
    """The FAIL runs of one reason code in the line page's window (the drill-down from a reason), the
    page ``cursor`` names (paging.py), newest first."""
    w = pick_window(store, day, shift)

    def fetch(order: str, after: int | None, n: int) -> list[RunView]:
        return [] if w is None else queries.reason_runs(store, code, w.t0, w.t1, station, order, after, n)

    return {"code": code, "window": w, "runs_page": page_of(fetch, cursor, limit), "station": station, "day": day,
            "shift": shift, "window_from": None if w is None else iso(w.t0),
            "window_to": None if w is None else iso(w.t1)}


def _residuals(rec: RunRecord) -> Chart | None:
    """One run's residuals per pose, refitted from its stored poses with its model."""
    if not rec.poses or rec.status != "complete":
        return None
    from ..models.fitting import fit_session

    try:
        fit = fit_session(rec.session(), rec.model or "12")
    except AccelcalError:
        return None
    return residual_chart(f"run {rec.id}: residuals per pose (model {fit.model})",
                          [p.name for p in rec.poses], np.asarray(fit.residuals_g) * 1e3)


class AcceptanceRow(TypedDict):
    """A figure of the board page's acceptance table: its value, limit, unit and whether it failed."""

    key: str
    what: str
    value: float | None
    limit: float | None
    unit: str
    failed: bool
    judged: bool


def acceptance_rows(measured: Mapping[str, JsonValue], limits: dict[str, float],
                    failed_codes: list[str]) -> list[AcceptanceRow]:
    """The board page's acceptance table: each figure with its limit, unit and whether it failed."""
    rows: list[AcceptanceRow] = []
    for key in sorted(set(measured) | set(limits)):
        got, lim = measured.get(key), limits.get(key)
        v = got if isinstance(got, (int, float)) and not isinstance(got, bool) else None
        failed = key in failed_codes or (v is not None and lim is not None and float(v) > lim)
        rows.append({"key": key, "what": LIMIT_KEYS.get(key, "").split(",")[0], "value": v,
                     "limit": lim, "unit": limit_unit(key), "failed": failed,
                     "judged": lim is not None and v is not None})
    return rows


def _scaled(d: Mapping[str, JsonValue], key: str, k: float) -> float | None:
    """A stored number times k, or None (a damaged or missing value shows as a dash, never breaks the page)."""
    v = d.get(key)
    if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v):
        return float(v) * k
    return None


class SelfTestRow(TypedDict):
    """One axis of the self-test table: output change (mg), the judged value with its limits and unit, ok."""

    axis: str
    change_mg: float | None
    value: float | None
    low: float | None
    high: float | None
    unit: str
    ok: bool


class SelfTestView(TypedDict):
    chip: str
    source: str
    ok: bool
    no_effect: bool
    rows: list[SelfTestRow]


def self_test_view(fit_summary: JsonObject | None) -> SelfTestView | None:
    """The board page's self-test table from a run's stored ``fit_summary.self_test`` (None: not run):
    per axis the output change (mg), the judged value with its limits and unit, and ok."""
    st = fit_summary.get("self_test") if isinstance(fit_summary, dict) else None
    axes = st.get("axes") if isinstance(st, dict) else None
    if not isinstance(st, dict) or not isinstance(axes, list):
        return None
    rows: list[SelfTestRow] = []
    for a in axes:
        if not isinstance(a, dict):
            continue
        pct = a.get("unit") == "fraction_of_factory_trim"
        k = 100.0 if pct else 1e3  # a fraction of the factory trim in %, a change in g as mg
        rows.append({"axis": str(a.get("axis", "?")), "change_mg": _scaled(a, "change_g", 1e3),
                     "value": _scaled(a, "value", k), "low": _scaled(a, "low", k), "high": _scaled(a, "high", k),
                     "unit": "% from factory trim" if pct else "mg", "ok": a.get("ok") is True})
    return {"chip": str(st.get("chip", "")), "source": str(st.get("source", "")), "ok": st.get("ok") is True,
            "no_effect": st.get("no_effect") is True, "rows": rows}


class UncertaintyRow(TypedDict):
    """A calibration parameter with its expanded uncertainty (the run's budget, k given)."""

    name: str
    value: float | None
    U: float | None
    unit: str


class UncertaintyView(TypedDict):
    k: float | None
    rows: list[UncertaintyRow]
    rule: str | None
    site: str | None
    warnings: list[str]


def _num(v: object, k: float = 1.0) -> float | None:
    return float(v) * k if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) else None


def uncertainty_view(unc: JsonObject | None, cal: JsonObject | None, site: JsonObject | None) -> UncertaintyView | None:
    """The board page's uncertainty table from a run's stored ``uncertainty`` (schema 6; None: none
    recorded): V (mg) and W with their expanded uncertainty U, the decision rule and the site."""
    exp = unc.get("expanded") if isinstance(unc, dict) else None
    if not isinstance(unc, dict) or not isinstance(exp, dict):
        return None
    uV, uW = exp.get("V_mg"), exp.get("W")
    V, W = (cal or {}).get("V"), (cal or {}).get("W")
    def at(v: object, *idx: int) -> object:
        """v[i][j]... of stored JSON, None where the shape is not there (a damaged row never breaks the page)."""
        for i in idx:
            v = v[i] if isinstance(v, list) and len(v) == 3 else None
        return v

    rows: list[UncertaintyRow] = [{"name": f"V_{a}", "unit": "mg", "value": _num(at(V, i), 1e3), "U": _num(at(uV, i))}
                                  for i, a in enumerate("xyz")]
    rows += [{"name": f"W_{a}{b}", "unit": "g/g", "value": _num(at(W, i, j)), "U": _num(at(uW, i, j))}
             for i, a in enumerate("xyz") for j, b in enumerate("xyz")]
    rule = unc.get("decision_rule")
    warn = unc.get("warnings")
    return {"k": _num(unc.get("k")), "rows": rows,
            "rule": str(rule.get("rule")) + f" ({rule.get('guard_band')})" if isinstance(rule, dict) else None,
            "site": (f"{site.get('gravity_mps2')} m/s^2 ({site.get('source')})" if isinstance(site, dict) else None),
            "warnings": [str(w.get("message")) for w in warn if isinstance(w, dict)] if isinstance(warn, list) else []}


class BoardRun(TypedDict):
    """A run on the board page: the record, its start, residual chart, self-test, reasons and acceptance."""

    rec: RunRecord
    started: str | None
    chart: Chart | None
    self_test: SelfTestView | None
    reasons: list[dict[str, str]]  # Reason.to_dict: code, message
    limits_source: str | None
    acceptance: list[AcceptanceRow]
    uncertainty: UncertaintyView | None
    time_budget: TimeBudgetView | None  # where the run's time went (time_budget_view.py)


class NvmLine(TypedDict):
    """A line of a board's NVM history: the run, when (ISO 8601), what happened."""

    run: int | None
    t: str | None
    kind: str
    message: str | None


class BoardContext(TypedDict):
    """The board page (board.html)."""

    serial: str
    runs: list[BoardRun]
    nvm: list[NvmLine]
    similar: list[str]


def board_context(store: Store, serial: str) -> BoardContext:
    """Every run of one board (newest first) with its acceptance table, residual chart and NVM history."""
    recs = store.runs(device=serial)
    runs: list[BoardRun] = []
    nvm: list[NvmLine] = []
    for rec in reversed(recs):
        lim = rec.limits if isinstance(rec.limits, dict) else queries.limits_from_text(rec.config_text)
        measured = (rec.fit_summary or {}).get("measured") or {}
        runs.append({"rec": rec, "started": iso(rec.started_at), "chart": _residuals(rec),
                     "self_test": self_test_view(rec.fit_summary),
                     "reasons": [r.to_dict() for r in rec.reasons],
                     "limits_source": "stored" if isinstance(rec.limits, dict) else ("config" if lim else None),
                     "acceptance": acceptance_rows(measured if isinstance(measured, dict) else {}, lim,
                                                   [r.code for r in rec.reasons]),
                     "uncertainty": uncertainty_view(rec.uncertainty, rec.calibration, rec.site),
                     "time_budget": time_budget_view(rec.fit_summary)})
        nvm.extend({"run": rec.id, "t": iso(e["t"]), "kind": e["kind"], "message": e["message"]}
                   for e in rec.events if e["kind"] is not None and e["kind"].startswith("nvm_"))
        if rec.nvm_status and rec.nvm_status != "none":
            o = rec.nvm_outcome or {}
            nvm.append({"run": rec.id, "t": iso(rec.finished_at), "kind": f"run {rec.nvm_status}",
                        "message": f"slot {o.get('slot')}, generation {o.get('generation')}"})
    return {"serial": serial, "runs": runs, "nvm": nvm,
            "similar": [] if recs else queries.serials_like(store, serial)}


class ParamRow(TypedDict):
    """A parameter over a lot, in its unit: mean, sample std (None for one run), min, max."""

    name: str
    unit: str
    mean: float
    min: float
    max: float
    std: float | None


def _param_table(vals: np.ndarray) -> list[ParamRow]:
    """Mean, sample std, min, max of every parameter in its unit (W and Γ as fitted, V in mg)."""
    names = ([(f"W{a}{b}", 3 * a + b, 1.0, "g/g") for a in range(3) for b in range(3)]
             + [(f"V{i}", 9 + i, 1e3, "mg") for i in range(3)] + [(f"Γ{i}", 12 + i, 1.0, "1/g²") for i in range(3)])
    out: list[ParamRow] = []
    for name, idx, scale, unit in names:
        x = vals[:, idx] * scale
        out.append({"name": name, "unit": unit, "mean": float(x.mean()), "min": float(x.min()),
                    "max": float(x.max()), "std": float(x.std(ddof=1)) if len(x) > 1 else None})
    return out


class LotContext(TypedDict):
    """The lot page (lot.html): a lot's counts, parameter table and charts; the lots list beside it."""

    lot: str
    summary: LotCounts | None
    charts: list[Chart]
    parameters: list[ParamRow]
    lots: list[LotRow]
    runs_page: RunsPage | None


def _numbers(x: JsonValue) -> list[float] | None:
    """A JSON list of numbers as floats; None when it is not one."""
    if not isinstance(x, list) or not all(isinstance(v, (int, float)) for v in x):
        return None
    return [float(v) for v in x if isinstance(v, (int, float))]


def param_numbers(cal: JsonObject) -> list[float] | None:
    """W, V, Gamma of a stored calibration as 15 numbers (calibration.param_vector's order), without a
    numpy call per run; None when it is damaged (named on the board page and by `report check`)."""
    w, v, g = cal.get("W"), cal.get("V"), cal.get("Gamma", [0.0, 0.0, 0.0])
    rows = [_numbers(r) for r in w] if isinstance(w, list) and len(w) == 3 else [None]
    parts = [*rows, _numbers(v), _numbers(g)]
    if any(p is None for p in parts):
        return None
    vec = [x for p in parts for x in p or ()]
    return vec if len(vec) == 15 else None


def lot_runs(store: Store, lot: str, cursor: str, limit: int) -> RunsPage:
    """The lot's runs, the page ``cursor`` names (paging.py: the API's keyset on id), newest first."""
    f: RunFilters = {"since": None, "until": None, "station": None, "serial": None, "verdict": None, "lot": lot,
                     "status": None}
    return page_of(lambda order, after, n: queries.run_page(store, f, order, after, n), cursor, limit)


def lot_context(store: Store, lot: str, cursor: str = "", limit: int = PAGE_SIZE) -> LotContext:
    """The lot page: counts grouped in SQL, a page of its runs, and on its first page (no cursor) the
    parameters' statistics and run charts of the lot's calibrations, each run against its own limits."""
    charts: list[Chart] = []
    table: list[ParamRow] = []
    if cursor:  # a later page of runs: the runs only (the summary is the first page's)
        return {"lot": lot, "summary": None, "charts": [], "parameters": [], "lots": [],
                "runs_page": lot_runs(store, lot, cursor, limit)}
    summ = queries.lot_counts(store, lot)
    page = lot_runs(store, lot, cursor, limit) if summ["runs"] else None
    cals = queries.lot_calibrations(store, lot) if summ["runs"] else []
    rows: list[LotCalibration] = []
    vecs: list[list[float]] = []
    for c in cals:
        vec = param_numbers(c["calibration"])
        if vec is not None:
            rows.append(c)
            vecs.append(vec)
    keep = np.isfinite(np.array(vecs, dtype=float).reshape(-1, 15)).all(axis=1)
    rows, vecs = [r for r, k in zip(rows, keep, strict=True) if k], [x for x, k in zip(vecs, keep, strict=True) if k]
    if rows:
        vals = np.array(vecs)
        table = _param_table(vals)
        shown = slice(max(0, len(rows) - LOT_CHART_RUNS), len(rows))
        for name, idx, scale, unit, key, centre in LOT_PARAMS:
            pts = []
            for c, v in zip(rows[shown], vals[shown], strict=True):
                lk = c["limits"].get(key)
                s = 1e-3 * scale if key == "offset_max_mg" else 1.0
                pts.append(RunPoint(c["t"], float(v[idx] * scale), None if lk is None else centre + lk * s,
                                    None if lk is None else centre - lk * s, f"run {c['id']} ({c['station_id']})"))
            ch = run_chart(name, unit, pts)
            if len(rows) > LOT_CHART_RUNS:
                ch.note = f"newest {LOT_CHART_RUNS} of {len(rows)} runs drawn; " + ch.note
            charts.append(ch)
    # the lots list shows only without a lot (lot.html): not read here
    return {"lot": lot, "summary": summ, "charts": charts, "parameters": table, "lots": [], "runs_page": page}


# The heavy pages' work as the lanes run it (lanes.py): module-level functions of picklable
# arguments, so a worker process can run them; each opens the store read-only for itself.

def reason_page(settings: WebSettings, code: str, day: str, shift: str, station: str | None, cursor: str = "",
                limit: int = PAGE_SIZE) -> ReasonContext:
    """The reason page's context, read from the store of ``settings``."""
    with open_store(settings) as st:
        return reason_context(st, code, day, shift, station, cursor, limit)


def board_page(settings: WebSettings, serial: str) -> BoardContext:
    """The board page's context, read from the store of ``settings``."""
    with open_store(settings) as st:
        return board_context(st, serial)


def lot_page(settings: WebSettings, lot: str, cursor: str = "", limit: int = PAGE_SIZE) -> LotContext:
    """The lot page's context (no lot: the lots list only), read from the store of ``settings``."""
    with open_store(settings) as st:
        if lot:
            return lot_context(st, lot, cursor, limit)
        return {"lot": "", "summary": None, "charts": [], "parameters": [], "lots": queries.lots(st),
                "runs_page": None}

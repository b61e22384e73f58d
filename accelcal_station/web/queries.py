"""The line page's and the feed's views of the store: the rows the store's query functions
read (store/runpages.py, store/linequeries.py: SQLAlchemy Core over a read-only StoreReader)
turned into what the API and pages show (runs judged by their limits, yields, counts).
Shifts are 8 h from 06:00 UTC (A 06-14, B 14-22, C 22-06).
"""
from __future__ import annotations

import json
import math
from collections import Counter
from datetime import UTC, datetime
from decimal import Decimal

from ..acceptance.reasons import codes
from ..acceptance.rules import DEFAULT_LIMITS
from ..config.safe_yaml import HostileYAML, safe_load
from ..jsontypes import JsonValue
from ..store import linequeries as lq
from ..store import runpages as rp
from ..store.linequeries import SHIFT0_S, SHIFT_S
from ..store.reader import StoreReader as Store
from ..store.records import load_or, stored_reasons
from ..store.rowcheck import JSON_MAX_DEPTH, CheckedRow
from .views import (
    Damaged,
    FeedRow,
    Judged,
    LotCalibration,
    LotCounts,
    LotRow,
    LotYield,
    Rates,
    RunFilters,
    RunView,
    SeriesPoint,
    ShiftYield,
    StationRow,
    StationYield,
)

WINDOW_S = 24 * 3600.0  # the line page's yields: the day before the newest run
T_END = 253402300800.0  # an open window's end: after every time a run can have


def _damage(row: CheckedRow) -> list[dict[str, str]]:
    return [d.to_dict() for d in row.damage]


def shift_label(bucket: int) -> str:
    """Shift number since the epoch as "2026-11-24 A 06:00" (bucket 0 began at 06:00 UTC, an A shift)."""
    t = datetime.fromtimestamp(bucket * SHIFT_S + SHIFT0_S, UTC)
    return f"{t:%Y-%m-%d} {'ABC'[bucket % 3]} {t:%H:%M}"


def limits_from_text(text: str | None) -> dict[str, float]:
    """The acceptance section of a config's text (numbers only) with the limits every run is judged
    on by default (acceptance.rules.DEFAULT_LIMITS); {} when it cannot be read."""
    try:
        acc = (safe_load(text or "") or {}).get("acceptance") or {}
    except (HostileYAML, ValueError, AttributeError):  # a stored config is only advisory here
        return {}
    if not isinstance(acc, dict):
        return {}
    got = {str(k): float(v) for k, v in acc.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
           and math.isfinite(v)}
    return {**DEFAULT_LIMITS, **got}


def quick_json(text: object, default: JsonValue) -> JsonValue:
    """A JSON column's value as load_or reads it, faster for the common small document: one with
    fewer brackets than rowcheck's depth limit cannot nest deeper, so json.loads is safe on it
    (NaN and infinities still refused); anything else goes through load_or's full check."""
    if not isinstance(text, str):
        return default  # NULL, or not text: damaged (load_or refuses it too)
    if len(text) < 65536 and text.count("[") + text.count("{") < JSON_MAX_DEPTH:
        try:
            got: JsonValue = _DECODER.decode(text)
        except ValueError:
            return default
        return got
    return load_or(text, default)


def _no_constant(s: str) -> float:
    raise ValueError(f"{s} is not a number JSON allows")


_DECODER = json.JSONDecoder(parse_constant=_no_constant)


def _finite_numbers(value: JsonValue) -> dict[str, float]:
    """The finite numbers of a JSON object ({key: number}; anything else left out)."""
    return {str(k): float(v) for k, v in (value.items() if isinstance(value, dict) else ())
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}


def stored_limits(value: object) -> dict[str, float] | None:
    """A run's ``limits`` column as {key: number}; None when absent or damaged."""
    got = quick_json(value, None)
    return _finite_numbers(got) if isinstance(got, dict) else None


def fill_limits(store: Store, rows: list[CheckedRow]) -> list[Judged]:
    """Each row's limits (its ``limits`` column parsed, else its config's, read once per config hash)."""
    memo: dict[object, dict[str, float] | None] = {}  # a line's runs share a few limits texts: each parsed once
    own = []
    for r in rows:
        t = r.value("limits")
        if t not in memo:
            memo[t] = stored_limits(t)
        own.append(memo[t])
    missing = {str(h) for r, o in zip(rows, own, strict=True) if o is None and (h := r.value("config_hash"))}
    by_hash: dict[str, dict[str, float]] = {}
    if missing:
        for r in rp.configs_by_hash(store, sorted(missing)):
            got = limits_from_text(r.text("t"))
            if got:
                by_hash[r.text("config_hash") or ""] = got
    out: list[Judged] = []
    for r, o in zip(rows, own, strict=True):
        cfg = by_hash.get(r.text("config_hash") or "")  # shared between rows: read, never changed
        out.append({"limits": o if o is not None else cfg,
                    "source": "stored" if o is not None else ("config" if cfg is not None else None)})
    return out


def summary(row: CheckedRow, judged: Judged | None = None) -> RunView:
    """A run row (SUMMARY_COLS) with the limits it was judged by (fill_limits; None: what the row
    itself holds) as the API and pages show it."""
    fit = quick_json(row.value("fit_summary"), {})
    reasons = stored_reasons(row.text("reasons"))
    if judged is None:
        lim = stored_limits(row.value("limits"))
        judged = {"limits": lim, "source": "stored" if lim is not None else None}
    measured = _finite_numbers(fit.get("measured") if isinstance(fit, dict) else None)
    t = row.text
    damaged: Damaged = {"damage": _damage(row)} if row.damage else {}
    # the damage between the row's columns and what is read from them, as the feed's JSON has it
    return {"id": row.int("id"), "started_at": row.real("started_at"), "finished_at": row.real("finished_at"),
            "status": t("status"), "status_reason": t("status_reason"), "device_serial": t("device_serial"),
            "chip": t("chip"), "station_id": t("station_id"), "operator": t("operator"), "lot": t("lot"),
            "model": t("model"), "verdict": t("verdict"), "nvm_status": t("nvm_status"), "limits": judged["limits"],
            **damaged, "limits_source": judged["source"],
            "reasons": [{"code": r.code, "message": str(r)} for r in reasons],  # Reason.to_dict, typed
            "reason_codes": codes(reasons), "residual_rms_mg": measured.get("residual_rms_mg"), "measured": measured}


def summaries_of(store: Store, rows: list[CheckedRow]) -> list[RunView]:
    """``summary`` of each row, judged by its limits (fill_limits)."""
    return [summary(r, j) for r, j in zip(rows, fill_limits(store, rows), strict=True)]


def _count(v: object) -> int:
    """An aggregate's count (an int; a Decimal from PostgreSQL's sum), 0 for NULL."""
    return int(v) if isinstance(v, (int, float, Decimal)) and not isinstance(v, bool) else 0


def newest_start(store: Store) -> float | None:
    return lq.newest_start(store).real("t")


def window_start(store: Store) -> float | None:
    t = newest_start(store)
    return None if t is None else t - WINDOW_S


def station_rows(store: Store, t0: float, t1: float = T_END) -> list[StationRow]:
    """Per station: its latest run, and runs, PASS and first-pass yield in [t0, t1)."""
    latest = lq.station_latest(store)
    yields = {r.value("station_id"): _rates(r) for r in lq.yields(store, t0, t1, by_shift=False)}
    none: Rates = {"runs": 0, "pass": 0, "first_runs": 0, "yield": None, "first_pass_yield": None}
    return [{"station_id": row.text("station_id"), "latest": summary(row),
             **yields.get(row.value("station_id"), none)} for row in latest]


def station_yields(rows: list[StationRow]) -> list[StationYield]:
    """The stations' yields without their latest runs (the API's /yield)."""
    return [{"station_id": s["station_id"], "runs": s["runs"], "pass": s["pass"], "first_runs": s["first_runs"],
             "yield": s["yield"], "first_pass_yield": s["first_pass_yield"]} for s in rows]


def _rates(y: CheckedRow) -> Rates:
    n, first, passed = _count(y.value("n")), _count(y.value("first_n")), _count(y.value("pass"))
    return {"runs": n, "pass": passed, "first_runs": first, "yield": (passed / n) if n else None,
            "first_pass_yield": (_count(y.value("first_pass")) / first) if first else None}


def shift_rows(store: Store, t0: float, t1: float = T_END) -> list[ShiftYield]:
    return [{"station_id": y.text("station_id"), "shift": shift_label(_count(y.value("shift"))), **_rates(y)}
            for y in lq.yields(store, t0, t1, by_shift=True)]


def reason_counts(store: Store, t0: float, t1: float = T_END) -> list[tuple[str, int]]:
    """FAIL runs in [t0, t1) per reason code (a run counts once per code)."""
    rows = lq.fail_reasons(store, t0, t1)
    counts: Counter[str] = Counter()
    for r in rows:
        counts.update(set(codes(stored_reasons(r.text("reasons")))))
    return counts.most_common()


def recent(store: Store, limit: int = 20) -> list[RunView]:
    """The newest runs, running ones included."""
    return summaries_of(store, rp.newest_runs(store, limit))


def reason_runs(store: Store, code: str, t0: float, t1: float, station: str | None, order: str,
                after_id: int | None, n: int, chunk: int = 500) -> list[RunView]:
    """Up to ``n`` FAIL runs in [t0, t1) (of one station) with reason ``code``, in ``order`` by id after
    ``after_id`` (a keyset, no OFFSET); the store's rows are read ``chunk`` at a time until ``n`` match."""
    rows: list[CheckedRow] = []
    while len(rows) < n:
        got = lq.fail_runs(store, t0, t1, station, order, after_id, chunk)
        rows += [r for r in got if code in codes(stored_reasons(r.text("reasons")))]
        ids = [i for r in got if (i := r.int("id")) is not None]
        if len(got) < chunk or not ids:
            break
        after_id = ids[-1]
    return summaries_of(store, rows[:n])


def station_series(store: Store, station: str | None, t0: float, t1: float, limit: int = 100) -> list[SeriesPoint]:
    """One station's newest complete runs in [t0, t1) (at most ``limit``): id, start, measured figures
    and the limits each was judged by."""
    rows = lq.station_series(store, station, t0, t1, limit)
    out: list[SeriesPoint] = []
    for r, j in zip(rows, fill_limits(store, rows), strict=True):
        fit = quick_json(r.value("fit_summary"), {})
        m = fit.get("measured") if isinstance(fit, dict) else None
        start = r.real("started_at")
        if isinstance(m, dict) and start is not None:
            out.append({"id": r.int("id"), "t": start, "limits": j["limits"] or {}, "measured": _finite_numbers(m)})
    return out


def newest_config_text(store: Store) -> str | None:
    row = rp.newest_config_text(store)
    return row.text("config_text") if row is not None else None


def feed_rows(store: Store, low: int, limit: int = 5000) -> list[FeedRow]:
    """(id, status, started_at) of the runs with id >= low, in id order: one statement, one snapshot."""
    rows = rp.feed_rows(store, low, limit)
    return [{"id": rid, "status": r.text("status"), "started_at": r.real("started_at")}
            for r in rows if (rid := r.int("id")) is not None]


def summaries(store: Store, ids: list[int]) -> list[RunView]:
    return summaries_of(store, rp.runs_by_id(store, ids))


def run_page(store: Store, filters: RunFilters, order: str, after_id: int | None, limit: int) -> list[RunView]:
    """One page of runs by keyset on id: ``order`` "asc"/"desc", after ``after_id`` (exclusive);
    one indexed range scan whatever the page's depth (no OFFSET)."""
    return summaries_of(store, rp.run_page(store, filters, order, after_id, limit))


def run_count(store: Store, filters: RunFilters) -> int:
    return _count(rp.run_count(store, filters))


def serials_like(store: Store, text: str, limit: int = 20) -> list[str]:
    rows = rp.serials_like(store, text, limit)
    return [s for r in rows if (s := r.text("device_serial")) is not None]


def lot_yields(store: Store, t0: float, t1: float, limit: int = 12) -> list[LotYield]:
    """The lots with complete runs in [t0, t1), newest first: runs, PASS and yield in the window."""
    return [{"lot": r.text("lot"), "runs": _count(r.value("n")), "pass": _count(r.value("pass")),
             "yield": _count(r.value("pass")) / _count(r.value("n")) if _count(r.value("n")) else None}
            for r in lq.lot_yields(store, t0, t1, limit)]


def lots(store: Store, limit: int = 50) -> list[LotRow]:
    rows = lq.lots(store, limit)
    return [{"lot": r.text("lot"), "runs": _count(r.value("runs")), "last": r.real("last")} for r in rows]


def dumps(x: object) -> str:
    return json.dumps(x, allow_nan=False)


def head_rows(store: Store) -> tuple[int, list[FeedRow]]:
    """Where the feed is now: the lowest running run's id (else the newest id + 1) and the rows from it."""
    row = rp.feed_head(store)
    running = row.value("r")
    low = _count(running) if running is not None else _count(row.value("m")) + 1
    return low, feed_rows(store, low)


def lot_counts(store: Store, lot: str) -> LotCounts:
    """The lot page's counts, read by the store (store.linequeries.lot_counts)."""
    got = lq.lot_counts(store, lot)
    rows, span, nvm, stops, fails = got["status"], got["span"][0], got["nvm"], got["stops"], got["fails"]
    by_status: Counter[str] = Counter()
    verdicts: Counter[str] = Counter()
    for r in rows:
        by_status[str(r.value("status"))] += _count(r.value("n"))
        if r.value("status") == "complete" and r.value("verdict"):
            verdicts[str(r.value("verdict"))] += _count(r.value("n"))
    reasons: Counter[str] = Counter()
    for r in fails:
        reasons.update(set(codes(stored_reasons(r.text("reasons")))))
    decided = verdicts["PASS"] + verdicts["FAIL"]
    return {"runs": sum(by_status.values()), "by_status": dict(by_status), "pass": verdicts["PASS"],
            "fail": verdicts["FAIL"], "pass_rate": verdicts["PASS"] / decided if decided else None,
            "devices": _count(span.value("boards")), "first_started": span.real("t0"), "last_started": span.real("t1"),
            "nvm": {str(r.value("nvm_status") or "none"): _count(r.value("n")) for r in nvm},
            "interruptions": {str(r.value("status_reason") or "unknown"): _count(r.value("n")) for r in stops},
            "failure_reasons": dict(reasons.most_common())}


def lot_calibrations(store: Store, lot: str) -> list[LotCalibration]:
    """The lot's complete runs with a calibration, oldest first: id, start, station, calibration (parsed)
    and the limits each was judged by."""
    rows = lq.lot_calibrations(store, lot)
    out: list[LotCalibration] = []
    for r, j in zip(rows, fill_limits(store, rows), strict=True):
        cal = quick_json(r.value("calibration"), None)
        start = r.real("started_at")
        if isinstance(cal, dict) and start is not None:
            out.append({"id": r.int("id"), "t": start, "station_id": r.text("station_id"), "calibration": cal,
                        "limits": j["limits"] or {}})
    return out

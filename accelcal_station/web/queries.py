"""The line page's and the feed's reads: plain aggregate SELECTs on the store's own connection.

The store's public functions (store/runs.py) load whole runs; the line page over a store of
100,000 runs needs counts grouped in SQL instead, so these few statements live here, small
and isolated, and read only.  Columns and tables are the store's schema (store/schema.py).
Shifts are 8 h from 06:00 UTC (A 06-14, B 14-22, C 22-06).
"""
from __future__ import annotations

import json
import math
from collections import Counter
from datetime import UTC, datetime
from typing import Any

from ..acceptance.reasons import codes
from ..acceptance.rules import DEFAULT_LIMITS
from ..config.safe_yaml import HostileYAML, safe_load
from ..store.liveness import mark_stale
from ..store.records import load_or, stored_reasons
from ..store.rowcheck import JSON_MAX_DEPTH, SPECS, check_row
from ..store.runs import Store

SHIFT_S = 8 * 3600.0
SHIFT0_S = 6 * 3600.0  # shift A starts at 06:00 UTC
WINDOW_S = 24 * 3600.0  # the line page's yields: the day before the newest run
SUMMARY_COLS = ("id, started_at, finished_at, status, status_reason, device_serial, chip, station_id, operator, "
                "lot, model, verdict, reasons, nvm_status, fit_summary, limits, config_hash, host, pid, heartbeat_at, "
                "heartbeat_s")


# runs columns checked on every read as the store's own reads check them (store/rowcheck.py); the
# JSON columns stay text here and go through load_or / stored_reasons, which bound them alike
_JSON_COLS = ("reasons", "nvm_outcome", "calibration", "fit_summary", "limits")
_SCALAR_COLS = frozenset(SPECS["runs"]) - set(_JSON_COLS)
# a stored time a page can show (year 1970 to 9999): a damaged one is left out of the aggregates
SANE_T = "(started_at BETWEEN 0 AND 253402300799)"
T_END = 253402300800.0  # an open window's end: after every time a run can have


def select_unchecked(store: Store, sql: str, **params: Any) -> list[dict[str, Any]]:
    """Rows of one read-only statement as dicts, with no column check: for a statement that itself
    keeps damaged scalars out (SANE_T; the integer key) and reads JSON columns through quick_json."""
    from sqlalchemy import text

    conn = store._db.conn  # the one place the web layer touches the store's connection
    return [dict(r) for r in conn.execute(text(sql), params).mappings().all()]


def select(store: Store, sql: str, **params: Any) -> list[dict[str, Any]]:
    """Rows of one read-only statement (named ``:params``) as dicts, on the store's connection; a
    damaged value of a runs column (wrong type, time out of range) reads as None, named in
    ``damage`` (as ``report list`` names it), never an exception in a page."""
    out = []
    for row in select_unchecked(store, sql, **params):
        scalars = {k: v for k, v in row.items() if k in _SCALAR_COLS}
        if scalars:
            checked, damage = check_row("runs", scalars)
            row.update(checked)
            if damage:
                row["damage"] = [d.to_dict() for d in damage]
            mark_stale(row)  # running, its station process gone: stale (store/liveness.py)
        out.append(row)
    return out


def _bucket(store: Store) -> str:
    """SQL for a run's shift number since the epoch (floor; SQLite's CAST truncates, times are positive)."""
    expr = f"(started_at - {SHIFT0_S}) / {SHIFT_S}"
    return f"floor({expr})" if store.dialect == "postgresql" else f"CAST({expr} AS INTEGER)"


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


def quick_json(text: Any, default: Any) -> Any:
    """A JSON column's value as load_or reads it, faster for the common small document: one with
    fewer brackets than rowcheck's depth limit cannot nest deeper, so json.loads is safe on it
    (NaN and infinities still refused); anything else goes through load_or's full check."""
    if not isinstance(text, str):
        return default if text is None else load_or(text, default)
    if len(text) < 65536 and text.count("[") + text.count("{") < JSON_MAX_DEPTH:
        try:
            return _DECODER.decode(text)
        except ValueError:
            return default
    return load_or(text, default)


def _no_constant(s: str) -> Any:
    raise ValueError(f"{s} is not a number JSON allows")


_DECODER = json.JSONDecoder(parse_constant=_no_constant)


def stored_limits(value: Any) -> dict[str, float] | None:
    """A run's ``limits`` column as {key: number}; None when absent or damaged."""
    got = quick_json(value, None)
    if not isinstance(got, dict):
        return None
    return {str(k): float(v) for k, v in got.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}


def fill_limits(store: Store, rows: list[dict[str, Any]]) -> None:
    """Each row's ``limits`` (parsed) and ``limits_source``: "stored" (schema 4 runs), "config" (an older
    run: the acceptance section of the config it ran with, read once per config hash) or None."""
    memo: dict[Any, dict[str, float] | None] = {}  # a line's runs share a few limits texts: each parsed once
    own = []
    for r in rows:
        t = r.get("limits")
        if t not in memo:
            memo[t] = stored_limits(t)
        own.append(memo[t])
    missing = {str(h) for r, o in zip(rows, own, strict=True) if o is None and (h := r.get("config_hash"))}
    by_hash: dict[str, dict[str, float]] = {}
    if missing:
        marks = ", ".join(f":h{k}" for k in range(len(missing)))
        for r in select(store, f"SELECT config_hash, min(config_text) AS t FROM runs WHERE config_hash IN ({marks})"
                        " GROUP BY config_hash", **{f"h{k}": h for k, h in enumerate(sorted(missing))}):
            got = limits_from_text(r["t"])
            if got:
                by_hash[r["config_hash"]] = got
    for r, o in zip(rows, own, strict=True):
        cfg = by_hash.get(r.get("config_hash") or "")
        r["limits"] = o if o is not None else cfg  # shared between rows: read, never changed
        r["limits_source"] = "stored" if o is not None else ("config" if cfg is not None else None)


def summary(row: dict[str, Any]) -> dict[str, Any]:
    """A run row (SUMMARY_COLS, limits filled by fill_limits) as the API and pages show it: typed
    reasons, the fit figures, the limits it was judged by."""
    loaded = quick_json(row.get("fit_summary"), {})
    fit: dict[str, Any] = loaded if isinstance(loaded, dict) else {}
    reasons = stored_reasons(row.get("reasons"))
    out = {k: row[k] for k in row if k not in ("reasons", "fit_summary", "config_hash", "host", "pid",
                                                   "heartbeat_at", "heartbeat_s")}
    if "limits_source" not in out:  # not filled: what the row itself holds
        lim = stored_limits(row.get("limits"))
        out.update(limits=lim, limits_source="stored" if lim is not None else None)
    m = fit.get("measured")
    measured = {str(k): float(v) for k, v in (m.items() if isinstance(m, dict) else ())
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}
    out.update(reasons=[r.to_dict() for r in reasons], reason_codes=codes(reasons),
               residual_rms_mg=measured.get("residual_rms_mg"), measured=measured)
    return out


def newest_start(store: Store) -> float | None:
    row = select(store, f"SELECT max(started_at) AS t FROM runs WHERE {SANE_T}")
    return None if row[0]["t"] is None else float(row[0]["t"])


def window_start(store: Store) -> float | None:
    row = select(store, f"SELECT max(started_at) AS t FROM runs WHERE {SANE_T}")
    return None if row[0]["t"] is None else float(row[0]["t"]) - WINDOW_S


def station_rows(store: Store, t0: float, t1: float = T_END) -> list[dict[str, Any]]:
    """Per station: its latest run, and runs, PASS and first-pass yield in [t0, t1)."""
    latest = select(store, f"SELECT {SUMMARY_COLS} FROM runs WHERE id IN "
                    "(SELECT max(id) FROM runs GROUP BY station_id) ORDER BY station_id")
    yields = {(r["station_id"], None): r for r in _yields(store, t0, t1, by_shift=False)}
    out = []
    for row in latest:
        y = yields.get((row["station_id"], None), {})
        out.append({"station_id": row["station_id"], "latest": summary(row), **_rates(y)})
    return out


def _rates(y: dict[str, Any]) -> dict[str, Any]:
    n, first = int(y.get("n") or 0), int(y.get("first_n") or 0)
    return {"runs": n, "pass": int(y.get("pass") or 0), "first_runs": first,
            "yield": (int(y.get("pass") or 0) / n) if n else None,
            "first_pass_yield": (int(y.get("first_pass") or 0) / first) if first else None}


def _yields(store: Store, t0: float, t1: float, by_shift: bool) -> list[dict[str, Any]]:
    """Complete runs in [t0, t1) grouped by station (and shift): runs, PASS, first runs of a board
    (no earlier complete run of the same serial) and those that passed."""
    first = ("NOT EXISTS (SELECT 1 FROM runs p WHERE p.device_serial = r.device_serial AND p.status = 'complete'"
             " AND p.started_at < r.started_at)")
    shift = f", {_bucket(store)} AS shift" if by_shift else ""
    group = ", shift" if by_shift else ""
    return select(store, f"SELECT station_id{shift}, count(*) AS n,"
                  " sum(CASE WHEN verdict = 'PASS' THEN 1 ELSE 0 END) AS pass,"
                  f" sum(CASE WHEN {first} THEN 1 ELSE 0 END) AS first_n,"
                  f" sum(CASE WHEN verdict = 'PASS' AND {first} THEN 1 ELSE 0 END) AS first_pass"
                  f" FROM runs r WHERE status = 'complete' AND started_at >= :t0 AND started_at < :t1 AND {SANE_T}"
                  f" GROUP BY station_id{group}"
                  f" ORDER BY station_id{group}", t0=t0, t1=t1)


def shift_rows(store: Store, t0: float, t1: float = T_END) -> list[dict[str, Any]]:
    return [{"station_id": y["station_id"], "shift": shift_label(int(y["shift"])), **_rates(y)}
            for y in _yields(store, t0, t1, by_shift=True)]


def reason_counts(store: Store, t0: float, t1: float = T_END) -> list[tuple[str, int]]:
    """FAIL runs in [t0, t1) per reason code (a run counts once per code)."""
    rows = select(store, "SELECT reasons FROM runs WHERE status = 'complete' AND verdict = 'FAIL'"
                  " AND started_at >= :t0 AND started_at < :t1", t0=t0, t1=t1)
    counts: Counter[str] = Counter()
    for r in rows:
        counts.update(set(codes(stored_reasons(r["reasons"]))))
    return counts.most_common()


def recent(store: Store, limit: int = 20) -> list[dict[str, Any]]:
    """The newest runs, running ones included."""
    rows = select(store, f"SELECT {SUMMARY_COLS} FROM runs ORDER BY id DESC LIMIT :n", n=int(limit))
    fill_limits(store, rows)
    return [summary(r) for r in rows]


def reason_runs(store: Store, code: str, t0: float, t1: float, station: str | None = None,
                limit: int = 200) -> list[dict[str, Any]]:
    """The FAIL runs in [t0, t1) (of one station) with reason ``code``, newest first (at most ``limit``)."""
    where = "status = 'complete' AND verdict = 'FAIL' AND started_at >= :t0 AND started_at < :t1"
    params: dict[str, Any] = {"t0": t0, "t1": t1}
    if station is not None:
        where += " AND station_id = :s"
        params["s"] = station
    rows = [r for r in select(store, f"SELECT {SUMMARY_COLS} FROM runs WHERE {where} ORDER BY id DESC", **params)
            if code in codes(stored_reasons(r["reasons"]))][:limit]
    fill_limits(store, rows)
    return [summary(r) for r in rows]


def station_series(store: Store, station: str | None, t0: float, t1: float, limit: int = 100) -> list[dict[str, Any]]:
    """One station's newest complete runs in [t0, t1) (at most ``limit``): id, start, measured figures
    and the limits each was judged by."""
    cond = "station_id IS NULL" if station is None else "station_id = :s"
    rows = select(store, "SELECT id, started_at, station_id, fit_summary, limits, config_hash FROM runs"
                  f" WHERE {cond} AND status = 'complete' AND started_at >= :t0 AND started_at < :t1 AND {SANE_T}"
                  " ORDER BY started_at DESC LIMIT :n", s=station, t0=t0, t1=t1, n=int(limit))
    fill_limits(store, rows)
    out = []
    for r in rows:
        fit = quick_json(r["fit_summary"], {})
        m = fit.get("measured") if isinstance(fit, dict) else None
        if isinstance(m, dict) and r["started_at"] is not None:
            out.append({"id": r["id"], "t": float(r["started_at"]), "limits": r["limits"] or {},
                        "measured": {k: float(v) for k, v in m.items() if isinstance(v, (int, float))
                                     and not isinstance(v, bool) and math.isfinite(v)}})
    return out


def newest_config_text(store: Store) -> str | None:
    rows = select(store, "SELECT config_text FROM runs WHERE config_text IS NOT NULL ORDER BY id DESC LIMIT 1")
    return rows[0]["config_text"] if rows else None


def feed_rows(store: Store, low: int, limit: int = 5000) -> list[dict[str, Any]]:
    """(id, status, started_at) of the runs with id >= low, in id order: one statement, one snapshot."""
    return select(store, "SELECT id, status, started_at FROM runs WHERE id >= :low ORDER BY id LIMIT :n",
                  low=int(low), n=int(limit))


def summaries(store: Store, ids: list[int]) -> list[dict[str, Any]]:
    if not ids:
        return []
    marks = ", ".join(f":i{k}" for k in range(len(ids)))
    rows = select(store, f"SELECT {SUMMARY_COLS} FROM runs WHERE id IN ({marks}) ORDER BY id",
                  **{f"i{k}": int(v) for k, v in enumerate(ids)})
    fill_limits(store, rows)
    return [summary(r) for r in rows]


# the MES API's filters: parameter -> (column, operator)
RUN_FILTERS = {"since": ("started_at", ">="), "until": ("started_at", "<"), "station": ("station_id", "="),
               "serial": ("device_serial", "="), "verdict": ("verdict", "="), "lot": ("lot", "="),
               "status": ("status", "=")}


def _filter_sql(filters: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
    where, params = [], {}
    for k, v in filters.items():
        if v is not None:
            col, op = RUN_FILTERS[k]
            where.append(f"{col} {op} :f_{k}")
            params[f"f_{k}"] = v
    return where, params


def run_page(store: Store, filters: dict[str, Any], order: str, after_id: int | None,
             limit: int) -> list[dict[str, Any]]:
    """One page of runs by keyset on id: ``order`` "asc"/"desc", after ``after_id`` (exclusive);
    one indexed range scan whatever the page's depth (no OFFSET)."""
    where, params = _filter_sql(filters)
    if after_id is not None:
        where.append("id > :after_id" if order == "asc" else "id < :after_id")
        params["after_id"] = int(after_id)
    cond = " AND ".join(where) or "1 = 1"
    way = "ASC" if order == "asc" else "DESC"
    rows = select(store, f"SELECT {SUMMARY_COLS} FROM runs WHERE {cond} ORDER BY id {way} LIMIT :n", n=int(limit),
                  **params)
    fill_limits(store, rows)
    return [summary(r) for r in rows]


def run_count(store: Store, filters: dict[str, Any]) -> int:
    where, params = _filter_sql(filters)
    cond = " AND ".join(where) or "1 = 1"
    return int(select(store, f"SELECT count(*) AS n FROM runs WHERE {cond}", **params)[0]["n"])


def serials_like(store: Store, text: str, limit: int = 20) -> list[str]:
    rows = select(store, "SELECT DISTINCT device_serial FROM runs WHERE device_serial LIKE :p ORDER BY device_serial"
                  " LIMIT :n", p=text.replace("%", "").replace("_", "") + "%", n=int(limit))
    return [r["device_serial"] for r in rows if r["device_serial"] is not None]


def lots(store: Store, limit: int = 50) -> list[dict[str, Any]]:
    return select(store, "SELECT lot, count(*) AS runs, max(started_at) AS last FROM runs WHERE lot IS NOT NULL"
                  f" AND {SANE_T} GROUP BY lot ORDER BY max(started_at) DESC LIMIT :n", n=int(limit))


def dumps(x: Any) -> str:
    return json.dumps(x, allow_nan=False)


def head_rows(store: Store) -> tuple[int, list[dict[str, Any]]]:
    """Where the feed is now: the lowest running run's id (else the newest id + 1) and the rows from it."""
    row = select(store, "SELECT min(CASE WHEN status = 'running' THEN id END) AS r, max(id) AS m FROM runs")[0]
    low = int(row["r"]) if row["r"] is not None else int(row["m"] or 0) + 1
    return low, feed_rows(store, low)


def lot_counts(store: Store, lot: str) -> dict[str, Any]:
    """The lot page's counts, each one grouped SELECT over the lot's rows (index runs_lot)."""
    rows = select(store, "SELECT status, verdict, count(*) AS n FROM runs WHERE lot = :lot GROUP BY status, verdict",
                  lot=lot)
    by_status: Counter[str] = Counter()
    verdicts: Counter[str] = Counter()
    for r in rows:
        by_status[str(r["status"])] += int(r["n"])
        if r["status"] == "complete" and r["verdict"]:
            verdicts[str(r["verdict"])] += int(r["n"])
    span = select(store, "SELECT count(*) AS n, count(DISTINCT device_serial) AS boards, min(started_at) AS t0,"
                  f" max(started_at) AS t1 FROM runs WHERE lot = :lot AND {SANE_T}", lot=lot)[0]
    nvm = select(store, "SELECT nvm_status, count(*) AS n FROM runs WHERE lot = :lot AND status = 'complete'"
                 " GROUP BY nvm_status", lot=lot)
    stops = select(store, "SELECT status_reason, count(*) AS n FROM runs WHERE lot = :lot AND status IN"
                   " ('interrupted', 'error') GROUP BY status_reason ORDER BY count(*) DESC LIMIT 20", lot=lot)
    fails = select(store, "SELECT reasons FROM runs WHERE lot = :lot AND status = 'complete' AND verdict = 'FAIL'",
                   lot=lot)
    reasons: Counter[str] = Counter()
    for r in fails:
        reasons.update(set(codes(stored_reasons(r["reasons"]))))
    decided = verdicts["PASS"] + verdicts["FAIL"]
    return {"runs": sum(by_status.values()), "by_status": dict(by_status), "pass": verdicts["PASS"],
            "fail": verdicts["FAIL"], "pass_rate": verdicts["PASS"] / decided if decided else None,
            "devices": int(span["boards"] or 0), "first_started": span["t0"], "last_started": span["t1"],
            "nvm": {str(r["nvm_status"] or "none"): int(r["n"]) for r in nvm},
            "interruptions": {str(r["status_reason"] or "unknown"): int(r["n"]) for r in stops},
            "failure_reasons": dict(reasons.most_common())}


def lot_calibrations(store: Store, lot: str) -> list[dict[str, Any]]:
    """The lot's complete runs with a calibration, oldest first: id, start, station, calibration (parsed)
    and the limits each was judged by."""
    # id is the integer key; SANE_T keeps a damaged time out (text, blob, NaN and infinities compare
    # outside the range on SQLite and PostgreSQL alike); station_id is only shown, escaped
    rows = select_unchecked(store, "SELECT id, started_at, station_id, calibration, limits, config_hash FROM runs"
                            f" WHERE lot = :lot AND status = 'complete' AND calibration IS NOT NULL AND {SANE_T}"
                            " ORDER BY started_at, id", lot=lot)
    fill_limits(store, rows)
    out = []
    for r in rows:
        cal = quick_json(r["calibration"], None)
        if isinstance(cal, dict) and r["started_at"] is not None:
            out.append({"id": r["id"], "t": float(r["started_at"]), "station_id": r["station_id"],
                        "calibration": cal, "limits": r["limits"] or {}})
    return out

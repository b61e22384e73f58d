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
from ..store.liveness import mark_stale
from ..store.records import load_or, stored_reasons
from ..store.rowcheck import SPECS, check_row
from ..store.runs import Store

SHIFT_S = 8 * 3600.0
SHIFT0_S = 6 * 3600.0  # shift A starts at 06:00 UTC
WINDOW_S = 24 * 3600.0  # the line page's yields: the day before the newest run
SUMMARY_COLS = ("id, started_at, finished_at, status, status_reason, device_serial, chip, station_id, operator, "
                "lot, model, verdict, reasons, nvm_status, fit_summary, host, pid")


# runs columns checked on every read as the store's own reads check them (store/rowcheck.py); the
# JSON columns stay text here and go through load_or / stored_reasons, which bound them alike
_JSON_COLS = ("reasons", "nvm_outcome", "calibration", "fit_summary")
_SCALAR_COLS = frozenset(SPECS["runs"]) - set(_JSON_COLS)
# a stored time a page can show (year 1970 to 9999): a damaged one is left out of the aggregates
SANE_T = "(started_at BETWEEN 0 AND 253402300799)"


def select(store: Store, sql: str, **params: Any) -> list[dict[str, Any]]:
    """Rows of one read-only statement (named ``:params``) as dicts, on the store's connection; a
    damaged value of a runs column (wrong type, time out of range) reads as None, named in
    ``damage`` (as ``report list`` names it), never an exception in a page."""
    from sqlalchemy import text

    conn = store._db.conn  # the one place the web layer touches the store's connection
    out = []
    for r in conn.execute(text(sql), params).mappings().all():
        row = dict(r)
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


def summary(row: dict[str, Any]) -> dict[str, Any]:
    """A run row (SUMMARY_COLS) as the API and pages show it: typed reasons, the fit figures."""
    loaded = load_or(row.get("fit_summary"), {})
    fit: dict[str, Any] = loaded if isinstance(loaded, dict) else {}
    reasons = stored_reasons(row.get("reasons"))
    out = {k: row[k] for k in row if k not in ("reasons", "fit_summary", "host", "pid")}
    m = fit.get("measured")
    measured = {str(k): float(v) for k, v in (m.items() if isinstance(m, dict) else ())
                if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}
    out.update(reasons=[r.to_dict() for r in reasons], reason_codes=codes(reasons),
               residual_rms_mg=measured.get("residual_rms_mg"), measured=measured)
    return out


def window_start(store: Store) -> float | None:
    row = select(store, f"SELECT max(started_at) AS t FROM runs WHERE {SANE_T}")
    return None if row[0]["t"] is None else float(row[0]["t"]) - WINDOW_S


def station_rows(store: Store, t0: float) -> list[dict[str, Any]]:
    """Per station: its latest run, and runs, PASS and first-pass yield since ``t0``."""
    latest = select(store, f"SELECT {SUMMARY_COLS} FROM runs WHERE id IN "
                    "(SELECT max(id) FROM runs GROUP BY station_id) ORDER BY station_id")
    yields = {(r["station_id"], None): r for r in _yields(store, t0, by_shift=False)}
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


def _yields(store: Store, t0: float, by_shift: bool) -> list[dict[str, Any]]:
    """Complete runs since t0 grouped by station (and shift): runs, PASS, first runs of a board
    (no earlier complete run of the same serial) and those that passed."""
    first = ("NOT EXISTS (SELECT 1 FROM runs p WHERE p.device_serial = r.device_serial AND p.status = 'complete'"
             " AND p.started_at < r.started_at)")
    shift = f", {_bucket(store)} AS shift" if by_shift else ""
    group = ", shift" if by_shift else ""
    return select(store, f"SELECT station_id{shift}, count(*) AS n,"
                  " sum(CASE WHEN verdict = 'PASS' THEN 1 ELSE 0 END) AS pass,"
                  f" sum(CASE WHEN {first} THEN 1 ELSE 0 END) AS first_n,"
                  f" sum(CASE WHEN verdict = 'PASS' AND {first} THEN 1 ELSE 0 END) AS first_pass"
                  f" FROM runs r WHERE status = 'complete' AND started_at >= :t0 AND {SANE_T}"
                  f" GROUP BY station_id{group}"
                  f" ORDER BY station_id{group}", t0=t0)


def shift_rows(store: Store, t0: float) -> list[dict[str, Any]]:
    return [{"station_id": y["station_id"], "shift": shift_label(int(y["shift"])), **_rates(y)}
            for y in _yields(store, t0, by_shift=True)]


def reason_counts(store: Store, t0: float) -> list[tuple[str, int]]:
    """FAIL runs since t0 per reason code (a run counts once per code)."""
    rows = select(store, "SELECT reasons FROM runs WHERE status = 'complete' AND verdict = 'FAIL'"
                  " AND started_at >= :t0", t0=t0)
    counts: Counter[str] = Counter()
    for r in rows:
        counts.update(set(codes(stored_reasons(r["reasons"]))))
    return counts.most_common()


def recent(store: Store, limit: int = 20) -> list[dict[str, Any]]:
    """The newest runs, running ones included."""
    return [summary(r) for r in select(store, f"SELECT {SUMMARY_COLS} FROM runs ORDER BY id DESC LIMIT :n",
                                       n=int(limit))]


def measured_series(store: Store, limit: int = 100) -> list[dict[str, Any]]:
    """The acceptance figures (fit_summary.measured) of the newest complete runs, oldest first."""
    rows = select(store, "SELECT id, station_id, fit_summary FROM runs WHERE status = 'complete'"
                  " AND fit_summary IS NOT NULL ORDER BY id DESC LIMIT :n", n=int(limit))
    out = []
    for r in reversed(rows):
        fit = load_or(r["fit_summary"], {})
        m = fit.get("measured") if isinstance(fit, dict) else None
        if isinstance(m, dict):
            out.append({"id": r["id"], "station_id": r["station_id"], **m})
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
    return [summary(r) for r in rows]


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

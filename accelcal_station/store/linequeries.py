"""The line's aggregate reads: yields per station and shift, failure reasons, a station's newest
runs, the lots and one lot's counts and calibrations, counted in SQL (grouped SELECTs in
SQLAlchemy Core over a ``StoreReader``), so a page over 100,000 runs never loads them.

Shifts are 8 h from 06:00 UTC (A 06-14, B 14-22, C 22-06); a run's shift number since the
epoch is floor((started_at - 6 h) / 8 h).  Every function returns checked rows (runpages.checked).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from .runpages import checked, sane_time, summary_select, unchecked

if TYPE_CHECKING:
    from sqlalchemy import ColumnElement, FromClause

    from .reader import StoreReader
    from .rowcheck import CheckedRow

SHIFT_S = 8 * 3600.0
SHIFT0_S = 6 * 3600.0  # shift A starts at 06:00 UTC


def newest_start(reader: StoreReader) -> CheckedRow:
    """``t``: the newest sane start time."""
    from sqlalchemy import func, select

    from .tables import runs

    return checked(reader, select(func.max(runs.c.started_at).label("t")).where(sane_time()))[0]


def station_latest(reader: StoreReader) -> list[CheckedRow]:
    """Each station's newest run (by id), by station."""
    from sqlalchemy import func, select

    from .tables import runs

    inner = runs.alias("i")
    newest = select(func.max(inner.c.id)).group_by(inner.c.station_id)
    return checked(reader, summary_select().where(runs.c.id.in_(newest)).order_by(runs.c.station_id))


def _shift_of(reader: StoreReader, r: FromClause) -> ColumnElement[int]:
    """A run's shift number since the epoch (floor; SQLite's CAST truncates, sane times are positive)."""
    from sqlalchemy import Integer, cast, func

    expr = (r.c.started_at - SHIFT0_S) / SHIFT_S
    return (func.floor(expr) if reader.dialect == "postgresql" else cast(expr, Integer)).label("shift")


def yields(reader: StoreReader, t0: float, t1: float, by_shift: bool) -> list[CheckedRow]:
    """Complete runs in [t0, t1) grouped by station (and ``shift``): ``n`` runs, ``pass``, ``first_n``
    first runs of a board (no earlier complete run of the same serial) and ``first_pass`` of those."""
    from sqlalchemy import case, func, select

    from .tables import runs

    r, p = runs.alias("r"), runs.alias("p")
    first = ~select(1).where(p.c.device_serial == r.c.device_serial, p.c.status == "complete",
                             p.c.started_at < r.c.started_at).exists()
    passed = r.c.verdict == "PASS"
    keys = [r.c.station_id, *([_shift_of(reader, r)] if by_shift else [])]
    stmt = (select(*keys, func.count().label("n"), func.sum(case((passed, 1), else_=0)).label("pass"),
                   func.sum(case((first, 1), else_=0)).label("first_n"),
                   func.sum(case((passed & first, 1), else_=0)).label("first_pass"))
            .where(r.c.status == "complete", r.c.started_at >= t0, r.c.started_at < t1, sane_time(r.c.started_at))
            .group_by(*keys).order_by(*keys))
    return checked(reader, stmt)


def _fails(t0: float, t1: float) -> list[ColumnElement[bool]]:
    from .tables import runs

    return [runs.c.status == "complete", runs.c.verdict == "FAIL", runs.c.started_at >= t0, runs.c.started_at < t1]


def fail_reasons(reader: StoreReader, t0: float, t1: float) -> list[CheckedRow]:
    """The ``reasons`` of the FAIL runs in [t0, t1)."""
    from sqlalchemy import select

    from .tables import runs

    return checked(reader, select(runs.c.reasons).where(*_fails(t0, t1)))


def fail_runs(reader: StoreReader, t0: float, t1: float, station: str | None, order: str = "desc",
              after_id: int | None = None, limit: int | None = None) -> list[CheckedRow]:
    """The FAIL runs in [t0, t1) (of one station), newest first (``order`` "asc": oldest first), after
    ``after_id`` (exclusive; a keyset on id as runpages.run_page, no OFFSET), at most ``limit``."""
    from .runpages import in_id_range
    from .tables import runs

    where = _fails(t0, t1) + ([runs.c.station_id == station] if station is not None else [])
    if after_id is not None:
        if not in_id_range(after_id):
            return []
        where.append(runs.c.id > after_id if order == "asc" else runs.c.id < after_id)
    stmt = summary_select().where(*where).order_by(runs.c.id.asc() if order == "asc" else runs.c.id.desc())
    return checked(reader, stmt if limit is None else stmt.limit(int(limit)))


def repeated_serials(reader: StoreReader, station: str | None, limit: int) -> list[CheckedRow]:
    """A station's serials with more than one complete calibrated run (``device_serial``, ``n``, ``last``:
    the newest id), the ``limit`` most recently measured: the parts of its Gage R&R study."""
    from sqlalchemy import func, select

    from .tables import runs

    who = runs.c.station_id.is_(None) if station is None else runs.c.station_id == station
    last = func.max(runs.c.id)
    return checked(reader, select(runs.c.device_serial, func.count().label("n"), last.label("last"))
                   .where(who, runs.c.status == "complete", runs.c.calibration.is_not(None),
                          runs.c.device_serial.is_not(None))
                   .group_by(runs.c.device_serial).having(func.count() > 1)
                   .order_by(last.desc()).limit(int(limit)))


def lot_yields(reader: StoreReader, t0: float, t1: float, limit: int) -> list[CheckedRow]:
    """The lots with complete runs in [t0, t1), newest first: ``lot``, ``n`` runs, ``pass``, ``last`` start."""
    from sqlalchemy import case, func, select

    from .tables import runs

    last = func.max(runs.c.started_at)
    return checked(reader, select(runs.c.lot, func.count().label("n"),
                                  func.sum(case((runs.c.verdict == "PASS", 1), else_=0)).label("pass"),
                                  last.label("last"))
                   .where(runs.c.status == "complete", runs.c.started_at >= t0, runs.c.started_at < t1, sane_time())
                   .group_by(runs.c.lot).order_by(last.desc()).limit(int(limit)))


def station_series(reader: StoreReader, station: str | None, t0: float, t1: float, limit: int) -> list[CheckedRow]:
    """One station's newest complete runs in [t0, t1): id, start, station, fit summary, limits, config hash."""
    from sqlalchemy import select

    from .tables import runs

    who = runs.c.station_id.is_(None) if station is None else runs.c.station_id == station
    return checked(reader, select(runs.c.id, runs.c.started_at, runs.c.station_id, runs.c.fit_summary,
                                  runs.c.limits, runs.c.config_hash)
                   .where(who, runs.c.status == "complete", runs.c.started_at >= t0, runs.c.started_at < t1,
                          sane_time())
                   .order_by(runs.c.started_at.desc()).limit(int(limit)))


def lots(reader: StoreReader, limit: int) -> list[CheckedRow]:
    """The lots, newest first: ``lot``, ``runs``, ``last`` (start)."""
    from sqlalchemy import func, select

    from .tables import runs

    last = func.max(runs.c.started_at)
    return checked(reader, select(runs.c.lot, func.count().label("runs"), last.label("last"))
                   .where(runs.c.lot.is_not(None), sane_time()).group_by(runs.c.lot)
                   .order_by(last.desc()).limit(int(limit)))


def lot_counts(reader: StoreReader, lot: str) -> dict[str, list[CheckedRow]]:
    """A lot's grouped counts (index runs_lot): ``status`` (status, verdict, n), ``span`` (n, boards,
    t0, t1), ``nvm`` (nvm_status, n), ``stops`` (status_reason, n: the 20 commonest) and ``fails``
    (the FAIL runs' reasons)."""
    from sqlalchemy import func, select

    from .tables import runs

    of_lot = runs.c.lot == lot
    n = func.count().label("n")
    complete = runs.c.status == "complete"
    return {
        "status": checked(reader, select(runs.c.status, runs.c.verdict, n).where(of_lot)
                          .group_by(runs.c.status, runs.c.verdict)),
        "span": checked(reader, select(n, func.count(runs.c.device_serial.distinct()).label("boards"),
                                       func.min(runs.c.started_at).label("t0"),
                                       func.max(runs.c.started_at).label("t1")).where(of_lot, sane_time())),
        "nvm": checked(reader, select(runs.c.nvm_status, n).where(of_lot, complete).group_by(runs.c.nvm_status)),
        "stops": checked(reader, select(runs.c.status_reason, n)
                         .where(of_lot, runs.c.status.in_(("interrupted", "error")))
                         .group_by(runs.c.status_reason).order_by(func.count().desc()).limit(20)),
        "fails": checked(reader, select(runs.c.reasons).where(of_lot, complete, runs.c.verdict == "FAIL")),
    }


def lot_calibrations(reader: StoreReader, lot: str) -> list[CheckedRow]:
    """The lot's complete runs with a calibration, oldest first (id, started_at, station_id,
    calibration, limits, config_hash); unchecked: the id is the integer key, sane_time keeps a
    damaged time out, station_id is only shown (escaped), the JSON is read by bounded parsers."""
    from sqlalchemy import select

    from .tables import runs

    return unchecked(reader, select(runs.c.id, runs.c.started_at, runs.c.station_id, runs.c.calibration,
                                    runs.c.limits, runs.c.config_hash)
                     .where(runs.c.lot == lot, runs.c.status == "complete", runs.c.calibration.is_not(None),
                            sane_time()).order_by(runs.c.started_at, runs.c.id))

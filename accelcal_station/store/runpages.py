"""The runs a page or the API shows, a page at a time: SQLAlchemy Core statements over a
``StoreReader`` (reader.py) returning checked rows (rowcheck.CheckedRow).

The run page is a keyset on id (no OFFSET: one indexed range scan at any depth); the feed
reads runs from an id on; a few runs by id; the newest runs; serials like a text; the configs
of runs by hash.  Every id is any value a store holds (int64 on PostgreSQL, SQLite's signed
64-bit rowid): a bound outside that range matches nothing rather than overflowing the driver.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

from .liveness import live_status
from .rowcheck import SPECS, CheckedRow
from .schema import JSON_COLUMNS

if TYPE_CHECKING:
    from sqlalchemy import ColumnElement, Executable, Select

    from .reader import StoreReader

ID_MIN, ID_MAX = -(2**63), 2**63 - 1  # a run id: a signed 64-bit integer
SUMMARY_COLUMNS = ("id", "started_at", "finished_at", "status", "status_reason", "device_serial", "chip",
                   "station_id", "operator", "lot", "model", "verdict", "reasons", "nvm_status", "fit_summary",
                   "limits", "config_hash", "host", "pid", "heartbeat_at", "heartbeat_s")
# runs columns checked on every read as the store's own reads check them (rowcheck.py); the JSON
# columns stay text here (the web reads them through bounded parsers)
_SCALAR_COLUMNS = frozenset(SPECS["runs"]) - set(JSON_COLUMNS)
SANE_T_MAX = 253402300799  # 9999-12-31T23:59:59Z: a time a page can show
# the API's run filters: name -> (column, operator)
RUN_FILTERS = {"since": ("started_at", ">="), "until": ("started_at", "<"), "station": ("station_id", "="),
               "serial": ("device_serial", "="), "verdict": ("verdict", "="), "lot": ("lot", "="),
               "status": ("status", "=")}


def checked(reader: StoreReader, stmt: Executable) -> list[CheckedRow]:
    """Rows of one SELECT on runs; a damaged scalar (wrong type, time out of range) reads as None,
    named in ``damage``; a run whose station process is gone reads ``stale`` (liveness.py)."""
    out = []
    for raw in reader.rows(stmt):
        row = CheckedRow("runs", raw, _SCALAR_COLUMNS)
        if (stale := live_status(row.values)) is not None:
            row.set(status=stale[0], status_reason=stale[1])
        out.append(row)
    return out


def unchecked(reader: StoreReader, stmt: Executable) -> list[CheckedRow]:
    """Rows of a SELECT that itself keeps damaged scalars out (sane_time; the integer key)."""
    return [CheckedRow("runs", raw, frozenset()) for raw in reader.rows(stmt)]


def sane_time(col: ColumnElement[float] | None = None) -> ColumnElement[bool]:
    """A stored start a page can show (1970 to 9999): text, blobs, NaN and infinities fall outside
    on SQLite and PostgreSQL alike, so a damaged time is left out of aggregates."""
    from .tables import runs

    return (runs.c.started_at if col is None else col).between(0, SANE_T_MAX)


def in_id_range(v: int) -> bool:
    return ID_MIN <= v <= ID_MAX


def summary_select() -> Select[tuple[object, ...]]:
    from sqlalchemy import select

    from .tables import runs

    return select(*(runs.c[c] for c in SUMMARY_COLUMNS))


def _filters(filters: Mapping[str, object]) -> list[ColumnElement[bool]]:
    from .tables import runs

    where: list[ColumnElement[bool]] = []
    for k, v in filters.items():
        if isinstance(v, (float, int, str)):  # None: not filtered
            name, op = RUN_FILTERS[k]
            col = runs.c[name]
            where.append(col >= v if op == ">=" else col < v if op == "<" else col == v)
    return where


def run_page(reader: StoreReader, filters: Mapping[str, object], order: str, after_id: int | None,
             limit: int) -> list[CheckedRow]:
    """One page of runs by keyset on id: ``order`` "asc"/"desc", after ``after_id`` (exclusive)."""
    from .tables import runs

    where = _filters(filters)
    if after_id is not None:
        if not in_id_range(after_id):
            return []
        where.append(runs.c.id > after_id if order == "asc" else runs.c.id < after_id)
    way = runs.c.id.asc() if order == "asc" else runs.c.id.desc()
    return checked(reader, summary_select().where(*where).order_by(way).limit(int(limit)))


def run_count(reader: StoreReader, filters: Mapping[str, object]) -> object:
    """How many runs match ``filters`` (the driver's count: an int, a Decimal from PostgreSQL's sum)."""
    from sqlalchemy import func, select

    from .tables import runs

    return reader.rows(select(func.count().label("n")).select_from(runs).where(*_filters(filters)))[0]["n"]


def runs_by_id(reader: StoreReader, ids: Sequence[int]) -> list[CheckedRow]:
    """The runs of these ids (those it holds), in id order."""
    from .tables import runs

    ids = [int(v) for v in ids if in_id_range(int(v))]
    if not ids:
        return []
    return checked(reader, summary_select().where(runs.c.id.in_(ids)).order_by(runs.c.id))


def newest_runs(reader: StoreReader, limit: int) -> list[CheckedRow]:
    """The newest runs by id, running ones included."""
    from .tables import runs

    return checked(reader, summary_select().order_by(runs.c.id.desc()).limit(int(limit)))


def feed_rows(reader: StoreReader, low: int, limit: int) -> list[CheckedRow]:
    """(id, status, started_at) of the runs with id >= low, in id order: one statement, one snapshot
    (a ``low`` past every id a store holds: none)."""
    from sqlalchemy import select

    from .tables import runs

    if low > ID_MAX:
        return []
    low = max(low, ID_MIN)
    return checked(reader, select(runs.c.id, runs.c.status, runs.c.started_at).where(runs.c.id >= low)
                   .order_by(runs.c.id).limit(int(limit)))


def feed_head(reader: StoreReader) -> CheckedRow:
    """The lowest running run's id (``r``) and the newest id (``m``)."""
    from sqlalchemy import case, func, select

    from .tables import runs

    return checked(reader, select(func.min(case((runs.c.status == "running", runs.c.id))).label("r"),
                                  func.max(runs.c.id).label("m")))[0]


def serials_like(reader: StoreReader, prefix: str, limit: int) -> list[CheckedRow]:
    """The distinct serials starting with ``prefix`` (its LIKE wildcards removed), in order."""
    from sqlalchemy import select

    from .tables import runs

    pattern = prefix.replace("%", "").replace("_", "") + "%"
    return checked(reader, select(runs.c.device_serial).distinct().where(runs.c.device_serial.like(pattern))
                   .order_by(runs.c.device_serial).limit(int(limit)))


def newest_config_text(reader: StoreReader) -> CheckedRow | None:
    """The config text of the newest run that has one."""
    from sqlalchemy import select

    from .tables import runs

    rows = checked(reader, select(runs.c.config_text).where(runs.c.config_text.is_not(None))
                   .order_by(runs.c.id.desc()).limit(1))
    return rows[0] if rows else None


def configs_by_hash(reader: StoreReader, hashes: Sequence[str]) -> list[CheckedRow]:
    """(config_hash, ``t``: one config text) for each of these hashes the store holds."""
    from sqlalchemy import func, select

    from .tables import runs

    return checked(reader, select(runs.c.config_hash, func.min(runs.c.config_text).label("t"))
                   .where(runs.c.config_hash.in_(list(hashes))).group_by(runs.c.config_hash))

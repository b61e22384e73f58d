"""The results store's reading side: ``StoreReader`` opens a store read-only and reads runs.

A ``StoreReader`` cannot write: its SQLite file is opened ``mode=ro`` (SQLite itself refuses
every write, and no journal is created), its PostgreSQL session is read-only, and it has no
writing method.  It never creates, stamps or migrates a schema: a store at another schema
version, or one whose Alembic revision is missing (schemacheck.py names what its columns
are), is one StoreError naming the command that upgrades it.  ``Store`` (runs.py) is the
writer built on it.  The web's aggregate reads are query functions over a reader
(linequeries.py, runpages.py), SQLAlchemy Core statements on the tables of tables.py.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from ..session import Session
from . import exports, integrity, schema
from .database import Database, Row, describe_target, is_url
from .liveness import STALE, live_status
from .location import store_identity
from .records import (
    RunDocument,
    RunNotFound,
    RunRecord,
    RunRow,
    RunSummary,
    StoreError,
    StoreUnreachable,
    build_record,
    run_row,
)
from .rowcheck import DamagedRow

if TYPE_CHECKING:
    from sqlalchemy import Executable
    from sqlalchemy.exc import SQLAlchemyError


def sqlerror() -> type[SQLAlchemyError]:
    """SQLAlchemy's error class, imported when a store is used (not when the CLI starts)."""
    from sqlalchemy.exc import SQLAlchemyError
    return SQLAlchemyError


def store_error(e: BaseException, message: str, server: bool) -> StoreError:
    """``message`` as a StoreError; StoreUnreachable when the database server (``server``: not
    an SQLite file) could not be reached or the connection to it was lost."""
    from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError, PendingRollbackError

    lost = isinstance(e, (OperationalError, InterfaceError, PendingRollbackError)) or (
        isinstance(e, DBAPIError) and e.connection_invalidated)
    return StoreUnreachable(message) if lost and server else StoreError(message)


def sql_message(e: BaseException) -> str:
    """The driver's own first line of a database error (SQLAlchemy wraps it in a long text)."""
    orig = getattr(e, "orig", None)
    return (str(orig if orig is not None else e).strip().splitlines() or [type(e).__name__])[0]


class StoreReader:
    """The results store at ``path`` (a file path, ``sqlite:///PATH`` or ``postgresql://...``),
    opened read-only: never created, stamped, migrated or written.  Use as a context manager;
    one per thread.  ``path`` is the file (SQLite) or the URL without its password."""

    _beats = True  # the schema has the heartbeat columns
    notice: str | None = None  # one line about the store read (a missing Alembic revision), for the caller

    def __init__(self, path: str | Path, timeout_s: float = 10.0):
        self._open(path, timeout_s, create=False, read_only=True)
        self._settle(create=False, upgrade=False)

    def _open(self, path: str | Path, timeout_s: float, create: bool, read_only: bool) -> None:
        SQLError = sqlerror()
        name = describe_target(path)
        try:
            self._db = Database(str(path) if is_url(path) else Path(path), timeout_s, create, read_only)
        except FileNotFoundError:
            raise StoreError(f"{name}: no results store there") from None
        except ValueError as e:
            raise StoreError(str(e)) from None
        except (OSError, SQLError) as e:
            raise store_error(e, f"{name}: cannot open results store ({sql_message(e)})",
                              is_url(path) and not str(path).startswith("sqlite")) from None
        db_path = self._db.path  # set for SQLite only
        self.path: Path | str = db_path if db_path is not None else self._db.name

    def _settle(self, create: bool, upgrade: bool) -> None:
        """Check (a reader) or bring (the writer) the schema to schema.SCHEMA_VERSION; closes on failure."""
        try:
            self._schema(create, upgrade)
        except sqlerror() as e:
            self._db.close()
            raise store_error(e, f"{self.path}: not a usable results store ({sql_message(e)})", self._server) from None
        except BaseException:
            self._db.close()
            raise

    def _schema(self, create: bool, upgrade: bool) -> None:
        """A reader's schema check: refuse a store at another version or one without its revision
        whose columns are another schema's (schemacheck.py); nothing is written."""
        from . import schemacheck  # SQLAlchemy, imported when a store is opened

        got = schemacheck.inspect_store(self._db)
        target = schema.SCHEMA_VERSION  # read at each open, so a test can stop at an older version
        self._beats = target >= 5  # runs.heartbeat_at/heartbeat_s exist from schema 5
        if got.version == 0:
            raise StoreError(f"{self.path}: not an accelcal results store (no schema); nothing was written")
        if got.version > target:
            raise StoreError(f"{self.path}: results store schema version {got.version} is newer than this "
                             f"station's {target}; upgrade accelcal-station")
        line = schemacheck.unstamped_line(str(self.path), got, target)
        if line is not None and got.columns_version != target:
            raise StoreError(line)
        self.notice = line
        if got.version != target:
            raise StoreError(f"{self.path}: results store schema version {got.version}, this station reads "
                             f"{target}; `accelcal report migrate --db {self.path}` upgrades it (nothing was written)")

    def __enter__(self) -> StoreReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._db.close()

    @property
    def identity(self) -> str:
        """What makes two store objects the same store: the resolved file, or the URL."""
        return store_identity(self.path)

    @property
    def dialect(self) -> str:
        return self._db.dialect

    @property
    def _server(self) -> bool:
        return self._db.dialect != "sqlite"

    def rows(self, stmt: Executable) -> list[Row]:
        """The rows of one Core SELECT (inside the open snapshot, else a read transaction of its own);
        a database error is a StoreError naming the store."""
        try:
            return self._db.rows(stmt)
        except sqlerror() as e:
            raise store_error(e, f"{self.path}: cannot read runs ({sql_message(e)})", self._server) from None

    @contextmanager
    def _snapshot(self) -> Iterator[None]:
        """One read transaction, so queries spanning tables see one committed state."""
        if self._db.in_transaction:
            yield
            return
        SQLError = sqlerror()
        try:
            self._db.begin(write=False)
            yield
        except SQLError as e:
            raise store_error(e, f"{self.path}: cannot read runs ({sql_message(e)})", self._server) from None
        finally:
            if self._db.in_transaction:
                try:
                    self._db.commit()
                except SQLError as e:  # a damaged page can surface only here
                    raise store_error(e, f"{self.path}: cannot read runs ({sql_message(e)})", self._server) from None

    @property
    def schema_version(self) -> int:
        from . import schemacheck

        with self._snapshot():
            return schemacheck.current_version(self._db)

    # -- queries ------------------------------------------------------------------------
    def _runs(self, filters: Mapping[str, object], limit: int | None = None) -> list[tuple[RunRow, list[DamagedRow]]]:
        """The matching ``runs`` rows, each checked (rowcheck.check_row) with what is damaged in it.
        Status ``running`` or ``stale`` (both stored as running) is told apart as each row is read."""
        from sqlalchemy import select

        from . import filters as filters_sql
        from .tables import runs

        wanted = filters.get("status")
        live = wanted in ("running", STALE)
        if live:
            filters = {**filters, "status": "running"}
        stmt = select(runs).where(*filters_sql.where(filters)).order_by(runs.c.started_at, runs.c.id)
        if limit is not None:
            stmt = stmt.limit(int(limit))
        out = [run_row(r) for r in self.rows(stmt)]
        for r, _ in out:  # running, its process gone: stale
            if (stale := live_status(r)) is not None:
                r["status"], r["status_reason"] = stale
        return [x for x in out if x[0]["status"] == wanted] if live else out

    def list_runs(self, limit: int | None = None, **filters: object) -> list[RunSummary]:
        """Run summaries (no poses) matching filters: device, station, lot, operator, since,
        until, verdict, status, model (a value or a list of values), run_ids.  A run whose row
        is damaged has ``damaged`` (its columns) and ``damage`` (typed ``damaged_row`` reasons)."""
        from sqlalchemy import func, select

        from .records import run_summary
        from .tables import poses

        with self._snapshot():
            per_run = self.rows(select(poses.c.run_id, func.count().label("n")).group_by(poses.c.run_id))
            counts: dict[object, int] = {r["run_id"]: r["n"] for r in per_run}  # as stored (a damaged id too)
            rows = self._runs(filters, limit)
        return [run_summary(r, damage, counts.get(r["id"], 0)) for r, damage in rows]

    def _record(self, r: RunRow, damage: list[DamagedRow]) -> RunRecord:
        from sqlalchemy import select

        from .tables import events, poses

        rid = r["id"]
        pose_rows = self.rows(select(poses).where(poses.c.run_id == rid).order_by(poses.c.idx))
        event_rows = self.rows(select(events).where(events.c.run_id == rid).order_by(events.c.id))
        return build_record(r, damage, pose_rows, event_rows)

    def get_run(self, run_id: int) -> RunRecord:
        with self._snapshot():
            rows = self._runs({"run_ids": [run_id]})
            if not rows:
                raise RunNotFound(f"{self.path}: no run {run_id}")
            return self._record(*rows[0])

    def runs(self, **filters: object) -> list[RunRecord]:
        """Full records (poses, events) of the matching runs."""
        with self._snapshot():
            return [self._record(r, damage) for r, damage in self._runs(filters)]

    def sessions_for_batch(self, skipped: list[tuple[str, str]] | None = None, **filters: object) -> list[Session]:
        """Sessions of complete runs with poses (for batch recalibration of a lot).

        A matching run with a damaged value is never silently left out: it is appended to
        ``skipped`` as ("run ID", "damaged_row: ...") whatever its status reads (a damaged status
        included), so the caller can name and count it; so is a complete run whose pose rows
        cannot all be read ("poses_unreadable: ...", RunRecord.poses_unread).
        """
        status = filters.pop("status", "complete")
        out: list[Session] = []
        for rec in self.runs(**filters):
            if rec.damage:
                if skipped is not None:
                    skipped.append((f"run {rec.id if rec.id is not None else '?'}", "damaged_row: "
                                    + "; ".join(str(d) for d in rec.damage[:3])
                                    + (f" (+{len(rec.damage) - 3} more)" if len(rec.damage) > 3 else "")))
            elif rec.status == status and (why := rec.poses_unread()) is not None:
                if skipped is not None:  # a complete run whose poses cannot be read: named, never left out
                    skipped.append((f"run {rec.id}", why))
            elif rec.poses and rec.status == status:
                out.append(rec.session())
        return out

    def check(self) -> list[DamagedRow]:
        """Every damaged value of every row (runs, poses, events; integrity.check_rows); nothing is written."""
        from .tables import events, poses, runs

        return integrity.check_rows(self._db, (runs, poses, events))

    def integrity(self) -> list[str]:
        """What SQLite's integrity check finds wrong in the file (integrity.file_problems); [] on PostgreSQL."""
        return [] if self._server else integrity.file_problems(self._db)

    # -- exports and summaries ----------------------------------------------------------
    def export_json(self, path: str | Path | None = None, **filters: object) -> list[RunDocument]:
        """Every matching run in full; written atomically to ``path`` when given."""
        data = [rec.to_dict() for rec in self.runs(**filters)]
        if path is not None:
            exports.write_export(path, exports.runs_json(data))
        return data

    def export_csv(self, path: str | Path | None = None, kind: str = "runs", **filters: object) -> str:
        """CSV of runs (one row per run, calibration flattened) or poses (one row per pose).

        Returns the text; written atomically to ``path`` when given.
        """
        table = exports.csv_table(kind)
        text = table(self.runs(**filters))
        if path is not None:
            exports.write_export(path, text)
        return text

    def lot_summary(self, **filters: object) -> exports.LotSummary:
        """Counts, pass rate, failure reasons and parameter distributions of the matching runs
        (exports.summarize)."""
        with self._snapshot():
            return exports.summarize(self._runs(filters))


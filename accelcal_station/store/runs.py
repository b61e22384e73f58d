"""The results store's ``Store``: every station run in one database, an SQLite file (the
default) or a line's shared PostgreSQL server (``postgresql://...``; database.py).

A run is committed as ``running`` when it starts, so a crash leaves a record; its
poses, calibration, verdict and NVM outcome are then written in ONE transaction by
``finish_run`` (or ``interrupt_run``), never half.  ``mark_stale_interrupted`` turns
runs whose station process died into ``interrupted``.

Journal mode is SQLite's default rollback journal, not WAL: the store stays one
file (WAL keeps -wal/-shm files beside it and does not work on network shares),
and a station commits a few times per board, so WAL's writer/reader overlap buys
nothing; readers wait out a commit through the busy timeout.  synchronous stays
FULL (the default): a committed run survives power loss.  Foreign keys are on.

Opening a store upgrades its schema (schema.py) under one transaction, in one logged line;
``StoreReader`` (reader.py) is the reading side, which never writes.
"""
from __future__ import annotations

import logging
import os
import socket
import time as _time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Unpack

from ..acceptance.reasons import Reason
from ..errors import DataError
from ..session import Session
from . import schema
from .database import Database
from .heartbeat import HEARTBEAT_S, Heartbeat
from .liveness import stale_reason
from .reader import StoreReader, sql_message, sqlerror, store_error
from .records import RunRecord, StoreError, opt, to_json
from .run_args import Outcome, RunResult, RunResultFields, RunStart, RunStartFields, one_of

if TYPE_CHECKING:
    from sqlalchemy import insert, select, update

    from . import migrate, replay
    from .tables import events, poses, runs

log = logging.getLogger(__name__)


def _load_sql() -> None:
    """SQLAlchemy, the tables, the migrations and replay, imported when a store is first opened,
    not when the CLI starts (importing SQLAlchemy takes about 0.4 s)."""
    global insert, select, update, migrate, replay, events, poses, runs
    from sqlalchemy import insert, select, update

    from . import migrate, replay
    from .tables import events, poses, runs


def _outcome(o: Outcome | None) -> Mapping[str, object] | None:
    return o if o is None or isinstance(o, Mapping) else o.to_dict()


class Store(StoreReader):
    """The results store at ``path`` for writing (and reading: StoreReader): a file path or
    ``sqlite:///PATH`` (an SQLite file, created with its parent folder when missing unless
    ``create`` is False) or ``postgresql://...`` (a server database; the schema is created in it
    when missing, and upgraded when ``upgrade``).  Use as a context manager; one Store per thread.
    ``path`` is the file (SQLite) or the URL without its password (PostgreSQL), as messages name it.
    """

    heartbeat_s: float = HEARTBEAT_S  # seconds between the running runs' heartbeats (store/heartbeat.py)
    _heart: Heartbeat | None = None  # started by the first start_run

    def __init__(self, path: str | Path, timeout_s: float = 10.0, create: bool = True, upgrade: bool = True,
                 read_only: bool = False, heartbeat_s: float = HEARTBEAT_S):
        _load_sql()
        self.heartbeat_s = float(heartbeat_s)
        self._open(path, timeout_s, create and not read_only, read_only)
        self._settle(create and not read_only, upgrade and not read_only)

    def __enter__(self) -> Store:
        return self

    def close(self) -> None:
        if self._heart is not None:
            self._heart.close()
        self._db.close()

    @contextmanager
    def _tx(self, what: str) -> Iterator[Database]:
        """One write transaction (IMMEDIATE on SQLite): all of it is committed or none of it."""
        SQLError = sqlerror()
        try:
            self._db.begin()
        except SQLError as e:
            raise store_error(e, f"{self.path}: cannot {what} ({sql_message(e)})", self._server) from None
        try:
            yield self._db
            self._db.commit()
        except BaseException as e:
            if self._db.in_transaction:
                self._db.rollback()
            if isinstance(e, SQLError):
                why = f"{self.path}: cannot {what} ({sql_message(e)}); that write was rolled back"
                raise store_error(e, why, self._server) from None
            raise

    def _schema(self, create: bool, upgrade: bool) -> None:
        """Bring the schema to schema.SCHEMA_VERSION by Alembic (migrate.py), in one transaction, and
        say so in one logged line; ``upgrade`` False: as a reader (write nothing, refuse another version)."""
        if not upgrade:
            super()._schema(create, upgrade)
            return
        from . import schemacheck  # SQLAlchemy, imported when a store is opened

        got = schemacheck.inspect_store(self._db)
        target = schema.SCHEMA_VERSION  # read at each open, so a test can stop at an older version
        self._beats = target >= 5  # runs.heartbeat_at/heartbeat_s exist from schema 5
        if got.version == 0 and not create:  # a reader never writes a schema into a file it only reads
            raise StoreError(f"{self.path}: not an accelcal results store (no schema); nothing was written")
        if got.version > target:
            raise StoreError(f"{self.path}: results store schema version {got.version} is newer than this "
                             f"station's {target}; upgrade accelcal-station")
        if got.version == target and got.stamped:
            return
        with self._tx("upgrade the schema") as db:
            migrate.upgrade(db, str(self.path), target)
        if got.version > 0:  # an existing store changed: said, never silent
            what = (f"schema {got.version} upgraded to {target}" if got.version != target else
                    f"schema revision {migrate.revision(target)} recorded (its columns are schema {target}'s)")
            log.warning("%s: %s", self.path, what)
            self.notice = f"{self.path}: {what}"

    # -- recording ----------------------------------------------------------------------
    def start_run(self, run: RunStart | None = None, /, **fields: Unpack[RunStartFields]) -> int:
        """Commit a ``running`` row now (a crash leaves it recorded) and return its id: ``run``, or its
        fields as keywords (RunStart)."""
        r = one_of(run, fields, RunStart)
        now = _time.time()
        with self._tx("start a run") as db:
            cur = db.execute(insert(runs).values(
                started_at=now if r.started_at is None else float(r.started_at), status="running",
                device_serial=r.device_serial, chip=r.chip, station_id=r.station_id, operator=r.operator,
                lot=r.lot, config_hash=r.config_hash, config_text=r.config_text, model=opt(r.model, str),
                units=r.units, counts_per_g=opt(r.counts_per_g), gravity_mps2=opt(r.gravity_mps2),
                host=socket.gethostname(), pid=os.getpid(), panel_id=r.panel_id,
                **({"heartbeat_at": now, "heartbeat_s": self.heartbeat_s} if self._beats else {})))
            key = cur.inserted_primary_key
            assert key is not None  # an INSERT of one row
        if self._beats:
            if self._heart is None:
                self._heart = Heartbeat(self._db.target, self.heartbeat_s)
            self._heart.add(int(key[0]))
        log.info("run %d started: board %s, station %s, lot %s", key[0], r.device_serial, r.station_id, r.lot)
        return int(key[0])

    def _running(self, db: Database, run_id: int) -> None:
        got = db.rows(select(runs.c.status).where(runs.c.id == run_id))
        if not got:
            raise StoreError(f"{self.path}: no run {run_id}")
        if got[0]["status"] != "running":
            raise StoreError(f"{self.path}: run {run_id} is already {got[0]['status']}; a run is closed once")

    def _insert_poses(self, db: Database, run_id: int, session: Session, retries: Sequence[int] | None) -> None:
        if retries is not None and len(retries) != len(session):
            raise DataError(f"retries has {len(retries)} entries for {len(session)} poses")
        rows: list[dict[str, object]] = []  # one insert's rows: column -> value
        for i, p in enumerate(session.poses):
            ref = [None] * 3 if p.reference_g is None else [float(v) for v in p.reference_g]
            std = [None] * 3 if p.std is None else [float(v) for v in p.std]
            values = (i, p.name, opt(p.pitch_deg), opt(p.roll_deg), *ref, *map(float, p.mean), *std,
                      opt(p.n, int), int(p.dropped), opt(p.temp_c), opt(p.t_start), opt(p.t_end),
                      0 if retries is None else int(retries[i]))
            rows.append({"run_id": run_id, **dict(zip(schema.POSE_COLS, values, strict=True))})
        if rows:
            db.execute(insert(poses), rows)
        db.execute(update(runs).where(runs.c.id == run_id).values(
            units=session.units, counts_per_g=opt(session.counts_per_g), gravity_mps2=opt(session.gravity_mps2)))

    def finish_run(self, run_id: int, result: RunResult | None = None, /, **fields: Unpack[RunResultFields]) -> None:
        """Record poses, calibration, verdict and NVM outcome of a run as ``complete``, atomically:
        ``result``, or its fields as keywords (RunResult)."""
        r = one_of(result, fields, RunResult)
        if r.verdict is not None and r.verdict not in schema.VERDICTS:
            raise DataError(f"verdict {r.verdict!r}; allowed: PASS, FAIL")
        outcome = _outcome(r.nvm_outcome)
        nvm_status = "none" if outcome is None else ("written" if outcome.get("ok") else "failed")
        with self._tx(f"record run {run_id}") as db:
            self._running(db, run_id)
            self._insert_poses(db, run_id, r.session, r.retries)
            cal = None if r.calibration is None else r.calibration.to_dict()
            try:
                texts = [to_json([Reason.from_dict(x).to_dict() for x in r.reasons]), to_json(outcome),
                         to_json(cal), to_json(r.fit_summary),
                         to_json(None if r.limits is None else {str(k): float(v) for k, v in r.limits.items()}),
                         to_json(None if r.site is None else dict(r.site)),
                         to_json(None if r.uncertainty is None else dict(r.uncertainty))]
            except (TypeError, ValueError) as e:
                raise DataError(f"run {run_id}: result is not JSON-serialisable ({e})") from None
            model = opt(r.model or (r.calibration.model if r.calibration else None), str)
            db.execute(update(runs).where(runs.c.id == run_id).values(
                status="complete", finished_at=_time.time() if r.finished_at is None else float(r.finished_at),
                verdict=r.verdict, reasons=texts[0], nvm_status=nvm_status, nvm_outcome=texts[1],
                calibration=texts[2], fit_summary=texts[3], **({} if texts[4] is None else {"limits": texts[4]}),
                **{k: v for k, v in (("site", texts[5]), ("uncertainty", texts[6])) if v is not None},
                **({} if model is None else {"model": model})))
        self._stop_beating(run_id)
        log.info("run %d complete: %s, NVM %s", run_id, r.verdict or "no verdict", nvm_status)

    def interrupt_run(self, run_id: int, reason: str, *, session: Session | None = None,
                      status: str = "interrupted", retries: Sequence[int] | None = None,
                      nvm_outcome: Outcome | None = None) -> None:
        """Close a run as ``interrupted`` (or ``error``) with the poses captured so far, atomically."""
        if status not in ("interrupted", "error"):
            raise DataError(f"status {status!r}; allowed: interrupted, error")
        outcome = _outcome(nvm_outcome)
        # no outcome given: keep what record_burn wrote (a burn cut short stays 'burning')
        nvm = {} if outcome is None else {"nvm_status": "written" if outcome.get("ok") else "failed",
                                          "nvm_outcome": to_json(outcome)}
        with self._tx(f"record run {run_id}") as db:
            self._running(db, run_id)
            if session is not None:
                self._insert_poses(db, run_id, session, retries)
            db.execute(update(runs).where(runs.c.id == run_id).values(
                status=status, status_reason=str(reason), finished_at=_time.time(), **nvm))
        self._stop_beating(run_id)
        log.warning("run %d %s: %s", run_id, status, reason)

    def _stop_beating(self, run_id: int) -> None:
        if self._heart is not None:
            self._heart.discard(run_id)

    def record_burn(self, run_id: int, kind: str, outcome: Mapping[str, object], t: float | None = None) -> None:
        """A burn as it happens, committed at once: ``nvm_burning`` (slot, generation, blob CRC)
        sets the run's nvm_status to ``burning`` before the first byte; ``nvm_burned`` /
        ``nvm_burn_failed`` to ``burned`` / ``failed`` (finish_run then records the outcome)."""
        status = {"nvm_burning": "burning", "nvm_burned": "burned", "nvm_burn_failed": "failed"}[kind]
        crc = outcome.get("crc32")
        with self._tx(f"record the burn of run {run_id}") as db:
            db.execute(insert(events).values(
                run_id=run_id, t=_time.time() if t is None else float(t), kind=kind,
                message=f"slot {outcome.get('slot')}, generation {outcome.get('generation')}, CRC-32 "
                        f"{crc if crc is None else f'0x{crc:08x}'}", data=to_json(outcome)))
            db.execute(update(runs).where(runs.c.id == run_id).values(nvm_status=status,
                                                                      nvm_outcome=to_json(outcome)))

    def log_event(self, run_id: int, kind: str, message: str = "", data: object = None, t: float | None = None) -> None:
        """Append an event (a rejected capture, an operator prompt, ...), committed at once."""
        with self._tx(f"log an event of run {run_id}") as db:
            db.execute(insert(events).values(run_id=run_id, t=_time.time() if t is None else float(t), kind=kind,
                                             message=message, data=to_json(data)))

    def mark_stale_interrupted(self, max_age_s: float | None = None) -> list[int]:
        """Mark ``running`` runs whose station process is gone as interrupted; returns their ids.

        A run is stale when its station process on this host is gone (liveness.stale_reason: the
        same rule every read applies), or (any host) when ``max_age_s`` is given and it started
        longer ago.
        """
        now = _time.time()
        stale: list[int] = []
        with self._tx("mark stale runs") as db:
            for r in db.rows(select(runs.c.id, runs.c.status, runs.c.host, runs.c.pid, runs.c.started_at,
                                    runs.c.heartbeat_at, runs.c.heartbeat_s).where(runs.c.status == "running")):
                old = max_age_s is not None and isinstance(r["started_at"], (int, float)) \
                    and now - r["started_at"] > max_age_s
                if old or stale_reason(r) is not None:
                    stale.append(r["id"])
            if stale:
                db.execute(update(runs).where(runs.c.id.in_(stale)).values(
                    status="interrupted", finished_at=now, status_reason="station stopped during the run"))
        return stale

    def replay_run(self, rec: RunRecord, server_run_id: int | None = None, note: str = "") -> tuple[int, bool]:
        """Write a run recorded in another store (the outbox) into this one, once (replay.py):
        (its id here, whether anything was written)."""
        with self._tx(f"replay run {rec.id}") as db:
            return replay.replay_run(db, rec, server_run_id, note)

"""The results store: every station run in one database, an SQLite file (the default) or a
line's shared PostgreSQL server (``postgresql://...``; storedb.py).

A run is committed as ``running`` when it starts, so a crash leaves a record; its
poses, calibration, verdict and NVM outcome are then written in ONE transaction by
``finish_run`` (or ``interrupt_run``), never half.  ``mark_stale_interrupted`` turns
runs whose station process died into ``interrupted``.

Journal mode is SQLite's default rollback journal, not WAL: the store stays one
file (WAL keeps -wal/-shm files beside it and does not work on network shares),
and a station commits a few times per board, so WAL's writer/reader overlap buys
nothing; readers wait out a commit through the busy timeout.  synchronous stays
FULL (the default): a committed run survives power loss.  Foreign keys are on.

Schema versions live in ``PRAGMA user_version``; ``MIGRATIONS[i]`` upgrades
version i to i + 1.  Times are unix seconds (REAL); exports also give ISO 8601 UTC.
Failure reasons are typed (reasons.Reason): the ``reasons`` column holds a JSON list of
``{"code", "message"}`` objects and summaries group by the code.  Rows written before
schema 3 held bare text; migration 3 gives each its code once (_typed_reasons).
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import socket
import time as _time
from collections import Counter
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .calibration import Calibration
from .config import atomic_write_text, check_keys
from .errors import ConfigError, DataError
from .reasons import Reason, codes
from .session import PoseRecord, Session
from .storedb import Database, Row, describe_target, is_url

STATUSES = ("running", "complete", "interrupted", "error")
VERDICTS = ("PASS", "FAIL")
AXES = "xyz"


def _legacy_code(text: str, typed: list | None, i: int) -> str:
    """The code of a reason stored as bare text before schema 3: the station's own
    ``reason_codes`` when it kept them, else the text's first word (acceptance.py starts
    each limit reason with its key).  Used by migration 3 only, once per row."""
    if typed is not None and i < len(typed) and isinstance(typed[i], str) and typed[i]:
        return typed[i]
    words = text.strip().split(None, 1)
    return words[0].split(":", 1)[0] if words else ""


def _typed_reasons(db) -> None:
    """Migration 3: every stored reason becomes ``{"code", "message"}``; damaged rows stay as they are."""
    rows = db.execute("SELECT id, reasons, fit_summary FROM runs WHERE reasons IS NOT NULL").fetchall()
    updates = []
    for r in rows:
        old, fit = _load_or(r["reasons"], None), _load_or(r["fit_summary"], None)
        if not isinstance(old, list):
            continue
        typed = fit.get("reason_codes") if isinstance(fit, dict) and len(fit.get("reason_codes") or []) == len(old) \
            else None
        new = [x if isinstance(x, dict) else {"code": _legacy_code(str(x), typed, i), "message": str(x)}
               for i, x in enumerate(old)]
        updates.append((json.dumps(new), r["id"]))
    db.executemany("UPDATE runs SET reasons = ? WHERE id = ?", updates)


# statements are split at ';' (keep it out of comments and strings); a callable gets the connection
MIGRATIONS: list = [
    """
    CREATE TABLE runs (
        id INTEGER PRIMARY KEY,
        started_at REAL NOT NULL,
        finished_at REAL,
        status TEXT NOT NULL DEFAULT 'running'
            CHECK (status IN ('running', 'complete', 'interrupted', 'error')),
        status_reason TEXT,
        device_serial TEXT,
        chip TEXT,
        station_id TEXT,
        operator TEXT,
        lot TEXT,
        config_hash TEXT,
        config_text TEXT,
        model TEXT,
        units TEXT,
        counts_per_g REAL,
        gravity_mps2 REAL,
        verdict TEXT CHECK (verdict IN ('PASS', 'FAIL')),
        reasons TEXT,           -- JSON list of {"code", "message"} (text before schema 3)
        nvm_status TEXT,        -- written / failed / none
        nvm_outcome TEXT,       -- JSON (writer.BurnOutcome.to_dict)
        calibration TEXT,       -- JSON (Calibration.to_dict)
        fit_summary TEXT,       -- JSON (FitResult.to_json_dict or similar)
        host TEXT,
        pid INTEGER
    );
    CREATE INDEX runs_device ON runs (device_serial, started_at);
    CREATE INDEX runs_lot ON runs (lot, started_at);
    CREATE INDEX runs_started ON runs (started_at);
    CREATE TABLE poses (
        run_id INTEGER NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
        idx INTEGER NOT NULL,
        name TEXT NOT NULL,
        pitch_deg REAL, roll_deg REAL,
        ref_x REAL, ref_y REAL, ref_z REAL,          -- expected output, g
        mean_x REAL NOT NULL, mean_y REAL NOT NULL, mean_z REAL NOT NULL,  -- session units
        std_x REAL, std_y REAL, std_z REAL,          -- session units
        n INTEGER,
        dropped INTEGER NOT NULL DEFAULT 0,
        temp_c REAL,
        t_start REAL, t_end REAL,
        retries INTEGER NOT NULL DEFAULT 0,          -- rejected captures before this one
        PRIMARY KEY (run_id, idx)
    );
    CREATE TABLE events (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
        t REAL NOT NULL,
        kind TEXT NOT NULL,
        message TEXT,
        data TEXT                                    -- JSON
    );
    CREATE INDEX events_run ON events (run_id);
    """,
    """
    ALTER TABLE runs ADD COLUMN panel_id TEXT;   -- the boards calibrated together on one jig (panel.py)
    CREATE INDEX runs_panel ON runs (panel_id);
    """,
    _typed_reasons,
]
SCHEMA_VERSION = len(MIGRATIONS)

_POSE_COLS = ("idx", "name", "pitch_deg", "roll_deg", "ref_x", "ref_y", "ref_z", "mean_x", "mean_y", "mean_z",
              "std_x", "std_y", "std_z", "n", "dropped", "temp_c", "t_start", "t_end", "retries")
_RUN_CSV_COLS = ("id", "started_at", "finished_at", "status", "status_reason", "device_serial", "chip",
                 "station_id", "operator", "lot", "config_hash", "model", "units", "counts_per_g", "verdict",
                 "reasons", "nvm_status", "pose_count")
_FIT_SCALARS = ("residual_rms_g", "residual_max_g", "crossval_rms_g", "condition_number")
PARAM_NAMES = ([f"W{i}{j}" for i in range(3) for j in range(3)] + [f"V{i}" for i in range(3)]
               + [f"Gamma{i}" for i in range(3)])


DEFAULT_STORE = "accelcal-runs.sqlite"


def store_path(config: dict, base_dir: str | Path = ".") -> Path | str:
    """The store of a station config: ``store: {path: FILE or URL}`` (default DEFAULT_STORE),
    a relative path taken from ``base_dir`` (the config file's folder); a URL
    (``postgresql://...``, ``sqlite:///...``) is returned as it is."""
    section = check_keys(config.get("store"), ("path",), "store")
    p = section.get("path", DEFAULT_STORE)
    if not isinstance(p, str) or not p.strip():
        raise ConfigError(f"store.path: {p!r}; allowed: a file path, sqlite:///PATH or postgresql://...")
    return store_target(p, base_dir)


def store_target(p: str | Path, base_dir: str | Path = ".") -> Path | str:
    """A store given by the user: a URL as it is, a path taken from ``base_dir``."""
    if is_url(p):
        return str(p)
    return Path(base_dir) / Path(p).expanduser()


def _sqlerror():
    from sqlalchemy.exc import SQLAlchemyError
    return SQLAlchemyError


def _msg(e: BaseException) -> str:
    """The driver's own first line of a database error (SQLAlchemy wraps it in a long text)."""
    orig = getattr(e, "orig", None)
    return (str(orig if orig is not None else e).strip().splitlines() or [type(e).__name__])[0]


class StoreError(DataError):
    """The results store cannot be opened, read or written."""


def iso(t: float | None) -> str | None:
    """Unix seconds as ISO 8601 UTC."""
    return None if t is None else datetime.fromtimestamp(t, timezone.utc).isoformat(timespec="milliseconds")


def timestamp(value, what: str = "time") -> float | None:
    """Unix seconds from unix seconds, a datetime or an ISO 8601 string (naive = local time)."""
    if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return None if value is None else float(value)
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value)
        except ValueError:
            raise DataError(f"{what} {value!r}: not a date; allowed ISO 8601 like 2024-05-01 or "
                            "2024-05-01T13:30") from None
    if isinstance(value, datetime):
        return value.timestamp()
    raise DataError(f"{what} {value!r}: not a time")


def stored_reasons(text) -> list[Reason]:
    """The typed reasons of a ``reasons`` column ([] when empty or damaged)."""
    value = _load_or(text, [])
    return [Reason.from_dict(x) for x in value] if isinstance(value, list) else []


def param_vector(cal: dict) -> np.ndarray:
    """W (row major), V, Gamma of a calibration dict as 15 numbers, PARAM_NAMES order."""
    return np.concatenate([np.asarray(cal["W"], float).ravel(), np.asarray(cal["V"], float),
                           np.asarray(cal.get("Gamma", [0, 0, 0]), float)])


def _opt(x, cast=float):
    return None if x is None else cast(x)


def _json(x) -> str | None:
    return None if x is None else json.dumps(x, allow_nan=False)


def _stats(values: np.ndarray) -> dict:
    """mean, sample std (ddof=1; 0 for one value), min, max and n over axis 0."""
    v = np.asarray(values, dtype=float)
    return {"n": int(len(v)), "mean": v.mean(axis=0).tolist(),
            "std": (v.std(axis=0, ddof=1) if len(v) > 1 else np.zeros(v.shape[1:])).tolist(),
            "min": v.min(axis=0).tolist(), "max": v.max(axis=0).tolist()}


@dataclass
class RunRecord:
    """One stored run; ``session()`` rebuilds the captured Session."""

    id: int
    started_at: float
    finished_at: float | None
    status: str
    status_reason: str | None
    device_serial: str | None
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    config_hash: str | None
    config_text: str | None
    model: str | None
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    verdict: str | None
    reasons: list[Reason]
    nvm_status: str | None
    nvm_outcome: dict | None
    calibration: dict | None
    fit_summary: dict | None
    host: str | None
    pid: int | None
    panel_id: str | None = None  # the boards calibrated together on one jig
    poses: list[PoseRecord] = field(default_factory=list)
    retries: list[int] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    damaged: list[str] = field(default_factory=list)  # JSON columns that did not parse (shown, not fatal)

    def session(self) -> Session:
        return Session(list(self.poses), self.units or "counts", self.counts_per_g, self.gravity_mps2,
                       self.device_serial, {"run_id": self.id, "station_id": self.station_id, "lot": self.lot,
                                            "chip": self.chip, "started_at": iso(self.started_at)})

    def calibration_object(self) -> Calibration | None:
        return None if self.calibration is None else Calibration.from_dict(self.calibration, f"run {self.id}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["started_at_iso"], d["finished_at_iso"] = iso(self.started_at), iso(self.finished_at)
        d["poses"] = [_pose_dict(p, r) for p, r in zip(self.poses, self.retries)]
        d["reasons"], d["reason_codes"] = [str(r) for r in self.reasons], codes(self.reasons)
        return d


def _pose_dict(p: PoseRecord, retries: int) -> dict:
    arr = lambda a: None if a is None else np.asarray(a).tolist()  # noqa: E731
    return {"name": p.name, "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg, "reference_g": arr(p.reference_g),
            "mean": arr(p.mean), "std": arr(p.std), "n": p.n, "dropped": p.dropped, "temp_c": p.temp_c,
            "t_start": p.t_start, "t_end": p.t_end, "retries": retries}


class Store:
    """The results store at ``path``: a file path or ``sqlite:///PATH`` (an SQLite file, created
    with its parent folder when missing unless ``create`` is False) or ``postgresql://...``
    (a server database; the schema is created in it when missing).  Use as a context
    manager; one Store per thread.  ``path`` is the file (SQLite) or the URL without its
    password (PostgreSQL), as messages name it.
    """

    def __init__(self, path: str | Path, timeout_s: float = 10.0, create: bool = True):
        SQLError = _sqlerror()
        name = describe_target(path)
        try:
            self._db = Database(str(path) if is_url(path) else Path(path), timeout_s, create)
        except FileNotFoundError:
            raise StoreError(f"{name}: no results store there") from None
        except ValueError as e:
            raise StoreError(str(e)) from None
        except (OSError, SQLError) as e:
            raise StoreError(f"{name}: cannot open results store ({_msg(e)})") from None
        self.path = self._db.path if self._db.dialect == "sqlite" else self._db.name
        try:
            self._migrate(create)
        except SQLError as e:
            self._db.close()
            raise StoreError(f"{self.path}: not a usable results store ({_msg(e)})") from None
        except BaseException:
            self._db.close()
            raise

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._db.close()

    @property
    def identity(self) -> str:
        """What makes two Store objects the same store: the resolved file, or the URL."""
        return store_identity(self.path)

    @property
    def dialect(self) -> str:
        return self._db.dialect

    @contextmanager
    def _tx(self, what: str):
        """One write transaction (IMMEDIATE on SQLite): all of it is committed or none of it."""
        SQLError = _sqlerror()
        try:
            self._db.begin()
        except SQLError as e:
            raise StoreError(f"{self.path}: cannot {what} ({_msg(e)})") from None
        try:
            yield self._db
            self._db.commit()
        except BaseException as e:
            if self._db.in_transaction:
                self._db.rollback()
            if isinstance(e, SQLError):
                raise StoreError(f"{self.path}: cannot {what} ({_msg(e)}); nothing was recorded") from None
            raise

    @contextmanager
    def _snapshot(self):
        """One read transaction, so queries spanning tables see one committed state."""
        if self._db.in_transaction:
            yield
            return
        try:
            self._db.begin(write=False)
            yield
        except _sqlerror() as e:
            raise StoreError(f"{self.path}: cannot read runs ({_msg(e)})") from None
        finally:
            if self._db.in_transaction:
                try:
                    self._db.commit()
                except _sqlerror() as e:  # a damaged page can surface only here
                    raise StoreError(f"{self.path}: cannot read runs ({_msg(e)})") from None

    def _migrate(self, create: bool = True) -> None:
        version = self._db.schema_version()
        if version == 0 and not create:  # a reader never writes a schema into a file it only reads
            raise StoreError(f"{self.path}: not an accelcal results store (no schema); nothing was written")
        if version > SCHEMA_VERSION:
            raise StoreError(f"{self.path}: results store schema version {version} is newer than this "
                             f"station's {SCHEMA_VERSION}; upgrade accelcal-station")
        if version == SCHEMA_VERSION:
            return
        with self._tx("upgrade the schema") as db:
            db.lock_schema()
            version = db.schema_version()  # another process may have won
            if version == 0 and db.foreign_content():
                kind = "an SQLite file" if db.dialect == "sqlite" else "a database with runs/poses/events tables"
                raise StoreError(f"{self.path}: {kind} that is not an accelcal results store")
            for v in range(version, SCHEMA_VERSION):
                if callable(MIGRATIONS[v]):
                    MIGRATIONS[v](db)
                    db.set_schema_version(v + 1)
                    continue
                for stmt in MIGRATIONS[v].split(";"):
                    if stmt.strip():
                        db.raw(db.ddl(stmt))
                db.set_schema_version(v + 1)

    @property
    def schema_version(self) -> int:
        return self._db.schema_version()

    # -- recording ----------------------------------------------------------------------
    def start_run(self, *, device_serial: str | None, chip: str | None = None, station_id: str | None = None,
                  operator: str | None = None, lot: str | None = None, config_text: str | None = None,
                  config_hash: str | None = None, model: str | None = None, units: str | None = None,
                  counts_per_g: float | None = None, gravity_mps2: float | None = None,
                  started_at: float | None = None, panel_id: str | None = None) -> int:
        """Commit a ``running`` row now (a crash leaves it recorded) and return its id.

        ``config_hash`` defaults to the SHA-256 of ``config_text``; ``panel_id`` ties the runs
        of the boards calibrated together on one jig.
        """
        if config_hash is None and config_text is not None:
            config_hash = hashlib.sha256(config_text.encode()).hexdigest()
        with self._tx("start a run") as db:
            cur = db.execute(
                "INSERT INTO runs (started_at, status, device_serial, chip, station_id, operator, lot, config_hash,"
                " config_text, model, units, counts_per_g, gravity_mps2, host, pid, panel_id)"
                " VALUES (?, 'running', ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
                (_time.time() if started_at is None else float(started_at), device_serial, chip, station_id,
                 operator, lot, config_hash, config_text, _opt(model, str), units, _opt(counts_per_g),
                 _opt(gravity_mps2), socket.gethostname(), os.getpid(), panel_id))
            return int(cur.fetchone()[0])

    def _running(self, db, run_id: int) -> None:
        row = db.execute("SELECT status FROM runs WHERE id = ?", (run_id,)).fetchone()
        if row is None:
            raise StoreError(f"{self.path}: no run {run_id}")
        if row["status"] != "running":
            raise StoreError(f"{self.path}: run {run_id} is already {row['status']}; a run is closed once")

    def _insert_poses(self, db, run_id: int, session: Session, retries: Sequence[int] | None) -> None:
        if retries is not None and len(retries) != len(session):
            raise DataError(f"retries has {len(retries)} entries for {len(session)} poses")
        rows = []
        for i, p in enumerate(session.poses):
            ref = [None] * 3 if p.reference_g is None else [float(v) for v in p.reference_g]
            std = [None] * 3 if p.std is None else [float(v) for v in p.std]
            rows.append((run_id, i, p.name, _opt(p.pitch_deg), _opt(p.roll_deg), *ref, *map(float, p.mean), *std,
                         _opt(p.n, int), int(p.dropped), _opt(p.temp_c), _opt(p.t_start), _opt(p.t_end),
                         0 if retries is None else int(retries[i])))
        db.executemany(f"INSERT INTO poses (run_id, {', '.join(_POSE_COLS)}) VALUES ({', '.join('?' * 20)})", rows)
        db.execute("UPDATE runs SET units = ?, counts_per_g = ?, gravity_mps2 = ? WHERE id = ?",
                   (session.units, _opt(session.counts_per_g), _opt(session.gravity_mps2), run_id))

    def finish_run(self, run_id: int, *, session: Session, calibration: Calibration | None, verdict: str | None,
                   reasons: Iterable[Reason] = (), nvm_outcome: Any = None, fit_summary: dict | None = None,
                   model: str | None = None, retries: Sequence[int] | None = None,
                   finished_at: float | None = None) -> None:
        """Record poses, calibration, verdict and NVM outcome of a run as ``complete``, atomically.

        ``nvm_outcome``: a writer.BurnOutcome, its dict, or None when nothing was burned;
        ``reasons``: Reason objects (a plain string is kept with code "").
        """
        if verdict is not None and verdict not in VERDICTS:
            raise DataError(f"verdict {verdict!r}; allowed: PASS, FAIL")
        if nvm_outcome is not None and hasattr(nvm_outcome, "to_dict"):
            nvm_outcome = nvm_outcome.to_dict()
        nvm_status = "none" if nvm_outcome is None else ("written" if nvm_outcome.get("ok") else "failed")
        with self._tx(f"record run {run_id}") as db:
            self._running(db, run_id)
            self._insert_poses(db, run_id, session, retries)
            cal = None if calibration is None else calibration.to_dict()
            try:
                texts = [_json([Reason.from_dict(r).to_dict() for r in reasons]), _json(nvm_outcome), _json(cal), _json(fit_summary)]
            except (TypeError, ValueError) as e:
                raise DataError(f"run {run_id}: result is not JSON-serialisable ({e})") from None
            db.execute(
                "UPDATE runs SET status = 'complete', finished_at = ?, verdict = ?, reasons = ?, nvm_status = ?,"
                " nvm_outcome = ?, calibration = ?, fit_summary = ?, model = coalesce(?, model) WHERE id = ?",
                (_time.time() if finished_at is None else float(finished_at), verdict, texts[0], nvm_status,
                 *texts[1:], _opt(model or (calibration.model if calibration else None), str), run_id))

    def interrupt_run(self, run_id: int, reason: str, *, session: Session | None = None,
                      status: str = "interrupted", retries: Sequence[int] | None = None,
                      nvm_outcome: Any = None) -> None:
        """Close a run as ``interrupted`` (or ``error``) with the poses captured so far, atomically."""
        if status not in ("interrupted", "error"):
            raise DataError(f"status {status!r}; allowed: interrupted, error")
        if nvm_outcome is not None and hasattr(nvm_outcome, "to_dict"):
            nvm_outcome = nvm_outcome.to_dict()
        with self._tx(f"record run {run_id}") as db:
            self._running(db, run_id)
            if session is not None:
                self._insert_poses(db, run_id, session, retries)
            # no outcome given: keep what record_burn wrote (a burn cut short stays 'burning')
            db.execute("UPDATE runs SET status = ?, status_reason = ?, finished_at = ?,"
                       " nvm_status = coalesce(?, nvm_status), nvm_outcome = coalesce(?, nvm_outcome) WHERE id = ?",
                       (status, str(reason), _time.time(),
                        None if nvm_outcome is None else ("written" if nvm_outcome.get("ok") else "failed"),
                        _json(nvm_outcome), run_id))

    def record_burn(self, run_id: int, kind: str, outcome: dict) -> None:
        """A burn as it happens, committed at once: ``nvm_burning`` (slot, generation, blob CRC)
        sets the run's nvm_status to ``burning`` before the first byte; ``nvm_burned`` /
        ``nvm_burn_failed`` to ``burned`` / ``failed`` (finish_run then records the outcome)."""
        status = {"nvm_burning": "burning", "nvm_burned": "burned", "nvm_burn_failed": "failed"}[kind]
        crc = outcome.get("crc32")
        with self._tx(f"record the burn of run {run_id}") as db:
            db.execute("INSERT INTO events (run_id, t, kind, message, data) VALUES (?, ?, ?, ?, ?)",
                       (run_id, _time.time(), kind, f"slot {outcome.get('slot')}, generation "
                        f"{outcome.get('generation')}, CRC-32 {crc if crc is None else f'0x{crc:08x}'}",
                        _json(outcome)))
            db.execute("UPDATE runs SET nvm_status = ?, nvm_outcome = ? WHERE id = ?",
                       (status, _json(outcome), run_id))

    def log_event(self, run_id: int, kind: str, message: str = "", data: Any = None) -> None:
        """Append an event (a rejected capture, an operator prompt, ...), committed at once."""
        with self._tx(f"log an event of run {run_id}") as db:
            db.execute("INSERT INTO events (run_id, t, kind, message, data) VALUES (?, ?, ?, ?, ?)",
                       (run_id, _time.time(), kind, message, _json(data)))

    def mark_stale_interrupted(self, max_age_s: float | None = None) -> list[int]:
        """Mark ``running`` runs whose station process is gone as interrupted; returns their ids.

        A run is stale when it was started on this host by a process that no longer
        exists, or (any host) when ``max_age_s`` is given and it started longer ago.
        """
        host, now, stale = socket.gethostname(), _time.time(), []
        with self._tx("mark stale runs") as db:
            for r in db.execute("SELECT id, host, pid, started_at FROM runs WHERE status = 'running'").fetchall():
                old = max_age_s is not None and now - r["started_at"] > max_age_s
                if old or (r["host"] == host and r["pid"] is not None and not _alive(r["pid"])):
                    stale.append(r["id"])
            db.executemany("UPDATE runs SET status = 'interrupted', finished_at = ?, status_reason = ?"
                           " WHERE id = ?", [(now, "station stopped during the run", i) for i in stale])
        return stale

    # -- queries ------------------------------------------------------------------------
    def _where(self, device=None, station=None, lot=None, operator=None, since=None, until=None,
               verdict=None, status=None, model=None, run_ids=None) -> tuple[str, list]:
        clauses, args = [], []
        for col, v in (("device_serial", device), ("station_id", station), ("lot", lot), ("operator", operator),
                       ("verdict", verdict), ("status", status), ("model", model)):
            if v is not None:
                vals = [v] if isinstance(v, (str, int)) else list(v)
                clauses.append(f"{col} IN ({', '.join('?' * len(vals))})")
                args += [str(x) for x in vals]
        for op, v, what in ((">=", since, "since"), ("<", until, "until")):
            t = timestamp(v, what)
            if t is not None:
                clauses.append(f"started_at {op} ?")
                args.append(t)
        if run_ids is not None:
            ids = [int(i) for i in run_ids]
            clauses.append(f"id IN ({', '.join('?' * len(ids))})")
            args += ids
        return (" WHERE " + " AND ".join(clauses)) if clauses else "", args

    def _runs(self, filters: dict, limit: int | None = None) -> list[Row]:
        where, args = self._where(**filters)
        sql = f"SELECT * FROM runs{where} ORDER BY started_at, id"
        if limit is not None:
            sql += f" LIMIT {int(limit)}"
        try:
            return self._db.execute(sql, args).fetchall()
        except _sqlerror() as e:
            raise StoreError(f"{self.path}: cannot read runs ({_msg(e)})") from None

    def list_runs(self, limit: int | None = None, **filters) -> list[dict]:
        """Run summaries (no poses) matching filters: device, station, lot, operator, since,
        until, verdict, status, model (a value or a list of values), run_ids."""
        with self._snapshot():
            counts = dict(self._db.execute("SELECT run_id, count(*) FROM poses GROUP BY run_id").fetchall())
            rows = self._runs(filters, limit)
        out = []
        for r in rows:
            damaged = [c for c in ("fit_summary", "reasons") if _damaged(r[c])]
            fit = {} if "fit_summary" in damaged else (json.loads(r["fit_summary"]) if r["fit_summary"] else {})
            reasons = stored_reasons(r["reasons"])
            out.append({"id": r["id"], "started_at": iso(r["started_at"]), "finished_at": iso(r["finished_at"]),
                        "status": r["status"], "status_reason": r["status_reason"],
                        "device_serial": r["device_serial"], "chip": r["chip"], "station_id": r["station_id"],
                        "operator": r["operator"], "lot": r["lot"], "model": r["model"], "verdict": r["verdict"],
                        "reasons": [str(x) for x in reasons], "reason_codes": codes(reasons),
                        "nvm_status": r["nvm_status"], "pose_count": counts.get(r["id"], 0),
                        "panel_id": r["panel_id"],
                        "residual_rms_g": fit.get("residual_rms_g") if isinstance(fit, dict) else None,
                        **({"damaged": damaged} if damaged else {})})
        return out

    def _record(self, r: Row) -> RunRecord:
        cols = ("reasons", "nvm_outcome", "calibration", "fit_summary")  # JSON columns
        damaged = [k for k in cols if _damaged(r[k])]
        load = lambda k: None if r[k] is None or k in damaged else json.loads(r[k])  # noqa: E731
        rec = RunRecord(**{k: r[k] for k in r.keys() if k not in cols},
                        reasons=stored_reasons(r["reasons"]), nvm_outcome=load("nvm_outcome"),
                        calibration=load("calibration"), fit_summary=load("fit_summary"), damaged=damaged)
        for p in self._db.execute("SELECT * FROM poses WHERE run_id = ? ORDER BY idx", (r["id"],)):
            vec = lambda c: None if p[f"{c}_x"] is None else [p[f"{c}_{a}"] for a in AXES]  # noqa: E731
            rec.poses.append(PoseRecord(p["name"], vec("mean"), vec("std"), p["n"], vec("ref"), p["pitch_deg"],
                                        p["roll_deg"], p["temp_c"], p["dropped"], p["t_start"], p["t_end"]))
            rec.retries.append(p["retries"])
        rec.events = [{"t": e["t"], "kind": e["kind"], "message": e["message"],
                       "data": None if e["data"] is None else json.loads(e["data"])}
                      for e in self._db.execute("SELECT * FROM events WHERE run_id = ? ORDER BY id", (r["id"],))]
        return rec

    def get_run(self, run_id: int) -> RunRecord:
        with self._snapshot():
            rows = self._runs({"run_ids": [run_id]})
            if not rows:
                raise StoreError(f"{self.path}: no run {run_id}")
            return self._record(rows[0])

    def runs(self, **filters) -> list[RunRecord]:
        """Full records (poses, events) of the matching runs."""
        with self._snapshot():
            return [self._record(r) for r in self._runs(filters)]

    def sessions_for_batch(self, **filters) -> list[Session]:
        """Sessions of complete runs with poses (for batch recalibration of a lot)."""
        filters.setdefault("status", "complete")
        return [rec.session() for rec in self.runs(**filters) if rec.poses]

    # -- exports and summaries ----------------------------------------------------------
    def export_json(self, path: str | Path | None = None, **filters) -> list[dict]:
        """Every matching run in full; written atomically to ``path`` when given."""
        data = [rec.to_dict() for rec in self.runs(**filters)]
        if path is not None:
            _export(path, json.dumps({"schema": "accelcal.runs", "version": 1, "runs": data}, indent=1) + "\n")
        return data

    def export_csv(self, path: str | Path | None = None, kind: str = "runs", **filters) -> str:
        """CSV of runs (one row per run, calibration flattened) or poses (one row per pose).

        Returns the text; written atomically to ``path`` when given.
        """
        if kind not in ("runs", "poses"):
            raise DataError(f"CSV kind {kind!r}; allowed: runs, poses")
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        recs = self.runs(**filters)
        if kind == "runs":
            w.writerow([*_RUN_CSV_COLS, *_FIT_SCALARS, *PARAM_NAMES])
            for rec in recs:
                d = asdict(rec)
                d.update(started_at=iso(rec.started_at), finished_at=iso(rec.finished_at),
                         reasons="; ".join(rec.reasons), pose_count=len(rec.poses))
                fit = rec.fit_summary or {}
                params = param_vector(rec.calibration).tolist() if rec.calibration else [None] * 15
                w.writerow([*(d[c] for c in _RUN_CSV_COLS), *(fit.get(k) for k in _FIT_SCALARS), *params])
        else:
            w.writerow(["run_id", "device_serial", "lot", "verdict", "units", *_POSE_COLS])
            for rec in recs:
                for i, (p, retries) in enumerate(zip(rec.poses, rec.retries)):
                    v = lambda a: [None] * 3 if a is None else list(a)  # noqa: E731
                    w.writerow([rec.id, rec.device_serial, rec.lot, rec.verdict, rec.units, i, p.name, p.pitch_deg,
                                p.roll_deg, *v(p.reference_g), *v(p.mean), *v(p.std), p.n, p.dropped, p.temp_c,
                                p.t_start, p.t_end, retries])
        text = buf.getvalue()
        if path is not None:
            _export(path, text)
        return text

    def lot_summary(self, **filters) -> dict:
        """Counts, pass rate, failure reasons and parameter distributions of the matching runs.

        pass_rate = PASS / (PASS + FAIL) over complete runs (None when there are none);
        failure_reasons counts FAIL runs per reason code; parameters (W, V, Gamma
        elements, PARAM_NAMES) and fit figures give mean, sample std (ddof=1), min,
        max over complete runs with a calibration.
        """
        rows = self._runs(filters)
        by_status = Counter(r["status"] for r in rows)
        done = [r for r in rows if r["status"] == "complete"]
        verdicts = Counter(r["verdict"] for r in done if r["verdict"])
        decided = verdicts["PASS"] + verdicts["FAIL"]
        fail_reasons: Counter = Counter()
        for r in done:
            if r["verdict"] == "FAIL":
                fail_reasons.update(set(codes(stored_reasons(r["reasons"]))))
        cals = [c for c in (_load_or(r["calibration"], None) for r in done) if c]
        params = None
        if cals:
            s = _stats(np.array([param_vector(c) for c in cals]))
            params = {name: {k: (v if k == "n" else v[i]) for k, v in s.items()} for i, name in enumerate(PARAM_NAMES)}
        fits = [f for f in (_load_or(r["fit_summary"], None) for r in done) if isinstance(f, dict)]
        fit_stats = {}
        for k in _FIT_SCALARS:
            vals = [f[k] for f in fits if isinstance(f.get(k), (int, float))]
            if vals:
                fit_stats[k] = _stats(np.array(vals))
        starts = [r["started_at"] for r in rows]
        return {
            "runs": len(rows),
            "by_status": {s: by_status.get(s, 0) for s in STATUSES},
            "pass": verdicts["PASS"], "fail": verdicts["FAIL"],
            "pass_rate": verdicts["PASS"] / decided if decided else None,
            "failure_reasons": dict(fail_reasons.most_common()),
            "interruptions": dict(Counter(r["status_reason"] or "unknown" for r in rows
                                          if r["status"] in ("interrupted", "error")).most_common()),
            "nvm": dict(Counter(r["nvm_status"] or "none" for r in done)),
            "devices": len({r["device_serial"] for r in rows}),
            "models": dict(Counter(r["model"] for r in done if r["model"])),
            "first_started": iso(min(starts)) if starts else None,
            "last_started": iso(max(starts)) if starts else None,
            "parameters": params,
            "fit": fit_stats,
        }


def _damaged(text) -> bool:
    """A JSON column that does not parse: the row is shown as damaged, the listing goes on."""
    if text is None:
        return False
    try:
        json.loads(text)
    except (TypeError, ValueError):
        return True
    return False


def _load_or(text, default):
    """A JSON column's value, or ``default`` when it is empty or damaged."""
    return default if text is None or _damaged(text) else json.loads(text)


def _alive(pid: int) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _export(path, text: str) -> None:
    try:
        atomic_write_text(path, text)
    except OSError as e:
        raise StoreError(f"{path}: cannot write export ({e.strerror})") from None


def store_identity(target) -> str:
    """A store's identity: the resolved file of an SQLite store, the URL of a server store."""
    if is_url(target) and not str(target).startswith("sqlite:///"):
        return describe_target(target)
    p = str(target)[len("sqlite:///"):] if str(target).startswith("sqlite:///") else target
    return str(Path(p).resolve())

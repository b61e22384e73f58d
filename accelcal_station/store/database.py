"""The results store's database connection: SQLite (a file, the default) or PostgreSQL (a line's
shared server), both through SQLAlchemy Core; PostgreSQL through psycopg.

A store target is a file path, ``sqlite:///PATH`` or ``postgresql://USER@HOST:PORT/DB``
(``postgresql+psycopg://`` too; ``?host=/socket/dir`` for a unix socket).  Statements are
SQLAlchemy Core expressions on the tables of schema.py.  Transactions are SQLAlchemy's
(``Connection.begin``): on SQLite a write transaction starts ``BEGIN IMMEDIATE`` (one
writer; others wait out the busy timeout), emitted by the ``begin`` event as SQLAlchemy's
documentation prescribes for pysqlite, whose own transaction handling defers BEGIN and
cannot run DDL in a transaction; PostgreSQL runs at READ COMMITTED (MVCC: many stations
insert at once; identity ids never collide).
"""
from __future__ import annotations

import contextlib
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard

from .celltext import decode_text

if TYPE_CHECKING:
    from sqlalchemy import Connection, CursorResult, Engine, Executable, RootTransaction

Row = Mapping[str, Any]  # a result row by column name (SQLAlchemy's RowMapping, or a checked dict)


# the store a station config names when it names none (config/schema.py StoreSection.path); here, not in
# location.py, so that naming it imports no config schema (issue 51: `accelcal batch LOT --out` start-up)
DEFAULT_STORE = "accelcal-runs.sqlite"


def is_url(target: object) -> TypeGuard[str]:
    return isinstance(target, str) and "://" in target


def redact(url: str) -> str:
    """A URL without its password, for messages."""
    return re.sub(r"(://[^:/@]+):[^@/]*@", r"\1:***@", url)


def describe_target(target: str | Path) -> str:
    return redact(target) if is_url(target) else str(target)


def _sqlite_events(engine: Engine) -> None:
    """Foreign keys on (off by default in SQLite); the driver's own transactions off and a
    write transaction begun IMMEDIATE (the writer lock taken at once, not at the first write)."""
    from sqlalchemy import event

    @event.listens_for(engine, "connect")
    def _connect(dbapi_conn: Any, _rec: Any) -> None:
        dbapi_conn.isolation_level = None
        dbapi_conn.text_factory = decode_text  # a bad byte damages its cell, not the query (celltext.py)
        dbapi_conn.execute("PRAGMA foreign_keys = ON")

    @event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        opts = conn.get_execution_options()
        if opts.get("accelcal_tx"):  # a statement outside Database.begin runs on its own (autocommit)
            conn.exec_driver_sql("BEGIN IMMEDIATE" if opts.get("accelcal_write", True) else "BEGIN")


class Database:
    """One connection to a store target; ``dialect`` is "sqlite" or "postgresql"."""

    dialect: str
    path: Path | None
    name: str
    engine: Engine
    conn: Connection

    def __init__(self, target: str | Path, timeout_s: float = 10.0, create: bool = True, read_only: bool = False):
        """``read_only``: an SQLite file opened ``mode=ro`` (SQLite refuses every write; nothing, not
        even a journal, is created), a PostgreSQL session set ``default_transaction_read_only``."""
        from sqlalchemy import create_engine
        from sqlalchemy.pool import NullPool

        self.target = target
        if is_url(target):
            url = str(target)
            if url.startswith("sqlite:///"):
                target = Path(url[len("sqlite:///"):])
            elif url.startswith(("postgresql://", "postgresql+psycopg://")):
                self.dialect = "postgresql"
                self.path = None
                self.name = redact(url)
                self._url = "postgresql+psycopg://" + url.split("://", 1)[1]
            else:
                raise ValueError(f"{redact(url)}: unknown store URL scheme; allowed: a file path, "
                                 "sqlite:///PATH or postgresql://USER@HOST:PORT/DB")
        if not is_url(target):
            self.dialect = "sqlite"
            self.path = Path(target)
            self.name = str(self.path)
            if (read_only or not create) and not self.path.is_file():
                raise FileNotFoundError(f"{self.path}: no results store there")
            if read_only:  # SQLite's URI form; the path percent-quoted so '?' or '#' in a name stay the name
                from urllib.parse import quote

                self._url = f"sqlite:///file:{quote(str(self.path.resolve()))}?mode=ro&uri=true"
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._url = "sqlite:///" + str(self.path)
        args: dict[str, object] = {"timeout": timeout_s} if self.dialect == "sqlite" else \
            {"connect_timeout": max(1, int(timeout_s))}
        if read_only and self.dialect == "postgresql":
            args["options"] = "-c default_transaction_read_only=on"
        self.engine = create_engine(self._url, poolclass=NullPool, connect_args=args)
        if self.dialect == "sqlite":
            _sqlite_events(self.engine)
        self._tx: RootTransaction | None = None
        self.conn = self.engine.connect()
        self._idle()

    @property
    def in_transaction(self) -> bool:
        return self._tx is not None

    # -- statements -----------------------------------------------------------------------
    def execute(self, stmt: Executable, params: Any = None) -> CursorResult[Any]:
        """Run a Core statement inside the open transaction (``params``: a dict, or a list of
        dicts for executemany); never autobegun, so no transaction is left open by accident."""
        if self._tx is None:
            raise RuntimeError("Database.execute outside a transaction")
        return self.conn.execute(stmt, params)

    def rows(self, stmt: Executable) -> list[Row]:
        """The rows of a SELECT by column name (in a read transaction of its own when none is open)."""
        if self._tx is not None:
            return [dict(m) for m in self.conn.execute(stmt).mappings()]
        self.begin(write=False)
        try:
            out: list[Row] = [dict(m) for m in self.conn.execute(stmt).mappings()]
        except BaseException:
            self.rollback()
            raise
        self.commit()
        return out

    def scalar(self, stmt: Executable) -> Any:
        """The first value of the first row (None when there is no row)."""
        got = self.rows(stmt)
        return next(iter(got[0].values())) if got else None

    def _idle(self) -> None:
        """Between transactions the connection autocommits: a statement run on it directly (the
        web layer's read-only queries) never leaves a transaction open that would hold SQLite's
        lock or a PostgreSQL snapshot."""
        if self.dialect == "postgresql":
            self.conn.execution_options(isolation_level="AUTOCOMMIT")
        else:
            self.conn.execution_options(accelcal_tx=False)

    def begin(self, write: bool = True) -> None:
        if self.conn.in_transaction():  # an autobegun, autocommitting statement's: nothing to keep
            self.conn.commit()
        if self.dialect == "postgresql":
            self.conn.execution_options(isolation_level="READ COMMITTED")
        else:
            self.conn.execution_options(accelcal_tx=True, accelcal_write=write)
        self._tx = self.conn.begin()

    def commit(self) -> None:
        tx, self._tx = self._tx, None
        try:
            if tx is not None:
                tx.commit()
        finally:
            with contextlib.suppress(Exception):  # a connection lost with its transaction
                self._idle()

    def rollback(self) -> None:
        tx, self._tx = self._tx, None
        with contextlib.suppress(Exception):  # a lost server or SQLite's own rollback (disk full)
            if tx is not None:
                tx.rollback()
        with contextlib.suppress(Exception):
            self._idle()

    def close(self) -> None:
        try:
            with contextlib.suppress(Exception):  # closing a connection to a server that went away
                self.conn.close()
        finally:
            self.engine.dispose()

"""The results store's database connection: SQLite (a file, the default) or PostgreSQL (a line's
shared server), both through SQLAlchemy Core; PostgreSQL through psycopg.

A store target is a file path, ``sqlite:///PATH`` or ``postgresql://USER@HOST:PORT/DB``
(``postgresql+psycopg://`` too; ``?host=/socket/dir`` for a unix socket).  Statements are
written once with ``?`` placeholders (the store's SQL is plain SQL-92 plus RETURNING) and
sent as SQLAlchemy ``text()``.  Transactions are explicit: ``BEGIN IMMEDIATE`` on SQLite
(one writer; others wait out the busy timeout), ``BEGIN`` on PostgreSQL (MVCC: many
stations insert at once; identity ids never collide).

Schema versions: SQLite keeps its version in ``PRAGMA user_version`` (unchanged from
earlier stores); PostgreSQL in the one-row table ``accelcal_schema``, read and raised under
a transaction-scoped advisory lock so two stations starting at once migrate once.  DDL
is translated for PostgreSQL: ``INTEGER PRIMARY KEY`` becomes an identity column and
``REAL`` (single precision there) ``DOUBLE PRECISION``.
"""
from __future__ import annotations

import contextlib
import re
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard

if TYPE_CHECKING:
    from sqlalchemy import Connection, CursorResult, Engine

_PG_LOCK_KEY = 0x61636361  # advisory lock id of schema migrations ("acca")


def is_url(target: object) -> TypeGuard[str]:
    return isinstance(target, str) and "://" in target


def redact(url: str) -> str:
    """A URL without its password, for messages."""
    return re.sub(r"(://[^:/@]+):[^@/]*@", r"\1:***@", url)


def describe_target(target: str | Path) -> str:
    return redact(target) if is_url(target) else str(target)


class Row(tuple):
    """A result row: by position (``row[0]``) or by column name (``row["id"]``), like sqlite3.Row."""

    _index: dict[str, int]

    def __new__(cls, values: Iterable[Any], index: dict[str, int]) -> Row:
        r = super().__new__(cls, values)
        r._index = index
        return r

    def __getitem__(self, k: Any) -> Any:
        if isinstance(k, str):
            return tuple.__getitem__(self, self._index[k])
        return tuple.__getitem__(self, k)

    def keys(self) -> list[str]:
        return list(self._index)


class Result:
    """The rows of one statement (none for a statement that returns no rows)."""

    def __init__(self, res: CursorResult[Any]):
        self._res = res
        self._index: dict[str, int] | None = None
        if res is not None and res.returns_rows:
            self._index = {k: i for i, k in enumerate(res.keys())}

    def fetchone(self) -> Row | None:
        if self._index is None:
            return None
        r = self._res.fetchone()
        return None if r is None else Row(tuple(r), self._index)

    def fetchall(self) -> list[Row]:
        index = self._index
        return [] if index is None else [Row(tuple(r), index) for r in self._res.fetchall()]

    def scalar(self) -> Any:
        """The first value of a statement that returns one row (a count, a pragma, RETURNING id)."""
        row = self.fetchone()
        if row is None:
            raise ValueError("the statement returned no row")
        return row[0]

    def __iter__(self) -> Iterator[Row]:
        return iter(self.fetchall())


_QMARK = re.compile(r"\?")


def _named(sql: str) -> tuple[str, int]:
    """``?`` placeholders as ``:p0, :p1, ...`` (the store's SQL has no '?' in literals)."""
    n = [0]

    def sub(_m: re.Match[str]) -> str:
        n[0] += 1
        return f":p{n[0] - 1}"

    return _QMARK.sub(sub, sql), n[0]


class Database:
    """One connection to a store target; ``dialect`` is "sqlite" or "postgresql"."""

    dialect: str
    path: Path | None
    name: str
    engine: Engine
    conn: Connection

    def __init__(self, target: str | Path, timeout_s: float = 10.0, create: bool = True):
        from sqlalchemy import create_engine, event
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
            if not create and not self.path.is_file():
                raise FileNotFoundError(f"{self.path}: no results store there")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._url = "sqlite:///" + str(self.path)
        args = {"timeout": timeout_s, "isolation_level": None} if self.dialect == "sqlite" \
            else {"connect_timeout": max(1, int(timeout_s))}
        self.engine = create_engine(self._url, poolclass=NullPool, connect_args=args)
        if self.dialect == "sqlite":
            @event.listens_for(self.engine, "connect")
            def _fk(dbapi_conn: Any, _rec: Any) -> None:  # foreign keys are off by default in SQLite
                dbapi_conn.execute("PRAGMA foreign_keys = ON")
        self.conn = self.engine.connect().execution_options(isolation_level="AUTOCOMMIT")
        self.in_transaction = False

    # -- statements -----------------------------------------------------------------------
    def execute(self, sql: str, params: Sequence[Any] = ()) -> Result:
        from sqlalchemy import text
        s, n = _named(sql)
        if n != len(params):
            raise ValueError(f"{n} placeholders, {len(params)} parameters")
        return Result(self.conn.execute(text(s), {f"p{i}": v for i, v in enumerate(params)}))

    def executemany(self, sql: str, rows: Iterable[Sequence[Any]]) -> None:
        from sqlalchemy import text
        batch = list(rows)
        if batch:
            s, _ = _named(sql)
            self.conn.execute(text(s), [{f"p{i}": v for i, v in enumerate(r)} for r in batch])

    def raw(self, sql: str) -> None:
        self.conn.exec_driver_sql(sql)

    def begin(self, write: bool = True) -> None:
        self.raw("BEGIN IMMEDIATE" if self.dialect == "sqlite" and write else "BEGIN")
        self.in_transaction = True

    def commit(self) -> None:
        self.in_transaction = False
        self.raw("COMMIT")

    def rollback(self) -> None:
        self.in_transaction = False
        with contextlib.suppress(Exception):  # SQLite may already have rolled back by itself (disk full)
            self.raw("ROLLBACK")

    def close(self) -> None:
        try:
            self.conn.close()
        finally:
            self.engine.dispose()

    # -- schema ---------------------------------------------------------------------------
    def ddl(self, stmt: str) -> str:
        """A migration statement for this dialect."""
        if self.dialect == "sqlite":
            return stmt
        stmt = re.sub(r"\bINTEGER PRIMARY KEY\b", "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY", stmt)
        return re.sub(r"\bREAL\b", "DOUBLE PRECISION", stmt)

    def schema_version(self) -> int:
        if self.dialect == "sqlite":
            return int(self.execute("PRAGMA user_version").scalar())
        if not self.execute("SELECT to_regclass('accelcal_schema') IS NOT NULL").scalar():
            return 0
        row = self.execute("SELECT version FROM accelcal_schema").fetchone()
        return 0 if row is None else int(row[0])

    def lock_schema(self) -> None:
        """Inside a transaction: serialise schema migrations between processes."""
        if self.dialect == "postgresql":
            self.execute(f"SELECT pg_advisory_xact_lock({_PG_LOCK_KEY})")
            self.raw("CREATE TABLE IF NOT EXISTS accelcal_schema (version INTEGER NOT NULL)")

    def set_schema_version(self, v: int) -> None:
        if self.dialect == "sqlite":
            self.raw(f"PRAGMA user_version = {int(v)}")
        else:
            self.raw("DELETE FROM accelcal_schema")
            self.execute("INSERT INTO accelcal_schema (version) VALUES (?)", (int(v),))

    def foreign_content(self) -> bool:
        """At version 0: does the database already hold tables of ours (or, SQLite, any)?"""
        if self.dialect == "sqlite":
            return bool(self.execute("SELECT count(*) FROM sqlite_master").scalar())
        return bool(self.execute("SELECT count(*) FROM information_schema.tables WHERE table_schema = "
                                 "current_schema() AND table_name IN ('runs', 'poses', 'events')").scalar())

"""What schema a store really has: its Alembic revision, its pre-Alembic marker and its columns.

A store whose ``alembic_version`` table is missing or empty says nothing reliable about itself
(a marker can be wrong, a revision deleted); its ``runs`` columns do: ``panel_id`` came with
schema 2, ``limits`` with 4, ``heartbeat_at`` with 5, ``site`` with 6 (schemas 2 and 3 differ only in the
reasons' text, so their columns cannot tell them apart).  Readers name such a store in one
line and never stamp it; only a migrating command records a revision, the one its columns say.
"""
from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import Column, Integer, MetaData, String, Table, inspect, select

from .database import Database

# the runs columns each schema added, newest first: (version, column)
_ADDED = ((6, "site"), (5, "heartbeat_at"), (4, "limits"), (2, "panel_id"), (1, "id"))
_SAME_COLUMNS = {2: (2, 3)}  # versions whose columns are alike
PRE_ALEMBIC_MAX = 3  # stores of schema 3 and older were written before Alembic: a marker, no revision table


_legacy = MetaData()
accelcal_schema = Table("accelcal_schema", _legacy, Column("version", Integer, nullable=False))
alembic_version = Table("alembic_version", _legacy, Column("version_num", String(32), nullable=False))


def table_names(db: Database) -> set[str]:
    return set(inspect(db.conn).get_table_names())


def legacy_version(db: Database, tables: set[str]) -> int:
    if db.dialect == "sqlite":
        return int(db.conn.exec_driver_sql("PRAGMA user_version").scalar() or 0)
    if "accelcal_schema" not in tables:
        return 0
    return int(db.scalar(select(accelcal_schema.c.version)) or 0)


def current_version(db: Database) -> int:
    """Inside a transaction: the store's schema version: its Alembic revision, else its pre-Alembic marker, else 0.
    A revision this station does not know counts as newer than any it does."""
    tables = table_names(db)
    legacy = legacy_version(db, tables)
    if "alembic_version" not in tables:
        return legacy
    rev = db.scalar(select(alembic_version.c.version_num))
    if rev is None:
        return legacy
    return max(int(rev), legacy) if str(rev).isdigit() else 10_000


@dataclass(frozen=True)
class StoreSchema:
    """``version``: the schema to read the store as (0: none); ``stamped``: an Alembic revision is
    recorded; ``revision_state``: "recorded", "empty" (the table has no row) or "missing";
    ``columns_version``: the newest schema whose columns the runs table has; ``marker``: the
    pre-Alembic marker (PRAGMA user_version / accelcal_schema)."""

    version: int
    stamped: bool
    revision_state: str
    columns_version: int
    marker: int

    def columns_text(self) -> str:
        alike = _SAME_COLUMNS.get(self.columns_version)
        return " or ".join(map(str, alike)) if alike else str(self.columns_version)


def columns_version(db: Database) -> int:
    """The newest schema whose columns the ``runs`` table has (0: no runs table)."""
    insp = inspect(db.conn)
    if "runs" not in insp.get_table_names():
        return 0
    have = {c["name"] for c in insp.get_columns("runs")}
    return next((v for v, col in _ADDED if col in have), 0)


def read_schema(db: Database) -> StoreSchema:
    """Inside a transaction: the store's schema as its revision, marker and columns say (nothing written).
    A file with neither a revision table nor a marker is no store of ours (version 0), whatever its tables."""
    tables = set(inspect(db.conn).get_table_names())
    marker = legacy_version(db, tables)
    rev = db.scalar(select(alembic_version.c.version_num)) if "alembic_version" in tables else None
    state = "recorded" if rev is not None else ("empty" if "alembic_version" in tables else "missing")
    cols = columns_version(db)
    if rev is not None:
        version = current_version(db)
    elif state == "missing" and marker == 0:
        version = 0
    else:  # the marker when the columns agree with it, else what the columns say
        version = marker if marker in _SAME_COLUMNS.get(cols, (cols,)) else cols
    return StoreSchema(version, rev is not None, state, cols, marker)


def inspect_store(db: Database) -> StoreSchema:
    """read_schema in a read transaction of its own."""
    db.begin(write=False)
    try:
        return read_schema(db)
    finally:
        db.rollback()


def pre_alembic(got: StoreSchema) -> bool:
    """A store written before Alembic (schema 3 at most): no revision table, a marker its columns agree with."""
    return got.revision_state == "missing" and got.marker == got.version <= PRE_ALEMBIC_MAX


def unstamped_line(name: str, got: StoreSchema, target: int) -> str | None:
    """One line naming a store without an Alembic revision (None when it has one): what its columns
    are and what to do; a reader writes nothing into it."""
    if got.stamped or got.version == 0 or pre_alembic(got):
        return None
    table = "no alembic_version table" if got.revision_state == "missing" else "alembic_version is empty"
    marker = f", its version marker says {got.marker}" if got.marker and got.marker != got.version else ""
    head = f"{name}: no schema revision recorded ({table}); its columns are schema {got.columns_text()}'s{marker}"
    if got.columns_version == target:
        return f"{head}; read as schema {target}, nothing written (`accelcal report migrate --db {name}` records it)"
    return (f"{head}, this station reads {target}; `accelcal report migrate --db {name}` upgrades it "
            "(nothing was written)")

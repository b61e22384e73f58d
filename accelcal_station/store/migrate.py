"""Schema upgrades of a results store by Alembic, run programmatically when a store is opened.

The revisions live in the package (``migrations/versions``, shipped as package data) so an
installed station upgrades the stores it opens.  They run on the store's own connection in
one transaction: on PostgreSQL under a transaction-scoped advisory lock, so two stations
starting at once migrate once (the second waits, then finds the work done).

Stores written before Alembic keep their version in ``PRAGMA user_version`` (SQLite) or
the one-row table ``accelcal_schema`` (PostgreSQL).  Such a store is stamped with the
revision of that version, then upgraded; after every upgrade that legacy marker is set to
the new version too, so an older station refuses a newer store as it always did.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import delete, func, insert, select

from .database import Database
from .records import StoreError
from .schemacheck import accelcal_schema, alembic_version, current_version, read_schema, table_names

if TYPE_CHECKING:
    from alembic.config import Config

SCRIPTS = Path(__file__).resolve().parent / "migrations"
_PG_LOCK_KEY = 0x61636361  # advisory lock id of schema migrations ("acca")
def revision(version: int) -> str:
    """The Alembic revision id of a schema version: 3 -> "0003"."""
    return f"{version:04d}"


def stamped(db: Database) -> bool:
    """Inside a transaction: does the store carry an Alembic revision (not only a pre-Alembic marker)?"""
    return "alembic_version" in table_names(db) and db.scalar(select(alembic_version.c.version_num)) is not None


def _set_legacy_version(db: Database, version: int) -> None:
    if db.dialect == "sqlite":
        db.conn.exec_driver_sql(f"PRAGMA user_version = {int(version)}")
        return
    accelcal_schema.create(db.conn, checkfirst=True)
    db.execute(delete(accelcal_schema))
    db.execute(insert(accelcal_schema).values(version=int(version)))


def _config(db: Database) -> Config:
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(SCRIPTS))
    cfg.attributes["connection"] = db.conn
    return cfg


def _foreign(db: Database, tables: set[str]) -> bool:
    """At version 0: does the database already hold tables of ours (or, SQLite, any)?"""
    if db.dialect == "sqlite":
        return bool(tables)
    return bool(tables & {"runs", "poses", "events"})


def upgrade(db: Database, name: str, target: int) -> None:
    """Inside a write transaction: bring the store to ``target`` (stamping a pre-Alembic store
    first); refuses a foreign database."""
    from alembic import command

    if db.dialect == "postgresql":
        db.execute(select(func.pg_advisory_xact_lock(_PG_LOCK_KEY)))
    version = current_version(db)  # another process may have won
    adopted = stamped(db)
    if version >= target and adopted:
        return
    if not adopted:  # no revision recorded: stamp what its columns say (its marker when they agree)
        version = read_schema(db).version
    tables = table_names(db)
    if version == 0 and _foreign(db, tables - {"alembic_version", "accelcal_schema"}):
        kind = "an SQLite file" if db.dialect == "sqlite" else "a database with runs/poses/events tables"
        raise StoreError(f"{name}: {kind} that is not an accelcal results store")
    cfg = _config(db)
    if version > 0 and not adopted:
        command.stamp(cfg, revision(version))
    if version < target:
        command.upgrade(cfg, revision(target))
    _set_legacy_version(db, max(version, target))

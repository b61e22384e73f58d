"""The results store's tables as SQLAlchemy Core ``Table`` objects: ``runs``, ``poses``, ``events``.

They are created and upgraded by the Alembic revisions in ``migrations/versions``
(migrate.py runs them when a store is opened); these objects only build statements.
Column types: times are unix seconds in ``REAL`` columns, which are DOUBLE PRECISION on
PostgreSQL (its REAL is single precision: microseconds would be lost); run and event ids
are ``INTEGER PRIMARY KEY`` on SQLite (the rowid) and a BIGINT identity on PostgreSQL.
"""
from __future__ import annotations

from sqlalchemy import (
    REAL,
    BigInteger,
    CheckConstraint,
    Column,
    ForeignKey,
    Identity,
    Index,
    Integer,
    MetaData,
    Table,
    Text,
    text,
)
from sqlalchemy.dialects.postgresql import DOUBLE_PRECISION
from sqlalchemy.types import TypeEngine


def real() -> TypeEngine[float]:
    """REAL on SQLite, DOUBLE PRECISION on PostgreSQL."""
    return REAL().with_variant(DOUBLE_PRECISION(), "postgresql")


def row_id() -> TypeEngine[int]:
    """INTEGER (the rowid alias) on SQLite, BIGINT elsewhere."""
    return BigInteger().with_variant(Integer(), "sqlite")


metadata = MetaData()

runs = Table(
    "runs", metadata,
    Column("id", row_id(), Identity(), primary_key=True, nullable=True),  # as 0001 (a rowid alias is never NULL)
    Column("started_at", real(), nullable=False),
    Column("finished_at", real()),
    Column("status", Text, nullable=False, server_default=text("'running'")),
    Column("status_reason", Text),
    Column("device_serial", Text),
    Column("chip", Text),
    Column("station_id", Text),
    Column("operator", Text),
    Column("lot", Text),
    Column("config_hash", Text),
    Column("config_text", Text),
    Column("model", Text),
    Column("units", Text),
    Column("counts_per_g", real()),
    Column("gravity_mps2", real()),
    Column("verdict", Text),
    Column("reasons", Text),        # JSON list of {"code", "message"}
    Column("nvm_status", Text),     # written / failed / none / burning / burned
    Column("nvm_outcome", Text),    # JSON (writer.BurnOutcome.to_dict)
    Column("calibration", Text),    # JSON (Calibration.to_dict)
    Column("fit_summary", Text),    # JSON (FitResult.to_json_dict or similar)
    Column("host", Text),
    Column("pid", Integer),
    Column("panel_id", Text),       # the boards calibrated together on one jig
    Column("limits", Text),         # JSON {limit key: number}: the acceptance limits the run was judged by
    Column("heartbeat_at", real()),  # unix s: the station process's last sign of life (store/heartbeat.py)
    Column("heartbeat_s", real()),   # s between its heartbeats (readers on any host judge staleness by it)
    Column("site", Text),           # JSON {gravity_mps2, source, gravity_u_mps2}: the site's gravity (schema 6)
    Column("uncertainty", Text),    # JSON {k, expanded, budget, decision_rule}: docs/uncertainty.md (schema 6)
    CheckConstraint("status IN ('running', 'complete', 'interrupted', 'error')"),
    CheckConstraint("verdict IN ('PASS', 'FAIL')"),
)
Index("runs_device", runs.c.device_serial, runs.c.started_at)
Index("runs_lot", runs.c.lot, runs.c.started_at)
Index("runs_started", runs.c.started_at)
Index("runs_panel", runs.c.panel_id)
Index("runs_station", runs.c.station_id, runs.c.started_at)

poses = Table(
    "poses", metadata,
    Column("run_id", Integer, ForeignKey("runs.id", ondelete="CASCADE"), primary_key=True),
    Column("idx", Integer, primary_key=True, autoincrement=False),
    Column("name", Text, nullable=False),
    Column("pitch_deg", real()), Column("roll_deg", real()),
    Column("ref_x", real()), Column("ref_y", real()), Column("ref_z", real()),  # expected output, g
    Column("mean_x", real(), nullable=False), Column("mean_y", real(), nullable=False),
    Column("mean_z", real(), nullable=False),  # session units
    Column("std_x", real()), Column("std_y", real()), Column("std_z", real()),  # session units
    Column("n", Integer),
    Column("dropped", Integer, nullable=False, server_default=text("0")),
    Column("temp_c", real()),
    Column("t_start", real()), Column("t_end", real()),
    Column("retries", Integer, nullable=False, server_default=text("0")),  # rejected captures before this one
)

events = Table(
    "events", metadata,
    Column("id", row_id(), Identity(), primary_key=True, nullable=True),  # as 0001 (a rowid alias is never NULL)
    Column("run_id", Integer, ForeignKey("runs.id", ondelete="CASCADE"), nullable=False),
    Column("t", real(), nullable=False),
    Column("kind", Text, nullable=False),
    Column("message", Text),
    Column("data", Text),  # JSON
)
Index("events_run", events.c.run_id)

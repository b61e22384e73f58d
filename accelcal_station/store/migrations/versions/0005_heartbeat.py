"""Schema 5: runs.heartbeat_at and runs.heartbeat_s, a running station's sign of life.

A station process refreshes ``heartbeat_at`` of its running runs every ``heartbeat_s`` seconds
(store/heartbeat.py), so a reader on any host can tell a run whose station died (kill -9, power
cut) from one still going: stale when the last heartbeat is more than ``STALE_BEATS`` beats old
(store/liveness.py).  Additive only (ADD COLUMN, no table copy); runs recorded before keep both
NULL and are judged as before (on their own host by the pid only).

Revision ID: 0005
Revises: 0004
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def _real() -> sa.types.TypeEngine[float]:
    """REAL on SQLite, DOUBLE PRECISION on PostgreSQL (as 0001's times)."""
    return sa.REAL().with_variant(sa.DOUBLE_PRECISION(), "postgresql")


def upgrade() -> None:
    op.add_column("runs", sa.Column("heartbeat_at", _real()))
    op.add_column("runs", sa.Column("heartbeat_s", _real()))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("heartbeat_s")
        batch.drop_column("heartbeat_at")

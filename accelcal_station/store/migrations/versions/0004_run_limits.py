"""Schema 4: runs.limits, the acceptance limits a run was judged by (JSON ``{key: number}``),
and the indexes the line page and the MES API read by (station, verdict, status over time).

Additive only: an ADD COLUMN (no table copy, even on SQLite) and new indexes.  Runs recorded
before keep ``limits`` NULL; readers fall back to the acceptance section of the run's own
``config_text`` (the config it was run with) and say so.

Revision ID: 0004
Revises: 0003
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None

INDEXES = {"runs_station": ["station_id", "started_at"], "runs_status_started": ["status", "started_at"],
           "runs_verdict_started": ["verdict", "started_at"]}


def upgrade() -> None:
    op.add_column("runs", sa.Column("limits", sa.Text))
    for name, cols in INDEXES.items():
        op.create_index(name, "runs", cols)


def downgrade() -> None:
    for name in INDEXES:
        op.drop_index(name, "runs")
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("limits")

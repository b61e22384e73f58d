"""Schema 4: runs.limits, the acceptance limits a run was judged by (JSON ``{key: number}``),
and an index by station over time (the line page's per-station charts and yields).

Additive only: an ADD COLUMN (no table copy, even on SQLite) and a new index.  Runs recorded
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

# (status, started_at) is not indexed on purpose: SQLite would take it for the first-pass yield's
# correlated "earlier run of this serial" lookup and scan every earlier run (runs_device serves that)
INDEXES = {"runs_station": ["station_id", "started_at"]}


def upgrade() -> None:
    op.add_column("runs", sa.Column("limits", sa.Text))
    for name, cols in INDEXES.items():
        op.create_index(name, "runs", cols)


def downgrade() -> None:
    for name in INDEXES:
        op.drop_index(name, "runs")
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("limits")

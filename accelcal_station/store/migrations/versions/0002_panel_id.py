"""Schema 2: runs.panel_id, the boards calibrated together on one jig.

Revision ID: 0002
Revises: 0001
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("runs", sa.Column("panel_id", sa.Text))  # an ADD COLUMN: no table copy, even on SQLite
    op.create_index("runs_panel", "runs", ["panel_id"])


def downgrade() -> None:
    op.drop_index("runs_panel", "runs")
    with op.batch_alter_table("runs") as batch:
        batch.drop_column("panel_id")

"""Schema 6: runs.site, the site's gravity the jig's references were scaled to (JSON
``{gravity_mps2, source, gravity_u_mps2}``), and runs.uncertainty, the run's uncertainty budget and
decision rule (JSON ``{k, expanded, budget, decision_rule}``; docs/uncertainty.md).

Additive only: two ADD COLUMNs (no table copy, even on SQLite).  Runs recorded before keep both
NULL: they were fitted against standard gravity and judged without a stated uncertainty.

Revision ID: 0006
Revises: 0005
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None

COLUMNS = ("site", "uncertainty")


def upgrade() -> None:
    for name in COLUMNS:
        op.add_column("runs", sa.Column(name, sa.Text))


def downgrade() -> None:
    with op.batch_alter_table("runs") as batch:
        for name in COLUMNS:
            batch.drop_column(name)

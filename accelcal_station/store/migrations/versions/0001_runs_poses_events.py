"""Schema 1: the runs, poses and events tables.

Revision ID: 0001
Revises:
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import DOUBLE_PRECISION

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def _real() -> sa.types.TypeEngine[float]:
    return sa.REAL().with_variant(DOUBLE_PRECISION(), "postgresql")


def _id() -> sa.Column[int]:
    return sa.Column("id", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), sa.Identity(), primary_key=True,
                     # SQLite: no NOT NULL, as the pre-Alembic DDL (a rowid alias is never NULL)
                     nullable=op.get_context().dialect.name == "sqlite")


def _runs() -> None:
    text_cols = ("status_reason", "device_serial", "chip", "station_id", "operator", "lot", "config_hash",
                 "config_text", "model", "units")
    op.create_table(
        "runs", _id(),
        sa.Column("started_at", _real(), nullable=False),
        sa.Column("finished_at", _real()),
        sa.Column("status", sa.Text, nullable=False, server_default=sa.text("'running'")),
        *(sa.Column(c, sa.Text) for c in text_cols),
        sa.Column("counts_per_g", _real()), sa.Column("gravity_mps2", _real()),
        sa.Column("verdict", sa.Text),
        *(sa.Column(c, sa.Text) for c in ("reasons", "nvm_status", "nvm_outcome", "calibration", "fit_summary",
                                          "host")),
        sa.Column("pid", sa.Integer),
        sa.CheckConstraint("status IN ('running', 'complete', 'interrupted', 'error')"),
        sa.CheckConstraint("verdict IN ('PASS', 'FAIL')"),
    )
    op.create_index("runs_device", "runs", ["device_serial", "started_at"])
    op.create_index("runs_lot", "runs", ["lot", "started_at"])
    op.create_index("runs_started", "runs", ["started_at"])


def upgrade() -> None:
    _runs()
    op.create_table(
        "poses",
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id", ondelete="CASCADE"), nullable=False),
        sa.Column("idx", sa.Integer, nullable=False, autoincrement=False),
        sa.Column("name", sa.Text, nullable=False),
        *(sa.Column(c, _real()) for c in ("pitch_deg", "roll_deg", "ref_x", "ref_y", "ref_z")),
        *(sa.Column(c, _real(), nullable=False) for c in ("mean_x", "mean_y", "mean_z")),
        *(sa.Column(c, _real()) for c in ("std_x", "std_y", "std_z")),
        sa.Column("n", sa.Integer),
        sa.Column("dropped", sa.Integer, nullable=False, server_default=sa.text("0")),
        *(sa.Column(c, _real()) for c in ("temp_c", "t_start", "t_end")),
        sa.Column("retries", sa.Integer, nullable=False, server_default=sa.text("0")),
        sa.PrimaryKeyConstraint("run_id", "idx"),
    )
    op.create_table(
        "events", _id(),
        sa.Column("run_id", sa.Integer, sa.ForeignKey("runs.id", ondelete="CASCADE"), nullable=False),
        sa.Column("t", _real(), nullable=False),
        sa.Column("kind", sa.Text, nullable=False),
        sa.Column("message", sa.Text),
        sa.Column("data", sa.Text),
    )
    op.create_index("events_run", "events", ["run_id"])


def downgrade() -> None:
    for t in ("events", "poses", "runs"):
        op.drop_table(t)

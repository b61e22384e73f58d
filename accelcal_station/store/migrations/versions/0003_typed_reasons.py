"""Schema 3: every stored reason becomes ``{"code", "message"}``.

Rows written before held bare text.  The code is the station's own ``reason_codes`` (kept
in fit_summary) when it kept them, else the text's first word (acceptance.py starts each
limit reason with its key).  A row whose JSON does not parse stays as it is (shown damaged).

Revision ID: 0003
Revises: 0002
"""
from __future__ import annotations

import json
from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None

runs = sa.table("runs", sa.column("id", sa.Integer), sa.column("reasons", sa.Text),
                sa.column("fit_summary", sa.Text))


def _load(text: Any) -> Any:
    try:
        return json.loads(text) if isinstance(text, str) else None
    except (ValueError, RecursionError):
        return None


def _legacy_code(text: str, typed: list[Any] | None, i: int) -> str:
    if typed is not None and i < len(typed) and isinstance(typed[i], str) and typed[i]:
        return typed[i]
    words = text.strip().split(None, 1)
    return words[0].split(":", 1)[0] if words else ""


def _typed(old: list[Any], fit: Any) -> list[Any]:
    codes = fit.get("reason_codes") if isinstance(fit, dict) else None
    typed = codes if isinstance(codes, list) and len(codes) == len(old) else None
    return [x if isinstance(x, dict) else {"code": _legacy_code(str(x), typed, i), "message": str(x)}
            for i, x in enumerate(old)]


def upgrade() -> None:
    bind = op.get_bind()
    rows = bind.execute(sa.select(runs.c.id, runs.c.reasons, runs.c.fit_summary)
                        .where(runs.c.reasons.is_not(None))).all()
    updates = [{"rid": r.id, "new": json.dumps(_typed(old, _load(r.fit_summary)))}
               for r in rows if isinstance(old := _load(r.reasons), list)]
    if updates:
        bind.execute(runs.update().where(runs.c.id == sa.bindparam("rid")).values(reasons=sa.bindparam("new")),
                     updates)


def downgrade() -> None:
    bind = op.get_bind()
    rows = bind.execute(sa.select(runs.c.id, runs.c.reasons).where(runs.c.reasons.is_not(None))).all()
    updates = [{"rid": r.id, "old": json.dumps([x.get("message", "") if isinstance(x, dict) else x for x in new])}
               for r in rows if isinstance(new := _load(r.reasons), list)]
    if updates:
        bind.execute(runs.update().where(runs.c.id == sa.bindparam("rid")).values(reasons=sa.bindparam("old")),
                     updates)

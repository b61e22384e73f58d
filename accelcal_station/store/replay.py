"""Writing a run recorded elsewhere (the local outbox, outbox.py) into a store, once.

A replayed run is matched on the server by what its station wrote at start: the row it
started there (``server_run_id``) or, when that id never came back, the same
``started_at``, ``host`` and ``pid``.  A match whose status and pose count already equal the
local record's is left alone (replaying twice inserts nothing twice); a match left
``running`` (or marked interrupted while the server was away) is completed from the local
record; no match: the run is inserted whole.  Events are added when no event of the same
time and kind is there.
"""
from __future__ import annotations

import json
import time
from typing import Any, TypedDict

from sqlalchemy import delete, func, insert, select, update

from ..acceptance.reasons import Reason
from .database import Database
from .records import RunRecord, to_json
from .schema import POSE_COLS
from .tables import events, poses, runs

LOCAL_KINDS = ("outbox", "synced")  # bookkeeping events of the outbox, never replayed
_COPIED = ("started_at", "finished_at", "status", "status_reason", "device_serial", "chip", "station_id", "operator",
           "lot", "config_hash", "config_text", "model", "units", "counts_per_g", "gravity_mps2", "verdict",
           "nvm_status", "host", "pid", "panel_id")


def _run_values(rec: RunRecord) -> dict[str, object]:
    """The ``runs`` columns of a record as the update writes them: column -> value (JSON as text)."""
    values: dict[str, object] = {c: getattr(rec, c) for c in _COPIED}
    values.update(reasons=json.dumps([Reason.from_dict(r).to_dict() for r in rec.reasons]),
                  nvm_outcome=to_json(rec.nvm_outcome), calibration=to_json(rec.calibration),
                  fit_summary=to_json(rec.fit_summary), limits=to_json(rec.limits), site=to_json(rec.site),
                  uncertainty=to_json(rec.uncertainty))
    return values


def _pose_rows(run_id: int, rec: RunRecord) -> list[dict[str, object]]:
    """The ``poses`` rows of a record: column -> value."""
    out: list[dict[str, object]] = []
    for i, (p, retries) in enumerate(zip(rec.poses, rec.retries, strict=True)):
        def v(a: Any) -> list[Any]:
            return [None] * 3 if a is None else [float(x) for x in a]

        vals = (i, p.name, p.pitch_deg, p.roll_deg, *v(p.reference_g), *v(p.mean), *v(p.std), p.n, int(p.dropped),
                p.temp_c, p.t_start, p.t_end, int(retries))
        out.append({"run_id": run_id, **dict(zip(POSE_COLS, vals, strict=True))})
    return out


class _Found(TypedDict):
    id: int
    status: str


def _match(db: Database, rec: RunRecord, server_run_id: int | None) -> _Found | None:
    """The run already written for ``rec`` (the server's id when it still names it, else the first
    with the same start, host and process): its id and status."""
    same = (runs.c.started_at == rec.started_at) & (runs.c.host == rec.host) & (runs.c.pid == rec.pid)
    if server_run_id is not None:
        got = db.rows(select(runs.c.id, runs.c.status).where((runs.c.id == server_run_id) & same))
        if got:
            return {"id": int(got[0]["id"]), "status": got[0]["status"]}
    got = db.rows(select(runs.c.id, runs.c.status).where(same).order_by(runs.c.id).limit(1))
    return {"id": int(got[0]["id"]), "status": got[0]["status"]} if got else None


def replay_run(db: Database, rec: RunRecord, server_run_id: int | None, note: str) -> tuple[int, bool]:
    """Inside a write transaction: ``rec`` written into ``db``; (its id there, whether anything was written)."""
    found = _match(db, rec, server_run_id)
    if found is not None:
        rid = found["id"]
        n = db.scalar(select(func.count()).select_from(poses).where(poses.c.run_id == rid))
        if found["status"] == rec.status and n == len(rec.poses):
            return rid, False
        db.execute(update(runs).where(runs.c.id == rid).values(**_run_values(rec)))
        db.execute(delete(poses).where(poses.c.run_id == rid))
    else:
        rid = int(db.execute(insert(runs).values(**_run_values(rec))).inserted_primary_key[0])  # type: ignore[index]
    if rec.poses:
        db.execute(insert(poses), _pose_rows(rid, rec))
    there = {(r["t"], r["kind"]) for r in db.rows(select(events.c.t, events.c.kind).where(events.c.run_id == rid))}
    new = [{"run_id": rid, "t": e["t"], "kind": e["kind"], "message": e["message"], "data": to_json(e["data"])}
           for e in rec.events if e["kind"] not in LOCAL_KINDS and (e["t"], e["kind"]) not in there]
    new.append({"run_id": rid, "t": time.time(), "kind": "replayed", "message": note,
                "data": None})
    db.execute(insert(events), new)
    return rid, True

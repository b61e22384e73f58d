"""A line store that survives its server going away: runs journal into a local SQLite outbox
and are replayed into the server when it is back (``sync``; replay.py writes each once).

``open_store`` gives a plain Store for an SQLite file and a ``LineStore`` for a server URL.
A LineStore records on the server while it answers, keeping in memory what each of its
runs wrote (start, burn records, events, with their times).  When the server cannot be
reached, at open or at any write, the station goes on against the outbox: a run already
started on the server is started again there with the same start time, host and pid and
its steps so far, then the failed write is made there.  The server is not tried again in
this process (one switch, no flapping).  At close one line is logged: "line database
unreachable: results kept locally, N waiting".  The next LineStore that reaches the server
replays the outbox first; ``accelcal report sync`` does it on demand.

A run that lives only in the outbox has a negative id in this process (minus its outbox
id), so it never collides with a server id; replay gives it a server id.
"""
from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Unpack

from .database import describe_target, is_url
from .heartbeat import HEARTBEAT_S
from .location import store_identity
from .records import StoreError, StoreUnreachable
from .run_args import RunResult, RunResultFields, RunStart, RunStartFields, one_of
from .runs import Store

log = logging.getLogger(__name__)


def default_outbox() -> Path:
    """``$XDG_STATE_HOME/accelcal/outbox.sqlite`` (default ``~/.local/state``): local, per user."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "accelcal" / "outbox.sqlite"


def open_store(target: str | Path, outbox: str | Path | None = None, heartbeat_s: float = HEARTBEAT_S) -> Store:
    """The store a station records into: a Store for a file, a LineStore for a server URL; its
    running runs beat every ``heartbeat_s`` seconds (store/heartbeat.py)."""
    if is_url(target) and not str(target).startswith("sqlite:///"):
        return LineStore(str(target), Path(outbox) if outbox is not None else default_outbox(),
                         heartbeat_s=heartbeat_s)
    return Store(target, heartbeat_s=heartbeat_s)


Step = Callable[[Store, int], None]  # one write of a run, made on a store under that store's id of the run


@dataclass
class _Run:
    """What a run of this process wrote, to start it again in the outbox."""

    start: RunStart  # its start time fixed
    server_id: int | None = None
    local_id: int | None = None
    steps: list[Step] = field(default_factory=list)


@dataclass
class SyncResult:
    replayed: list[tuple[int, int]] = field(default_factory=list)  # (outbox id, server id)
    unchanged: list[tuple[int, int]] = field(default_factory=list)  # already there in full
    running: list[int] = field(default_factory=list)  # outbox runs still open (a live station)


def waiting(local: Store, target_identity: str) -> list[int]:
    """Outbox runs for ``target_identity`` not yet replayed."""
    out = []
    for rec in local.runs():
        kinds = {e["kind"] for e in rec.events}
        meta = next((e["data"] for e in rec.events if e["kind"] == "outbox"), None)
        if isinstance(meta, dict) and meta.get("target") == target_identity and "synced" not in kinds \
                and rec.id is not None:
            out.append(rec.id)
    return out


def sync(server: Store, local: Store) -> SyncResult:
    """Replay every closed outbox run meant for ``server`` into it, each once."""
    res = SyncResult()
    local.mark_stale_interrupted()  # a station killed while journaling: its run is closed first
    ident = server.identity
    for rid in waiting(local, ident):
        rec = local.get_run(rid)
        if rec.status == "running":
            res.running.append(rid)
            continue
        meta = next(e["data"] for e in rec.events if e["kind"] == "outbox")
        named = meta.get("server_run_id") if isinstance(meta, dict) else None  # a dict: waiting() read it
        sid, wrote = server.replay_run(rec, named if isinstance(named, int) and not isinstance(named, bool) else None,
                                       f"kept in the local outbox while the line database was unreachable "
                                       f"(outbox run {rid}); replayed")
        local.log_event(rid, "synced", f"replayed into {ident} as run {sid}", {"target": ident, "run_id": sid})
        (res.replayed if wrote else res.unchanged).append((rid, sid))
    return res


class LineStore(Store):
    """A server store (``postgresql://...``) that journals into the outbox at ``outbox`` when the
    server cannot be reached; the station's writes (start_run, record_burn, log_event,
    finish_run, interrupt_run, mark_stale_interrupted) never fail for that reason.  Reads
    go to the server, or to the outbox while the server is away."""

    def __init__(self, target: str, outbox: Path, timeout_s: float = 10.0, heartbeat_s: float = HEARTBEAT_S):
        # not Store.__init__: the server may be away
        self.target, self.outbox_path, self.heartbeat_s = target, outbox, float(heartbeat_s)
        self.path = describe_target(target)
        self._primary: Store | None = None
        self._local: Store | None = None
        self._journal: dict[int, _Run] = {}
        self._timeout_s = timeout_s
        try:
            self._primary = Store(target, timeout_s, heartbeat_s=heartbeat_s)
            self._db = self._primary._db
        except StoreUnreachable as e:
            self._fail(e)
            return
        self._replay_waiting()

    @property
    def identity(self) -> str:
        return store_identity(self.target)

    @property
    def dialect(self) -> str:
        return "postgresql"

    @property
    def kept_locally(self) -> bool:
        return self._local is not None

    def _outbox(self) -> Store:
        if self._local is None:
            self._local = Store(self.outbox_path, self._timeout_s, heartbeat_s=self.heartbeat_s)
        return self._local

    def _fail(self, e: StoreError) -> None:
        """The server is gone: everything from now on goes to the outbox."""
        if self._primary is not None:
            self._primary.close()
            self._primary = None
        try:
            self._db = self._outbox()._db
        except StoreError as o:
            raise StoreError(f"{e}; and the local outbox cannot keep the results ({o})") from None

    def _replay_waiting(self) -> None:
        """At open, server reachable: replay what an earlier run left in the outbox."""
        if self._primary is None or not self.outbox_path.is_file():
            return
        try:
            with Store(self.outbox_path, self._timeout_s, create=False) as local:
                done = sync(self._primary, local)
        except StoreUnreachable as e:
            self._fail(e)
            return
        if done.replayed:
            log.warning(f"line database back: {len(done.replayed)} run(s) replayed from the local outbox "
                        f"{self.outbox_path}")

    def _to_local(self, run: _Run) -> int:
        """The run in the outbox (started there with its start and steps so far, once)."""
        local = self._outbox()
        if run.local_id is None:
            run.local_id = local.start_run(run.start)
            local.log_event(run.local_id, "outbox", f"line database {self.path} unreachable; kept locally",
                            {"target": self.identity, "server_run_id": run.server_id}, t=run.start.started_at)
            for step in run.steps:
                step(local, run.local_id)
        return run.local_id

    def _write(self, handle: int, step: Step) -> None:
        run = self._journal.get(handle)
        if run is None:
            raise StoreError(f"{self.path}: no run {handle} started by this station")
        if self._primary is not None and run.local_id is None and run.server_id is not None:
            try:
                step(self._primary, run.server_id)
                run.steps.append(step)
                return
            except StoreUnreachable as e:
                self._fail(e)
        step(self._outbox(), self._to_local(run))
        run.steps.append(step)

    # -- the station's writes ------------------------------------------------------------
    def start_run(self, start: RunStart | None = None, /, **fields: Unpack[RunStartFields]) -> int:
        """Store.start_run: on the server while it answers, else in the outbox (module doc)."""
        run = _Run(one_of(start, fields, RunStart).stamped())
        if self._primary is not None:
            try:
                run.server_id = self._primary.start_run(run.start)
                self._journal[run.server_id] = run
                return run.server_id
            except StoreUnreachable as e:
                self._fail(e)
        handle = -self._to_local(run)
        self._journal[handle] = run
        return handle

    def record_burn(self, run_id: int, kind: str, outcome: Mapping[str, object], t: float | None = None) -> None:
        at = time.time() if t is None else t
        self._write(run_id, lambda st, rid: st.record_burn(rid, kind, outcome, t=at))

    def log_event(self, run_id: int, kind: str, message: str = "", data: object = None, t: float | None = None) -> None:
        at = time.time() if t is None else t
        self._write(run_id, lambda st, rid: st.log_event(rid, kind, message, data, t=at))

    def finish_run(self, run_id: int, result: RunResult | None = None, /,
                   **fields: Unpack[RunResultFields]) -> None:
        r = one_of(result, fields, RunResult)
        self._write(run_id, lambda st, rid: st.finish_run(rid, r))

    def interrupt_run(self, run_id: int, reason: str, **kw: Any) -> None:  # Store.interrupt_run's keywords
        self._write(run_id, lambda st, rid: st.interrupt_run(rid, reason, **kw))

    def mark_stale_interrupted(self, max_age_s: float | None = None) -> list[int]:
        if self._primary is not None:
            try:
                return self._primary.mark_stale_interrupted(max_age_s)
            except StoreUnreachable as e:
                self._fail(e)
        return [-i for i in self._outbox().mark_stale_interrupted(max_age_s)]

    def close(self) -> None:
        """Close both; one line when results were kept locally."""
        try:
            if self._local is not None:
                n = len(waiting(self._local, self.identity))
                log.warning(f"line database unreachable: results kept locally, {n} waiting (outbox "
                            f"{self.outbox_path}; `accelcal report sync --db {self.path} --outbox "
                            f"{self.outbox_path}` replays them, so does the next run that reaches it)")
        finally:
            for s in (self._primary, self._local):
                if s is not None:
                    s.close()

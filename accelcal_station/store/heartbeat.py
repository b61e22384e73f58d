"""A running station's sign of life: a thread that refreshes ``runs.heartbeat_at`` of this
process's running runs every ``every_s`` seconds, on a connection of its own (one Store per
thread), so a reader on another host can tell a dead station's run from a live one
(liveness.stale_reason: stale after ``STALE_BEATS`` missed beats).

A heartbeat is best effort: a write that fails (the server away, the file locked past the busy
timeout) is logged once and tried again at the next beat; it never fails or slows the run.
Times are this host's clock: the line's hosts are expected to keep NTP time (docs/store.md).
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

from .database import Database

log = logging.getLogger("accelcal.store")

HEARTBEAT_S = 30.0  # default seconds between beats (store.heartbeat_s in the config)


class Heartbeat:
    """Beats for the runs added, until each is discarded or the heartbeat is closed."""

    def __init__(self, target: str | Path, every_s: float = HEARTBEAT_S, timeout_s: float = 10.0):
        self.target, self.every_s, self.timeout_s = target, float(every_s), timeout_s
        self._ids: set[int] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._failing = False
        self._thread = threading.Thread(target=self._loop, name="accelcal-heartbeat", daemon=True)
        self._thread.start()

    def add(self, run_id: int) -> None:
        with self._lock:
            self._ids.add(int(run_id))

    def discard(self, run_id: int) -> None:
        with self._lock:
            self._ids.discard(int(run_id))

    def close(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=self.timeout_s + self.every_s)

    def _loop(self) -> None:
        db: Database | None = None
        try:
            while not self._stop.wait(self.every_s):
                with self._lock:
                    ids = sorted(self._ids)
                if ids:
                    db = self._beat(db, ids)
        finally:
            if db is not None:
                db.close()

    def _beat(self, db: Database | None, ids: list[int]) -> Database | None:
        """One beat; returns the connection to keep (None after a failure: reopened next beat)."""
        from sqlalchemy import update
        from sqlalchemy.exc import SQLAlchemyError

        from .tables import runs

        conn = db
        try:
            if conn is None:
                conn = Database(self.target, self.timeout_s, create=False)
            conn.begin()
            try:
                conn.execute(update(runs).where(runs.c.id.in_(ids), runs.c.status == "running")
                             .values(heartbeat_at=time.time()))
                conn.commit()
            except BaseException:
                conn.rollback()
                raise
        except (OSError, SQLAlchemyError, ValueError) as e:
            if not self._failing:
                log.warning("heartbeat of run(s) %s not written (%s); retrying every %.0f s",
                            ", ".join(map(str, ids)), str(e).splitlines()[0][:200], self.every_s)
            self._failing = True
            if conn is not None:
                conn.close()
            return None
        if self._failing:
            log.info("heartbeat of run(s) %s written again", ", ".join(map(str, ids)))
        self._failing = False
        return conn

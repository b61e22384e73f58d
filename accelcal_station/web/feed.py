"""The events feed of finished runs: exactly-once delivery with resume by an event id.

Run ids are handed out when a run starts, but runs finish in any order, so "the last id
seen" cannot be a resume point.  The cursor is ``(low, done)``: every run with id < low
is finished and delivered (or does not exist), and ``done`` holds the delivered ids >= low
(the runs that finished while an older one is still running).  It travels as the SSE
event id / ``after`` parameter ``"low"`` or ``"low:a,b,c"``; the server keeps no state per
client.  The cursor never moves past a running run, nor past a missing id younger than
``GAP_S`` (an id allocated by a transaction not yet visible; PostgreSQL's identity
values are not in commit order), so a run that becomes visible late is still delivered.
A cursor's ``low`` is any int64 id, or ID_MAX + 1 once the run of id 2^63-1 is delivered (past
every id a store can hold); the feed starts at run 1, the first id a store hands out (a
hand-made lower id is reached with ``after=-9223372036854775808``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..errors import DataError

if TYPE_CHECKING:
    from .views import FeedRow

GAP_S = 60.0  # a hole in the ids older than this is a rolled-back insert, not a late commit
MAX_DONE = 100_000  # a cursor naming more delivered ids than this is refused (not ours)
ID_MIN, ID_MAX = -(2**63), 2**63 - 1  # run ids are int64 (SQLite's rowid, PostgreSQL's BIGINT)


@dataclass(frozen=True)
class Cursor:
    """Where a client is in the feed (module docstring)."""

    low: int = 1
    done: frozenset[int] = field(default_factory=frozenset)

    def text(self) -> str:
        return str(self.low) if not self.done else f"{self.low}:" + ",".join(map(str, sorted(self.done)))

    @classmethod
    def parse(cls, text: str | None) -> Cursor:
        """A cursor from its text; "" or None is the start of the feed."""
        if not text:
            return cls()
        head, _, tail = text.strip().partition(":")
        try:
            low = int(head)
            done = frozenset(int(x) for x in tail.split(",") if x) if tail else frozenset()
        except ValueError:
            raise DataError(f"event id {text[:40]!r}: not a cursor; allowed: N or N:id,id,... "
                            "as sent in an event's id") from None
        if len(done) > MAX_DONE:
            raise DataError(f"event id {text[:40]!r}: not a cursor this server sent (more than {MAX_DONE} ids)")
        # held to the ids a store can hold: a low past 2^63-1 is past every run, below -2^63 before every
        # one; a delivered id below low or outside int64 names no run still to come
        low = min(max(low, ID_MIN), ID_MAX + 1)
        return cls(low, frozenset(d for d in done if low <= d <= ID_MAX))


@dataclass(frozen=True)
class Step:
    """One delivered run and the cursor just after it."""

    run_id: int
    cursor: Cursor


def advance(cursor: Cursor, rows: list[FeedRow], now_s: float, limit: int = 500) -> list[Step]:
    """The runs to deliver after ``cursor``, given ``rows`` = (id, status, started_at) of every
    visible run with id >= cursor.low in id order (one statement, one snapshot)."""
    running = [r["id"] for r in rows if r["status"] == "running"]
    blocked_at = running[0] if running else None  # the cursor stops below a running run
    expected = cursor.low
    for r in rows:  # the first hole that may still fill (a young gap in the ids)
        if r["id"] > expected and now_s - float(r["started_at"] or 0.0) < GAP_S:
            blocked_at = expected if blocked_at is None else min(blocked_at, expected)
            break
        expected = r["id"] + 1
    steps: list[Step] = []
    done = set(cursor.done)
    for r in rows:
        if r["status"] == "running" or r["id"] in done:
            continue
        if len(steps) >= limit:
            break
        done.add(r["id"])
        low = r["id"] + 1 if blocked_at is None else min(blocked_at, r["id"] + 1)
        low = max(low, cursor.low)
        while low in done and (blocked_at is None or low < blocked_at):
            low += 1  # delivered earlier, out of order: the cursor passes over them
        steps.append(Step(r["id"], Cursor(low, frozenset(d for d in done if d >= low))))
    return steps


def head(low: int, rows: list[FeedRow]) -> Cursor:
    """A cursor at the feed's present end (a page that shows the past already and wants what comes next)."""
    return Cursor(max(1, low), frozenset(r["id"] for r in rows if r["status"] != "running" and r["id"] >= low))

"""Whether a ``running`` run's station process is still there: a run whose process is gone reads
``stale``, so a run killed with SIGKILL (or a power cut) is not shown as running until the next
run on that host marks it interrupted (Store.mark_stale_interrupted).

A run row holds the host name and pid of the process that started it (Store.start_run).  On
the host that wrote it, the run is stale when that pid does not exist, or when the process that
has the pid now started after the run did (the pid was reused; Linux: /proc/PID/stat field 22,
clock ticks after boot, plus /proc/stat btime).  On any host (schema 5), the run is stale when its
station's heartbeat (store/heartbeat.py: ``heartbeat_at`` refreshed every ``heartbeat_s``) is more
than ``STALE_BEATS`` beats old by this host's clock.  A run with no heartbeat (recorded before
schema 5) started on another host cannot be judged from here and keeps its stored status.
Nothing is written: reading never changes the store.
"""
from __future__ import annotations

import math
import os
import socket
import time
from collections.abc import Mapping
from functools import cache
from typing import TypeGuard

STALE = "stale"
PID_START_SLACK_S = 2.0  # /proc start times are whole clock ticks and btime whole seconds
# beats missed before a run reads stale: a busy server or a long busy-timeout wait delays a beat or
# two, never ten (at the default 30 s: five minutes of silence)
STALE_BEATS = 10


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one we may not signal exists too)."""
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, OverflowError, ValueError):  # gone, or not a pid at all (a damaged row)
        return False
    except PermissionError:
        return True
    return True


@cache
def _boot_time_s() -> float | None:
    try:
        with open("/proc/stat") as f:
            return next(float(ln.split()[1]) for ln in f if ln.startswith("btime "))
    except (OSError, StopIteration, ValueError, IndexError):
        return None


def process_started_at(pid: int) -> float | None:
    """Unix time the process ``pid`` started (Linux /proc); None where it cannot be told."""
    boot = _boot_time_s()
    try:
        with open(f"/proc/{int(pid)}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()  # the command name may hold spaces and ')'
        return None if boot is None else boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _silent(row: Mapping[str, object], now: float) -> str | None:
    """Why a run on another host is stale by its heartbeat; None when it beat recently or has none."""
    beat, every = row.get("heartbeat_at"), row.get("heartbeat_s")
    if not _number(beat) or not _number(every) or every <= 0:
        return None
    if now - beat <= STALE_BEATS * every:
        return None
    return (f"no heartbeat from the station on {row.get('host')} for {now - beat:.0f} s "
            f"(it beats every {every:g} s)")


def _number(v: object) -> TypeGuard[float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def stale_reason(row: Mapping[str, object], host: str | None = None, now: float | None = None) -> str | None:
    """Why the checked ``runs`` row ``row`` (status running) has no live station process; None when it
    may be alive or cannot be judged here (module doc)."""
    pid, started = row.get("pid"), row.get("started_at")
    if row.get("status") != "running":
        return None
    if row.get("host") != (host or socket.gethostname()):
        return _silent(row, time.time() if now is None else now)
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return None
    if not pid_alive(pid):
        return f"station process {pid} on {row['host']} is gone"
    t0 = process_started_at(pid)
    if t0 is not None and isinstance(started, (int, float)) and t0 > started + PID_START_SLACK_S:
        return f"station process {pid} on {row['host']} is gone (the pid now belongs to a later process)"
    return None


def live_status(row: Mapping[str, object]) -> tuple[str | None, str | None] | None:
    """The status and reason a checked ``runs`` row reads with: (``stale``, why) when its station process
    is gone (stale_reason), None when it reads as stored."""
    why = stale_reason(row)
    return None if why is None else (STALE, why)

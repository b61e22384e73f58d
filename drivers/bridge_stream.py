"""One STREAM request over the bridge link (docs/bridge-protocol.md): SAMPLE frames gathered in order by
their index, the frames the bridge lost counted, ended by STREAM_END, by the m-th sample, by a stall or
by a BOOT frame (the bridge reset: BridgeReset)."""
from __future__ import annotations

import time
from dataclasses import dataclass

from . import bridge_protocol as bp
from .bridge_link import BridgeLink, BridgeReset


@dataclass
class Received:
    """What a capture has received so far, across its STREAM requests: the samples' bytes (x, y, z, TEMP_OUT
    big-endian int16 each), their MCU times in s, and the samples lost (``dropped[0]``)."""

    raw: bytearray
    times: list[float]
    dropped: list[int]


def stream_once(link: BridgeLink, port: str, m: int, got: Received, inactivity_s: float) -> str:
    """One STREAM of m samples into ``got``: "done", "short" (STREAM_END before m) or "stalled" (no frame
    for ``inactivity_s``)."""
    raw, times, dropped = got.raw, got.times, got.dropped
    link.command(bp.CMD_STREAM, bp.STREAM.pack(m))
    expected = 0
    while (frame := link.next_frame(time.monotonic() + inactivity_s)) is not None:
        f, t = frame
        if f.type == bp.RSP_BOOT:
            raise BridgeReset(port, f)
        if f.type == bp.RSP_SAMPLE and len(f.payload) == 4 + bp.SAMPLE_BYTES:
            i = bp.SAMPLE_INDEX.unpack_from(f.payload)[0]
            if i < expected or i >= m:
                continue
            dropped[0] += i - expected
            expected = i + 1
            raw += f.payload[4:]
            times.append(t)
            if expected == m:
                return "done"  # STREAM_END follows; the next command skips it
        elif f.type == bp.RSP_STREAM_END and len(f.payload) == bp.STREAM_END.size:
            sent = min(bp.STREAM_END.unpack(f.payload)[0], m)
            dropped[0] += max(0, sent - expected)
            return "done" if sent >= m else "short"
    link.stats.timeouts += 1
    return "stalled"

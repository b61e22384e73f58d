"""The serial link to the MPU6050 bridge (docs/bridge-protocol.md), through pyserial.

Frames of :mod:`bridge_protocol` both ways: commands are sent with a sequence number and
matched to their ACK/NAK; garbage and CRC failures are skipped by the parser (resync); a
gap in the bridge's sequence numbers counts lost frames; a command unanswered within
``timeout_s``, or NAKed for an I2C or NVM fault, is resent up to ``retries`` times; a BOOT
frame (the bridge reset) is raised as :class:`BridgeReset` for the driver to recover from.
MCU timestamps become seconds that never go back (:class:`_McuClock`).
"""
from __future__ import annotations

import errno
import logging
import time
from collections import deque
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass, field
from typing import TypeVar

import serial

from ..errors import PORT_FAULTS, DeviceError, PortLostError
from . import bridge_protocol as bp

log = logging.getLogger(__name__)
RETRYABLE_NAKS = (bp.ERR_I2C, bp.ERR_NVM)
PERMISSION_HINT = "add the user to the dialout group (sudo usermod -aG dialout $USER) and log in again"

T = TypeVar("T")


@dataclass
class LinkStats:
    """What the link saw since it was made: frames, losses, retries, resets, parser counts."""

    frames: int = 0  # good frames received
    lost_frames: int = 0  # from gaps in the bridge's sequence numbers
    timeouts: int = 0  # commands or streams that went unanswered for timeout_s
    retries: int = 0  # commands resent (timeout or retryable NAK)
    naks: int = 0
    resets: int = 0  # BOOT frames seen after open
    dropped_samples: int = 0

    parser: bp.ParserStats = field(default_factory=bp.ParserStats)


class BridgeReset(DeviceError):
    """The bridge sent BOOT: it restarted, and the chip is back at its power-on state."""

    def __init__(self, port: str, frame: bp.Frame) -> None:
        cause = bp.BOOT_CAUSES.get(frame.payload[1], "unknown") if len(frame.payload) >= 2 else "unknown"
        self.cause = cause
        super().__init__(f"MPU6050 bridge on {port} reset ({cause})")


class BridgeRefused(DeviceError):
    """The bridge answered NAK with an error that retrying cannot fix; ``code`` is the NAK's error code."""

    def __init__(self, message: str, code: int = 0) -> None:
        super().__init__(message)
        self.code = code


class _McuClock:
    """MCU microsecond timestamps (u32, wrap every 71.6 min) as seconds that never go back.

    Across a bridge reset the MCU clock restarts; the gap is bridged with the host's clock.
    """

    def __init__(self) -> None:
        self._last: int | None = None
        self._us = 0
        self._host_t = 0.0

    def seconds(self, ts_us: int, boot: bool = False) -> float:
        host_t = time.monotonic()
        if self._last is None:
            self._us = ts_us
        elif boot:
            self._us += int((host_t - self._host_t) * 1e6)
        else:
            d = (ts_us - self._last) & 0xFFFFFFFF
            self._us += d if d < 0x80000000 else 0  # a step back only at an unseen reset
        self._last, self._host_t = ts_us, host_t
        return self._us * 1e-6


class BridgeLink:
    """Frames over a pyserial port: send commands, match ACK/NAK by seq, bounded retries."""

    def __init__(self, port: str, baud: int = bp.DEFAULT_BAUD, timeout_s: float = 0.5, retries: int = 3) -> None:
        self.port, self.baud, self.timeout_s, self.retries = port, baud, timeout_s, retries
        self.stats = LinkStats()
        self.parser = bp.FrameParser()
        self.stats.parser = self.parser.stats
        self.clock = _McuClock()
        self._ser: serial.Serial | None = None
        self._seq = 0
        self._expect: int | None = None
        self._queue: deque[tuple[bp.Frame, float]] = deque()

    def open(self) -> None:
        try:
            ser = serial.Serial(self.port, self.baud, timeout=0.02, write_timeout=max(1.0, self.timeout_s),
                                exclusive=True)
        except serial.SerialException as e:
            code = e.errno if isinstance(e.errno, int) else getattr(e.__context__, "errno", None)
            if code == errno.ENOENT:
                raise DeviceError(f"serial port {self.port} does not exist; is the bridge plugged in? "
                                  "(list ports: python -m serial.tools.list_ports)") from None
            if code == errno.EACCES:
                raise DeviceError(f"permission denied on serial port {self.port}; {PERMISSION_HINT}") from None
            if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
                raise DeviceError(f"serial port {self.port} is in use by another program") from None
            raise DeviceError(f"cannot open serial port {self.port}: {e}") from None
        except PORT_FAULTS + (ValueError,) as e:
            raise DeviceError(f"cannot open serial port {self.port}: {e}") from None
        self._ser = ser
        self._io(lambda p: p.reset_input_buffer())

    def close(self) -> None:
        if self._ser is not None:
            try:
                with suppress(*PORT_FAULTS):  # a port that is gone has nothing left to release
                    self._ser.close()
            finally:
                self._ser = None

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def _io(self, fn: Callable[[serial.Serial], T]) -> T:
        """``fn(port)``, with a closed or lost port raised as DeviceError."""
        if self._ser is None:
            raise DeviceError(f"serial port {self.port} is not open; use `with driver:` or open()")
        try:
            return fn(self._ser)
        except PORT_FAULTS as e:  # SerialException, EIO of a hung-up pty, termios.error
            log.error("lost serial port %s: %s", self.port, e)
            raise PortLostError(f"lost serial port {self.port}: {e}") from None

    def send(self, type_: int, payload: bytes = b"") -> int:
        """Send one command frame; returns its seq."""
        self._seq = (self._seq + 1) & 0xFFFF
        frame = bp.encode_frame(type_, self._seq, 0, payload)
        self._io(lambda ser: ser.write(frame))
        return self._seq

    def next_frame(self, deadline: float) -> tuple[bp.Frame, float] | None:
        """The next good frame and its MCU time in s, or None at the (monotonic) deadline."""
        while not self._queue:
            # read before looking at the clock: a host that was descheduled still finds what came
            data = self._io(lambda ser: ser.read(max(1, ser.in_waiting)))
            for f in self.parser.feed(data):
                self._track(f)
            if not self._queue and time.monotonic() >= deadline:
                return None
        return self._queue.popleft()

    def _track(self, f: bp.Frame) -> None:
        self.stats.frames += 1
        boot = f.type == bp.RSP_BOOT
        if not boot and self._expect is not None:
            gap = (f.seq - self._expect) & 0xFFFF
            if gap < 0x8000:
                self.stats.lost_frames += gap
        self._expect = (f.seq + 1) & 0xFFFF
        self._queue.append((f, self.clock.seconds(f.ts_us, boot)))

    def command(self, cmd: int, payload: bytes = b"", timeout_s: float | None = None) -> bytes:
        """Send ``cmd`` until ACKed (at most 1 + retries times); return the ACK's data.

        Raises BridgeReset on a BOOT frame, DeviceError on a NAK or no answer.
        """
        name = bp.COMMAND_NAMES.get(cmd, hex(cmd))
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        attempts = self.retries + 1
        why = f"no answer within {timeout_s:g} s"
        for attempt in range(attempts):
            if attempt:
                self.stats.retries += 1
                log.info("bridge on %s: %s resent, attempt %d of %d (%s)", self.port, name, attempt + 1, attempts, why)
            seq = self.send(cmd, payload)
            deadline = time.monotonic() + timeout_s
            while (got := self.next_frame(deadline)) is not None:
                f = got[0]
                if f.type == bp.RSP_BOOT:
                    raise BridgeReset(self.port, f)
                if f.type not in (bp.RSP_ACK, bp.RSP_NAK) or len(f.payload) < bp.ACK_PREFIX.size:
                    continue  # samples or STREAM_END of a stream this command ended
                if bp.ACK_PREFIX.unpack_from(f.payload) != (cmd, seq):
                    continue  # a late answer to an earlier attempt
                if f.type == bp.RSP_ACK:
                    return f.payload[bp.ACK_PREFIX.size:]
                self.stats.naks += 1
                err = f.payload[3] if len(f.payload) > 3 else 0
                why = f"bridge answered NAK: {bp.ERROR_TEXT.get(err, f'error 0x{err:02x}')}"
                if err not in RETRYABLE_NAKS:
                    raise BridgeRefused(f"MPU6050 bridge on {self.port} refused {name}: "
                                        f"{bp.ERROR_TEXT.get(err, f'error 0x{err:02x}')}", err)
                break
            else:
                self.stats.timeouts += 1
        hint = {bp.ERR_I2C: "; check the MPU6050's SDA/SCL wiring, 3.3 V supply and AD0 (address 0x68)"}
        raise DeviceError(f"MPU6050 bridge on {self.port}: {name} failed after {attempts} attempts ({why})"
                          + (hint[bp.ERR_I2C] if "I2C" in why else
                             f"; check the cable, baud rate ({self.baud}) and that the bridge firmware is flashed"))

"""A thermal chamber emulated on a real pseudo-terminal, with first-order thermal physics.

:class:`ChamberPhysics` is the chamber air and the board inside it on a shared clock (the
simulated board's :class:`VirtualClock`, so an hour of soak takes milliseconds):

    d air / dt   = (target - air) / air_tau_s        target: the set point (clipped to what the
                                                      chamber can reach) or, door open, room_c
    d board / dt = (air - board) / board_tau_s       the board lags the air

Between events the target is constant and the cascade has the exact solution
``air = T + a0 e^{-t/ta}``, ``board = T + K e^{-t/ta} + (b0 - K) e^{-t/tb}``, ``K = a0 ta / (ta - tb)``.
A SimulatedBoard whose ``environment`` is this object takes ``board_c`` as its temperature,
so the simulator's temperature effect (physical offset and gain) follows the lagging board.

:class:`ChamberEmulator` answers docs/chamber-protocol.md on the master side of ``os.openpty()``.
Faults: :meth:`limit_air` (cooling or heating cannot reach beyond a temperature: the set
point is never reached), :meth:`alarm_at` (an alarm code at a clock time; the chamber
stops regulating), :meth:`open_door` (door alarm, air relaxes to room temperature),
``stall_at_s`` (the controller stops answering: a timeout).
"""
from __future__ import annotations

import math
import os
import select
import threading
from typing import Any

from ..config.schema import ChamberEmulatorSection, ChamberFaultsSection
from ..drivers.base import Clock
from ..errors import ConfigError
from ..sim.pty_server import PtyServer
from .chamber import DOOR_OPEN


class ChamberPhysics:
    """Chamber air and board temperature (C) on ``clock``: a first-order cascade (module docstring)."""

    def __init__(self, clock: Any, start_c: float = 25.0, room_c: float = 25.0, air_tau_s: float = 180.0,
                 board_tau_s: float = 300.0, door_tau_s: float = 60.0) -> None:
        self.clock = clock
        self.room_c, self.air_tau_s, self.board_tau_s, self.door_tau_s = room_c, air_tau_s, board_tau_s, door_tau_s
        self.air_c = self.board_c_state = float(start_c)
        self.t = clock.now()
        self.set_point_c = float(start_c)
        self.running = False
        self.door_open = False
        self.min_air_c, self.max_air_c = -75.0, 180.0
        self.alarms: set[int] = set()  # active alarm codes; they stay until ALARM, CLEAR
        self.lock = threading.RLock()
        self.events: list[tuple[float, str, Any]] = []  # (clock time, kind, value), applied in order

    def _target(self) -> tuple[float, float]:
        if self.door_open:
            return self.room_c, self.door_tau_s
        if not self.running:
            return self.room_c, self.air_tau_s * 4  # standby: drifts back to the room slowly
        return min(max(self.set_point_c, self.min_air_c), self.max_air_c), self.air_tau_s

    def _evolve(self, dt: float) -> None:
        if dt <= 0:
            return
        T, ta = self._target()
        tb = self.board_tau_s
        if abs(ta - tb) < 1e-6 * tb:
            ta = tb * (1 + 1e-6)  # the exact solution's K needs ta != tb
        a0, b0 = self.air_c - T, self.board_c_state - T
        k = a0 * ta / (ta - tb)
        ea, eb = math.exp(-dt / ta), math.exp(-dt / tb)
        self.air_c = T + a0 * ea
        self.board_c_state = T + k * ea + (b0 - k) * eb

    def advance(self, t: float | None = None) -> None:
        """Bring the state to clock time t (default now), applying due events on the way."""
        t = self.clock.now() if t is None else t
        with self.lock:
            while self.events and self.events[0][0] <= t:
                te, kind, value = self.events.pop(0)
                self._evolve(te - self.t)
                self.t = max(self.t, te)
                self._apply(kind, value)
            self._evolve(t - self.t)
            self.t = max(self.t, t)

    def _apply(self, kind: str, value: Any) -> None:
        if kind == "door":
            self.door_open = bool(value)
            if value:
                self.alarms.add(DOOR_OPEN)
        elif kind == "alarm":
            self.alarms.add(int(value))
            self.running = False  # a chamber alarm stops regulation

    def schedule(self, at_s: float, kind: str, value: Any) -> None:
        with self.lock:
            self.events.append((float(at_s), kind, value))
            self.events.sort(key=lambda e: e[0])

    def air_temperature_c(self) -> float:
        self.advance()
        return self.air_c

    def board_temperature_c(self) -> float:
        """The board's temperature now: what a SimulatedBoard with this environment reads."""
        self.advance()
        return self.board_c_state


class ChamberEmulator(PtyServer):
    """The ASCII chamber (docs/chamber-protocol.md) on a pseudo-terminal; ``start()`` returns its path."""

    thread_name = "chamber"

    def __init__(self, physics: ChamberPhysics, model: str = "ACCELCAL-EMU") -> None:
        self.physics = physics
        self.model = model
        self.received: list[str] = []
        self.stall_at_s: float | None = None  # from this clock time the controller answers nothing
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._master = self._slave = -1
        self.port: str | None = None

    @classmethod
    def from_section(cls, c: ChamberEmulatorSection, clock: Clock, path: str = "chamber.emulator") -> ChamberEmulator:
        """From a validated ``chamber.emulator`` section: the physics, and the faults given (a fault's
        second key without its time is refused: it would never happen)."""
        emu = cls(ChamberPhysics(clock, c.start_c, c.room_c, c.air_tau_s, c.board_tau_s, c.door_tau_s))
        f, fp = c.faults or ChamberFaultsSection(), f"{path}.faults"
        given = f.model_fields_set
        if given & {"min_air_c", "max_air_c"}:
            emu.limit_air(f.min_air_c, f.max_air_c)
        if f.alarm_at_s is not None:
            emu.alarm_at(f.alarm_at_s, f.alarm_code)
        elif "alarm_code" in given:
            raise ConfigError(f"{fp}.alarm_code: needs alarm_at_s (when the alarm goes off, clock seconds)")
        if f.door_open_at_s is not None:
            emu.open_door(f.door_open_at_s, f.door_open_s)
        elif "door_open_s" in given:
            raise ConfigError(f"{fp}.door_open_s: needs door_open_at_s (when the door opens, clock seconds)")
        if f.stall_at_s is not None:
            emu.stall_at_s = f.stall_at_s
        return emu

    # --- faults ------------------------------------------------------------------------
    def limit_air(self, min_air_c: float = -75.0, max_air_c: float = 180.0) -> None:
        """The refrigeration (heater) cannot take the air below (above) this: set points beyond are never reached."""
        with self.physics.lock:
            self.physics.advance()
            self.physics.min_air_c, self.physics.max_air_c = float(min_air_c), float(max_air_c)

    def alarm_at(self, at_s: float, code: int = 3) -> None:
        """Raise alarm ``code`` at clock time ``at_s``; the chamber stops regulating."""
        self.physics.schedule(at_s, "alarm", int(code))

    def open_door(self, at_s: float, for_s: float = 60.0) -> None:
        """Open the door at clock time ``at_s`` for ``for_s`` seconds (door alarm 1 stays until cleared)."""
        self.physics.schedule(at_s, "door", True)
        self.physics.schedule(at_s + for_s, "door", False)

    # --- protocol -----------------------------------------------------------------------
    def answer(self, line: str) -> str | None:
        """The reply to one command line (without terminator); None: a hung controller says nothing."""
        p = self.physics
        cmd = line.strip()
        self.received.append(cmd)
        if self.stall_at_s is not None and p.clock.now() >= self.stall_at_s:
            return None
        with p.lock:
            p.advance()
            head, _, arg = cmd.partition(",")
            head, arg = head.strip().upper(), arg.strip()
            if head == "TYPE?":
                return f"T,{self.model},1.0"
            if head == "TEMP?":
                return f"{p.air_c:.1f},{p.set_point_c:.1f},{p.max_air_c:.1f},{p.min_air_c:.1f}"
            if head == "MON?":
                mode = "CONSTANT" if p.running else "STANDBY"
                return f"{p.air_c:.1f},,{mode},{len(p.alarms)}"
            if head == "MODE?":
                return "CONSTANT" if p.running else "STANDBY"
            if head == "ALARM?":
                return ",".join(str(x) for x in [len(p.alarms), *sorted(p.alarms)])
            if head == "TEMP" and arg[:1].upper() == "S":
                try:
                    v = float(arg[1:])
                except ValueError:
                    return "NA:DATA NOT READY" if not arg[1:] else "NA:PARAMETER ERR"
                if not (-100.0 <= v <= 300.0) or v != v:
                    return "NA:DATA OUT OF RANGE"
                p.set_point_c = v
                return f"OK:{cmd}"
            if head == "MODE" and arg.upper() in ("CONSTANT", "STANDBY", "OFF"):
                if arg.upper() == "CONSTANT" and p.alarms - {DOOR_OPEN}:
                    return "NA:ALARM ACTIVE"
                p.running = arg.upper() == "CONSTANT"
                return f"OK:{cmd}"
            if head == "ALARM" and arg.upper() == "CLEAR":
                p.alarms.clear()
                if p.door_open:
                    p.alarms.add(DOOR_OPEN)  # still open: the alarm comes straight back
                return f"OK:{cmd}"
            return "NA:COMMAND ERR"

    # --- serving --------------------------------------------------------------------------
    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self._master], [], [], 0.05)
                if not r:
                    continue
                buf += os.read(self._master, 4096)
            except OSError:
                continue
            while b"\n" in buf or b"\r" in buf:
                cut = min(i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0)
                line, buf = buf[:cut], buf[cut + 1:]
                if line.strip():
                    reply = self.answer(line.decode("ascii", "replace"))
                    if reply is not None:
                        os.write(self._master, reply.encode("ascii") + b"\r\n")


class AcceleratedClock:
    """Wall time run ``speed`` times faster (``accelcal emulate chamber --speed 60``: a minute a second)."""

    def __init__(self, speed: float = 1.0) -> None:
        import time

        self._time, self.speed, self._t0 = time, float(speed), time.monotonic()
        self.realtime = True

    def now(self) -> float:
        return (self._time.monotonic() - self._t0) * self.speed

    def sleep(self, dt: float) -> None:
        if dt > 0:
            self._time.sleep(dt / self.speed)

"""Thermal chamber drivers: the :class:`Chamber` interface and one real implementation.

:class:`AsciiChamber` speaks the line-based ASCII command set of ESPEC-style chambers
(``TEMP?``, ``TEMP, S<c>``, ``MODE, CONSTANT``, ``MON?``, ``ALARM?``; docs/chamber-protocol.md)
through pyvisa with the pure-Python pyvisa-py backend, so the same code addresses a
chamber on a serial line (``ASRL/dev/ttyUSB2::INSTR``, or a bare device path) or on
Ethernet (``TCPIP::10.0.0.5::5025::SOCKET``).  The emulator (instruments/chamber_emulator.py)
answers on a pseudo-terminal; this module never imports it (the factory in
``accelcal_station.instruments`` builds it and hands the port in).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

from ..errors import ConfigError, DeviceError

if TYPE_CHECKING:
    from pyvisa.resources import MessageBasedResource

# the alarm codes this station names (docs/chamber-protocol.md); a chamber's manual may number others
ALARM_NAMES = {1: "door open", 2: "temperature high limit", 3: "refrigeration fault", 4: "heater fault",
               5: "temperature low limit"}
DOOR_OPEN = 1
MODES = ("CONSTANT", "STANDBY", "OFF")


class ChamberError(DeviceError):
    """The chamber did not answer, answered nonsense, or refused a command."""

    instrument = "chamber"  # a station fault (station/station_fault.py), never a board's verdict


@dataclass(frozen=True)
class ChamberStatus:
    """One look at the chamber: air temperature (C), set point (C), mode and active alarm codes."""

    air_c: float
    set_point_c: float | None
    mode: str
    alarms: tuple[int, ...] = ()

    @property
    def door_open(self) -> bool:
        return DOOR_OPEN in self.alarms

    def alarm_text(self) -> str:
        return ", ".join(f"{c} ({ALARM_NAMES.get(c, 'unknown alarm')})" for c in self.alarms)


class Chamber(ABC):
    """A temperature chamber: set point, air temperature, status and alarms; a context manager."""

    name = "chamber"
    min_c: float = -70.0
    max_c: float = 180.0

    def __init__(self) -> None:
        self.on_close: list[Callable[[], None]] = []  # e.g. stop an emulator the factory started

    @abstractmethod
    def open(self) -> None: ...

    def close(self) -> None:
        while self.on_close:
            self.on_close.pop()()

    def __enter__(self) -> Chamber:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @abstractmethod
    def identify(self) -> str: ...

    @abstractmethod
    def set_point(self, temp_c: float) -> None:
        """Set the constant-mode set point and run (MODE, CONSTANT)."""

    @abstractmethod
    def status(self) -> ChamberStatus: ...

    @abstractmethod
    def standby(self) -> None: ...

    @abstractmethod
    def clear_alarms(self) -> None: ...

    def check_set_point(self, temp_c: float, path: str = "set point") -> float:
        t = float(temp_c)
        if not (self.min_c <= t <= self.max_c):
            raise ConfigError(f"{path}: {t:g} C out of the chamber's range; "
                              f"allowed {self.min_c:g} to {self.max_c:g} C")
        return t


def visa_resource(port: str) -> str:
    """A VISA resource name for a port: device paths become ASRL<path>::INSTR, host:port a TCP socket."""
    if "::" in port:
        return port
    if port.startswith("/") or port.upper().startswith("COM"):
        return f"ASRL{port}::INSTR"
    host, sep, tcp = port.rpartition(":")
    if sep and tcp.isdigit():
        return f"TCPIP::{host}::{tcp}::SOCKET"
    raise ConfigError(f"chamber.port: {port!r}; allowed: a serial device path (/dev/ttyUSB2, COM3), "
                      "host:port or a VISA resource name (the emulated chamber: chamber.type: emulated)")


def require_pyvisa(where: str = "chamber", visa_library: str = "@py") -> None:
    """pyvisa (and pyvisa-py for the ``@py`` backend) are the optional ``chamber`` extra: refuse
    in one line, naming it."""
    try:
        import pyvisa  # noqa: F401
        if visa_library == "@py":
            import pyvisa_py  # noqa: F401
    except ImportError:
        raise ConfigError(f"{where}: the thermal chamber needs pyvisa and pyvisa-py, not installed; install the "
                          "extra: pip install 'accelcal-station[chamber]'") from None


class AsciiChamber(Chamber):
    """An ESPEC-style ASCII chamber over pyvisa (serial or TCP)."""

    name = "ascii"

    def __init__(self, port: str, baud: int = 9600, timeout_s: float = 1.0, retries: int = 2,
                 min_c: float = -70.0, max_c: float = 180.0, visa_library: str = "@py") -> None:
        super().__init__()
        self.visa_library = visa_library  # pyvisa's backend (config chamber.visa_library)
        self.port, self.resource_name = port, visa_resource(port)
        self.baud, self.timeout_s, self.retries = baud, timeout_s, retries
        self.min_c, self.max_c = min_c, max_c
        self._res: MessageBasedResource | None = None
        self._sp: float | None = None

    def open(self) -> None:
        import pyvisa  # lazily: only stations with a chamber need it

        try:
            rm = pyvisa.ResourceManager(self.visa_library)
            # ASRL INSTR and TCPIP SOCKET resources are message based (query, read/write terminations);
            # a serial one also takes the baud rate
            timeout_ms = int(self.timeout_s * 1000)
            if self.resource_name.startswith("ASRL"):
                res = rm.open_resource(self.resource_name, read_termination="\r\n", write_termination="\r\n",
                                       timeout=timeout_ms, baud_rate=self.baud)
            else:
                res = rm.open_resource(self.resource_name, read_termination="\r\n", write_termination="\r\n",
                                       timeout=timeout_ms)
            self._res = cast("MessageBasedResource", res)
        except (pyvisa.Error, OSError, ValueError) as e:
            raise ChamberError(f"chamber on {self.port}: cannot open ({e})") from None
        self.identify()

    def close(self) -> None:
        if self._res is not None:
            with suppress(Exception):  # closing a port whose device vanished must not hide the real error
                self._res.close()
            self._res = None
        super().close()

    def query(self, command: str) -> str:
        """Send one command line and return its answer; timeouts are retried, then ChamberError."""
        import pyvisa

        if self._res is None:
            raise ChamberError(f"chamber on {self.port} is not open")
        why = ""
        for _ in range(self.retries + 1):
            try:
                answer = self._res.query(command).strip()
            except pyvisa.errors.VisaIOError as e:
                why = "no answer" if e.error_code == pyvisa.constants.StatusCode.error_timeout else str(e)
                continue
            except (OSError, UnicodeDecodeError) as e:
                raise ChamberError(f"chamber on {self.port}: {command!r} failed ({e})") from None
            if answer.startswith("NA:"):
                raise ChamberError(f"chamber on {self.port} refused {command!r}: {answer[3:].strip()}")
            return answer
        raise ChamberError(f"chamber on {self.port}: {why} to {command!r} within {self.timeout_s:g} s "
                           f"({self.retries + 1} attempts)")

    def _fields(self, command: str, n: int) -> list[str]:
        parts = [p.strip() for p in self.query(command).split(",")]
        if len(parts) < n:
            raise ChamberError(f"chamber on {self.port}: answer to {command!r} has {len(parts)} fields; expected {n}")
        return parts

    def _float(self, text: str, command: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise ChamberError(f"chamber on {self.port}: {text!r} in the answer to {command!r} "
                               "is not a number") from None
        if v != v or abs(v) > 1e4:
            raise ChamberError(f"chamber on {self.port}: {text!r} in the answer to {command!r} is not a temperature")
        return v

    def identify(self) -> str:
        return self.query("TYPE?")

    def set_point(self, temp_c: float) -> None:
        t = self.check_set_point(temp_c)
        self.query(f"TEMP, S{t:.1f}")
        self.query("MODE, CONSTANT")
        self._sp = t

    def standby(self) -> None:
        self.query("MODE, STANDBY")

    def clear_alarms(self) -> None:
        self.query("ALARM, CLEAR")

    def alarms(self) -> tuple[int, ...]:
        parts = self._fields("ALARM?", 1)
        try:
            codes = tuple(int(p) for p in parts if p)
        except ValueError:
            raise ChamberError(f"chamber on {self.port}: alarm list {parts!r} is not numbers") from None
        if codes[0] != len(codes) - 1:
            raise ChamberError(f"chamber on {self.port}: alarm count {codes[0]} but {len(codes) - 1} codes")
        return codes[1:]

    def status(self) -> ChamberStatus:
        """MON? (air, humidity, mode, alarm count) and, when any alarm is up, ALARM? for the codes;
        the set point is the one this driver sent (TEMP? reads it back, at one more query per poll)."""
        f = self._fields("MON?", 4)
        air = self._float(f[0], "MON?")
        mode = f[2].upper()
        if mode not in MODES:
            raise ChamberError(f"chamber on {self.port}: mode {f[2]!r}; expected one of {', '.join(MODES)}")
        n_alarms = int(self._float(f[3], "MON?"))
        return ChamberStatus(air, self._sp, mode, self.alarms() if n_alarms else ())

"""A thermal plan (``thermal:`` of a station config, AN4399 section 9), the soak rule that
waits for the chamber and the board at each set point, and the chamber's faults.

The soak rule: the chamber air is within ``band_c`` of the set point and the board
temperature (the chip's die temperature; the chamber air for a chip without a sensor, the
MMA8451) has stayed within ``tolerance_c`` (max - min) for ``hold_s``; else ``timeout_s``.
"""
from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config.schema import SoakSection, ThermalSection, validate
from ..drivers.base import Clock
from ..errors import AccelcalError, ConfigError
from ..instruments.chamber import Chamber, ChamberStatus


class ChamberFault(AccelcalError):
    """The thermal environment failed the plan: a recorded FAIL, not a crash.  ``kind`` says which."""

    def __init__(self, kind: str, message: str, soak_s: float = 0.0) -> None:
        super().__init__(message)
        self.kind = kind
        self.soak_s = soak_s  # a soak that timed out: the time it took, still counted as soak


@dataclass(frozen=True)
class SoakRule:
    """``thermal.soak``: when a set point counts as soaked (module docstring)."""

    tolerance_c: float = 0.2
    band_c: float = 2.0
    hold_s: float = 300.0
    timeout_s: float = 5400.0
    poll_s: float = 10.0


@dataclass(frozen=True)
class ThermalPlan:
    """``thermal:`` of a station config, checked (errors name the key path)."""

    set_points_c: tuple[float, ...]
    verify_set_points_c: tuple[float, ...]
    method: str
    soak: SoakRule
    capture_band_c: float
    reference_c: float  # the single-temperature calibration "without the table" is the one nearest this
    temperature_u_c: float = 0.5  # standard uncertainty of a set point's assigned temperature (its budget)

    @classmethod
    def from_config(cls, d: Any, model: str, path: str = "thermal") -> ThermalPlan:
        """Keys, types and ranges from the schema (config/schema.py ThermalSection); here what
        depends on several values."""
        t = validate(d, ThermalSection, path)
        assert isinstance(t, ThermalSection)
        return cls.from_section(t, model, path)

    @classmethod
    def from_section(cls, t: ThermalSection, model: str, path: str = "thermal") -> ThermalPlan:
        """From a validated ``thermal`` section: the checks that depend on several values."""
        sps = _temps(t.set_points_c, "set_points_c", path)
        if len(sps) < 3:
            raise ConfigError(f"{path}.set_points_c: {len(sps)} set points; allowed: 3 or more")
        if min(np.diff(sorted(sps))) < 5.0:
            raise ConfigError(f"{path}.set_points_c: {sps}; set points must be 5 C or more apart")
        ver = _temps(t.verify_set_points_c, "verify_set_points_c", path)
        for v in ver:
            if not sps[0] < v < sps[-1] or min(abs(v - s) for s in sps) < 2.5:
                raise ConfigError(f"{path}.verify_set_points_c: {v:g} C; allowed: between {sps[0]:g} and "
                                  f"{sps[-1]:g} C and 2.5 C or more from every calibration set point")
        if model == "9":
            raise ConfigError(f"{path}: model 9 has no pose references to verify against; "
                              "allowed plan.model: 6, 12, 15")
        soak = SoakRule(**(t.soak or SoakSection()).model_dump())
        return cls(tuple(sps), tuple(ver), t.method, soak, t.capture_band_c, t.reference_c, t.temperature_u_c)

    def visits(self) -> list[tuple[float, str]]:
        """(set point, 'calibrate' | 'verify') in ascending temperature: the chamber travels one way."""
        return sorted([(t, "calibrate") for t in self.set_points_c] + [(t, "verify") for t in self.verify_set_points_c])


def _temps(v: list[float], key: str, path: str) -> list[float]:
    """A list of temperatures, each once, ascending (their ranges: the schema's)."""
    if not v:
        raise ConfigError(f"{path}.{key}: {v!r}; allowed: a list of temperatures in C")
    if len(set(v)) != len(v):
        raise ConfigError(f"{path}.{key}: {v}; each temperature once")
    return sorted(float(x) for x in v)


def soak_until(rule: SoakRule, sp: float, chamber: Chamber, clock: Clock,
               read: Callable[[ChamberStatus], np.ndarray],
               check_alarms: Callable[[ChamberStatus, str], None],
               echo: Callable[[str], None]) -> tuple[float, np.ndarray, float, float]:
    """Wait for the soak rule at ``sp`` (module docstring) over every temperature ``read(status)`` gives
    (one per board: the rule holds when each board's max - min over the hold is within tolerance).

    Returns (soak time, the temperatures, the air temperature, the time soaked), all on ``clock``;
    ChamberFault on timeout or alarm.
    """
    t0 = next_note = clock.now()
    window: list[tuple[float, np.ndarray]] = []
    while True:
        st = chamber.status()
        check_alarms(st, f"during the soak at {sp:g} C")
        temps = np.asarray(read(st), dtype=float)
        now = clock.now()
        if abs(st.air_c - sp) > rule.band_c:
            window = []
        else:
            window.append((now, temps))
            while np.max(np.ptp(np.stack([x for _, x in window]), axis=0)) > rule.tolerance_c:
                window.pop(0)
            if now - window[0][0] >= rule.hold_s:
                return now - t0, temps, st.air_c, now
        if now >= next_note + 600.0:  # a soak takes most of an hour: say where it is every 10 minutes
            next_note = now
            held = now - window[0][0] if window else 0.0
            echo(f"  soaking {now - t0:.0f} s: air {st.air_c:.1f} C, board {_span(temps)} C, stable for {held:.0f} s")
        if now - t0 >= rule.timeout_s:
            if abs(st.air_c - sp) > rule.band_c:
                raise ChamberFault("set point not reached", f"set point {sp:g} C not reached within "
                                   f"{rule.timeout_s:g} s (air {st.air_c:.1f} C, band +-{rule.band_c:g} C)", now - t0)
            raise ChamberFault("not stable", f"board temperature not stable within {rule.tolerance_c:g} C for "
                               f"{rule.hold_s:g} s at {sp:g} C within {rule.timeout_s:g} s (board {_span(temps)} C)",
                               now - t0)
        clock.sleep(rule.poll_s)


def _span(temps: np.ndarray) -> str:
    return f"{temps[0]:.2f}" if len(temps) == 1 else f"{temps.min():.2f}..{temps.max():.2f}"


class WallClock:
    """Real time, for a station with real hardware (the simulated board brings its virtual clock)."""

    realtime = True

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt: float) -> None:
        if dt > 0:
            time.sleep(dt)




def check_alarms(st: ChamberStatus, context: str) -> None:
    """ChamberFault when the chamber's door is open, an alarm is up or it left constant mode."""
    if st.door_open:
        raise ChamberFault("door open", f"door opened {context} (alarm {st.alarm_text()})")
    if st.alarms:
        raise ChamberFault("alarm", f"alarm {st.alarm_text()} {context}")
    if st.mode != "CONSTANT":
        raise ChamberFault("stopped", f"the chamber left constant mode ({st.mode}) {context}")


def standby(chamber: Chamber) -> None:
    """Leave the chamber safe; the original error is what matters."""
    with contextlib.suppress(AccelcalError):
        chamber.standby()

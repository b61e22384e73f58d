"""A raw log's time axis: sample times in seconds and the sample rate, from its time column (its unit
named or judged from the step), --rate, a rate stated in its preamble, or sample numbers."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import DataError
from .log_info import LogInfo

RATE_LIMITS_HZ = (1e-3, 1e7)
JUDGED_RATE_HZ = (1.0, 1e5)  # a time unit guessed from the step must give a logger's rate


def _judge_time_unit(dt: float, info: LogInfo) -> float:
    """Seconds per unit of a time column whose name gives no unit."""
    scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
    stated = info.stated_rate_hz
    if info.time_unit is None:
        if stated:  # the unit that makes the step match the stated rate
            info.time_unit = min(scale, key=lambda u: abs(math.log(dt * scale[u] * stated)))
            info.time_unit_judged = False
            info.time_unit_reason = f"its step {dt:g} matches the stated {info.stated_rate_hz:g} Hz"
        else:
            info.time_unit = "s" if dt < 1 else "ms" if dt < 50 else "us"
            info.time_unit_judged = True
            info.time_unit_reason = f"judged from its median step {dt:g} (not named in the header)"
    return scale[info.time_unit]



def time_axis(path: Path, t: np.ndarray | None, n: int, rate_hz: float | None, info: LogInfo, lines_arr: np.ndarray,
               tlabel: str) -> tuple[np.ndarray, float | None]:
    """Sample times in seconds and the rate: from the time column, --rate, a stated rate, or sample numbers."""
    if t is not None:
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size:
            raise DataError(f"{path}: line {lines_arr[back[0] + 1]}, {tlabel}: time goes backwards; "
                            "allowed: non-decreasing times")
        dt = float(np.median(np.diff(t)))
        if not dt > 0:
            raise DataError(f"{path}: {tlabel}: time does not advance; allowed: times in s, ms or us")
        per = _judge_time_unit(dt, info)
        t, rate = t * per, 1.0 / (dt * per)
        info.rate_source = f"time column {info.axis_names.get('t', 't')!r} in {info.time_unit}"
    elif rate_hz is not None:
        t, rate = np.arange(n) / rate_hz, float(rate_hz)
        info.rate_source = "--rate"
    elif info.stated_rate_hz is not None:
        if not RATE_LIMITS_HZ[0] <= info.stated_rate_hz <= RATE_LIMITS_HZ[1]:
            raise DataError(f"{path}: {info.rate_source}: {info.stated_rate_hz:g} Hz; allowed: {RATE_LIMITS_HZ[0]:g} "
                            f"to {RATE_LIMITS_HZ[1]:g} Hz (give --rate HZ)")
        t, rate = np.arange(n) / info.stated_rate_hz, info.stated_rate_hz
    else:
        t, rate = np.arange(n, dtype=float), None
        info.rate_source = None
    lo, hi = JUDGED_RATE_HZ if info.time_unit_judged else RATE_LIMITS_HZ
    if rate is not None and not lo <= rate <= hi:
        how = f"in {info.time_unit}, {info.time_unit_reason}" if info.time_unit else ""
        raise DataError(f"{path}: the time column ({how}) gives {rate:g} Hz; allowed: {lo:g} to {hi:g} Hz "
                        "(name its unit in the header: time_s, time_ms, time_us or time_ns)")
    return t, rate


def check_rate(rate_hz: float | None) -> None:
    """--rate within RATE_LIMITS_HZ (a denormal or huge rate would overflow every time axis)."""
    if rate_hz is not None and not (math.isfinite(rate_hz) and RATE_LIMITS_HZ[0] <= rate_hz <= RATE_LIMITS_HZ[1]):
        raise DataError(f"--rate {rate_hz!r}; allowed: a sample rate from {RATE_LIMITS_HZ[0]:g} to "
                        f"{RATE_LIMITS_HZ[1]:g} Hz")

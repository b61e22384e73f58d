"""Repeated samples and the value grid of logged samples, as a host captures them.

Repeats: a host that polls faster than the chip updates logs each conversion several times
(a sample equal to the previous one on every axis).  Repeats add no information: the noise
of a pose mean is std / sqrt(distinct samples), and the noise and the value grid are judged
on the distinct samples.  A log repeats when more than REPEAT_MIN of its consecutive samples
do: the chance that three noisy axes all repeat is the product of three per-axis chances
(each well below 1/2 once the noise spans a few LSB), so a noisy log that does not repeat sits
far below it; a noiseless one (simulated) repeats all the time and has no noise to misjudge.

Value grid: the samples of an ADC sit on multiples of its LSB; printed with few decimals
(m/s^2 or g with 6 decimals) each value is off the grid by up to half a unit of its last
decimal.  ``value_grid`` finds the step with that rounding allowed: the smallest gap between
distinct values is the step less at most two roundings; the step is refined by least squares
over every value's grid index, and every value must lie within the rounding (and 1e-9 of
its size) of its grid point.  Integers (counts) are judged exactly (gcd of the gaps).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

REPEAT_MIN = 0.2  # fraction of consecutive samples equal on every axis above which a log "repeats"
MAX_GRID_VALUES = 1 << 16  # distinct values judged (a 16-bit axis has at most this many)


def repeated(xyz: ArrayLike) -> np.ndarray:
    """(N,) bool: the sample equals the previous one on every axis (the first never does)."""
    x = np.asarray(xyz, dtype=float)
    out = np.zeros(len(x), dtype=bool)
    if len(x) > 1:
        out[1:] = np.all(x[1:] == x[:-1], axis=1)
    return out


def repeat_fraction(xyz: ArrayLike) -> float:
    """Fraction of consecutive sample pairs that repeat (0 for fewer than two samples)."""
    r = repeated(xyz)
    return float(r[1:].mean()) if len(r) > 1 else 0.0


def distinct_samples(xyz: ArrayLike) -> np.ndarray:
    """(N,) bool: the samples to judge noise and grid on: all of them unless the log repeats
    (repeat_fraction above REPEAT_MIN), else the first of each run of equal samples."""
    r = repeated(xyz)
    if len(r) < 2 or r[1:].mean() <= REPEAT_MIN:
        return np.ones(len(r), dtype=bool)
    return ~r


def value_grid(values: ArrayLike, decimals: int | None = None) -> float:
    """The grid step (LSB) the values sit on, in their units, allowing the rounding of ``decimals``
    printed decimals (None: exact to 1e-6 of the step); 0 when they sit on no grid."""
    v = np.unique(np.asarray(values, dtype=float).ravel())
    v = v[np.isfinite(v)]
    if len(v) < 2 or len(v) > MAX_GRID_VALUES:
        return 0.0
    if np.all(v == np.round(v)) and (decimals is None or decimals == 0):
        return float(np.gcd.reduce(np.diff(v).astype(np.int64)))
    gaps = np.diff(v)
    rnd = 0.5 * 10.0 ** -decimals if decimals is not None else 0.0
    first = float(gaps.min())
    near = gaps[gaps <= first + 4 * rnd + 1e-12 * float(np.max(np.abs(v)))]
    step = float(np.median(near))
    if not step > 0 or step <= 2 * rnd:  # the rounding is as coarse as the grid: no grid to see
        return 0.0
    a, step = _refine(v, float(v[0]), step, 4 * rnd + 1e-12 * float(np.max(np.abs(v))), rnd)
    k = np.round((v - a) / step)
    tol = rnd + 1e-9 * float(np.max(np.abs(v))) + (1e-6 * step if decimals is None else 0.0)
    off = np.abs(v - (a + k * step))
    return float(step) if math.isfinite(step) and step > 0 and np.all(off <= tol) else 0.0


def _refine(v: np.ndarray, a: float, step: float, err: float, rnd: float) -> tuple[float, float]:
    """(origin, step) of the grid by least squares over the values whose grid index the current
    step's uncertainty ``err`` still fixes (within a quarter step), widened as the fit narrows it:
    a step known to 1e-4 of itself fixes indices only up to some 2,500 steps away."""
    for _ in range(32):
        reach = 0.25 * step / max(err, 1e-300)
        use = np.abs(v - a) / step <= reach
        k = np.round((v[use] - a) / step)
        if np.ptp(k) < 1:
            break
        A = np.column_stack([np.ones_like(k), k])
        (a, step), *_ = np.linalg.lstsq(A, v[use], rcond=None)
        err = max(2.0 * rnd / float(np.ptp(k)), 1e-15 * abs(step))
        if use.all():
            break
    return float(a), float(step)


__all__ = ["REPEAT_MIN", "distinct_samples", "repeat_fraction", "repeated", "value_grid"]

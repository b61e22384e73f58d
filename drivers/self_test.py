"""The chip's built-in self-test: what a driver returns and how it is judged.

A MEMS accelerometer's self-test applies an electrostatic force to the proof mass; the output
change (self-test on minus off, averaged) shows that the mass moves and the signal chain works.
The fit alone cannot see a sensing element that reads plausible static values but responds weakly
(a damaged spring or comb).  Limits come from each chip's data sheet (docs/self-test.md):

- MMA8451Q (data sheet Rev. 10.3, Table 4 "Self-test output change", +-4 g, 14-bit: X +181, Y +255,
  Z +1680 LSB typical; NXP's stated screen: at least 50 LSB at +-4 g on every axis, at most 1000 on
  X and Y and 6000 on Z): judged on the change in g against [min, max] per axis.
- MPU-6050 (product specification rev 3.4, section 6.1; register map rev 4.2, section 4.1): the
  change is compared with the factory trim FT computed from the SELF_TEST registers; (STR - FT)/FT
  must lie within +-14 %.

A response within noise on every axis is named for what it is: the self-test did nothing.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class AxisSelfTest:
    """One axis: the output change and what the data sheet requires of it."""

    axis: str
    change_counts: float  # self-test on minus off, at the range it was measured (counts)
    change_g: float
    low: float  # limits, in ``unit``
    high: float
    unit: Literal["g", "fraction_of_factory_trim"]
    value: float  # the judged value, in ``unit``
    ok: bool
    sem_g: float  # standard error of change_g (the two averages' noise)
    factory_trim_counts: float | None = None  # MPU-6050: FT the change is compared with (counts)

    def to_json(self) -> dict[str, object]:
        value = self.value if np.isfinite(self.value) else None  # no factory trim: nothing to compare with
        return {"axis": self.axis, "value": value, "unit": self.unit, "low": self.low, "high": self.high,
                "ok": self.ok, "change_counts": self.change_counts, "change_g": self.change_g, "sem_g": self.sem_g}


@dataclass(frozen=True)
class SelfTestResult:
    """The self-test of one chip: per axis, and the verdict with its reason."""

    chip: str
    axes: tuple[AxisSelfTest, ...]
    n: int  # samples averaged in each state
    range_g: int  # range it was measured at
    source: str  # where the limits come from

    @property
    def no_effect(self) -> bool:
        """Every axis's change within 4 standard errors of zero: the self-test did nothing."""
        return all(abs(a.change_g) <= 4.0 * a.sem_g for a in self.axes)

    @property
    def ok(self) -> bool:
        return all(a.ok for a in self.axes) and not self.no_effect

    def reason(self) -> str | None:
        """The acceptance reason text (None when it passes)."""
        if self.no_effect:
            d = ", ".join(f"{a.axis} {a.change_g * 1e3:+.1f} mg" for a in self.axes)
            return f"self-test did nothing: output change {d}, all within noise (the self-test bit has no effect)"
        bad = [a for a in self.axes if not a.ok]
        if not bad:
            return None
        return "; ".join(_axis_text(a) for a in bad)

    def to_json(self) -> dict[str, object]:
        return {"chip": self.chip, "ok": self.ok, "no_effect": self.no_effect, "n": self.n, "range_g": self.range_g,
                "source": self.source, "reason": self.reason(), "axes": [a.to_json() for a in self.axes]}


def _axis_text(a: AxisSelfTest) -> str:
    if a.unit == "g":
        return (f"self-test {a.axis}: output change {a.change_g * 1e3:+.1f} mg outside "
                f"[{a.low * 1e3:.1f}, {a.high * 1e3:.1f}] mg")
    return (f"self-test {a.axis}: response {a.change_g * 1e3:+.1f} mg is {a.value * 100:+.1f} % from the factory trim; "
            f"allowed {a.low * 100:+.0f} % to {a.high * 100:+.0f} %")


def judge_in_g(chip: str, change_counts: np.ndarray, sem_counts: np.ndarray, counts_per_g: float,
               low_g: np.ndarray, high_g: np.ndarray, n: int, range_g: int, source: str) -> SelfTestResult:
    """Per axis: the change in g within [low_g, high_g] (MMA8451Q style limits)."""
    g = np.asarray(change_counts, float) / counts_per_g
    sem = np.asarray(sem_counts, float) / counts_per_g
    axes = tuple(AxisSelfTest(AXES[i], float(change_counts[i]), float(g[i]), float(low_g[i]), float(high_g[i]), "g",
                              float(g[i]), bool(low_g[i] <= g[i] <= high_g[i]), float(sem[i])) for i in range(3))
    return SelfTestResult(chip, axes, n, range_g, source)


def judge_against_trim(chip: str, change_counts: np.ndarray, sem_counts: np.ndarray, counts_per_g: float,
                       factory_trim_counts: np.ndarray, tolerance: float, n: int, range_g: int,
                       source: str) -> SelfTestResult:
    """Per axis: (STR - FT) / FT within +-tolerance (MPU-6050 product specification 6.1)."""
    ft = np.asarray(factory_trim_counts, float)
    str_ = np.asarray(change_counts, float)
    frac = np.where(ft > 0, (str_ - ft) / np.where(ft > 0, ft, 1.0), np.inf)
    sem = np.asarray(sem_counts, float) / counts_per_g
    axes = tuple(AxisSelfTest(AXES[i], float(str_[i]), float(str_[i] / counts_per_g), -tolerance, tolerance,
                              "fraction_of_factory_trim", float(frac[i]), bool(abs(frac[i]) <= tolerance),
                              float(sem[i]), float(ft[i])) for i in range(3))
    return SelfTestResult(chip, axes, n, range_g, source)


def with_limits(result: SelfTestResult, low_g: tuple[float, ...] | None = None,
                high_g: tuple[float, ...] | None = None, tolerance: float | None = None,
                source: str = "acceptance") -> SelfTestResult:
    """``result`` judged again with the limits a station's config overrides (None: the data sheet's kept).

    ``low_g``/``high_g`` apply to limits in g (MMA8451Q), ``tolerance`` to limits relative to the factory
    trim (MPU-6050); the other kind is ignored.  ``source`` names where the new limits come from."""
    axes = []
    changed = False
    for i, a in enumerate(result.axes):
        if a.unit == "g" and (low_g is not None or high_g is not None):
            lo = a.low if low_g is None else float(low_g[i])
            hi = a.high if high_g is None else float(high_g[i])
            axes.append(replace(a, low=lo, high=hi, ok=bool(lo <= a.value <= hi)))
            changed = True
        elif a.unit == "fraction_of_factory_trim" and tolerance is not None:
            t = float(tolerance)
            axes.append(replace(a, low=-t, high=t, ok=bool(abs(a.value) <= t)))
            changed = True
        else:
            axes.append(a)
    if not changed:
        return result
    return replace(result, axes=tuple(axes), source=f"{result.source}; limits overridden by {source}")

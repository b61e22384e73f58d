"""Charts as plain numbers for inline SVG (templates draw them; nothing is fetched).

A run chart puts each run at its start time (a time axis in UTC) and draws the acceptance
limit that run was judged by, as a step line, so a change of limits shows as a step; each
run is flagged against its own limit, and the Shewhart individuals limits (lot/report.py
``control_limits``: centre = mean, mean +- 3 sigma, sigma = mean moving range / 1.128) are
drawn beside it.  Value axes use "nice numbers" (Heckbert, Graphics Gems I, 1990: steps of
1, 2 or 5 x 10^k), time axes steps of whole minutes, hours or days; a figure that cannot be
negative (a largest |x|, an RMS) has its axis start at zero.  A residual chart shows one
run's residuals per pose and axis.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np

from ..lot.report import control_limits

W, H, PAD_L, PAD_R, PAD_T, PAD_B = 560.0, 210.0, 56.0, 12.0, 22.0, 40.0
TIME_STEPS_S = (60, 300, 900, 1800, 3600, 2 * 3600, 3 * 3600, 6 * 3600, 12 * 3600, 86400, 2 * 86400, 7 * 86400,
                14 * 86400, 30 * 86400, 91 * 86400, 365 * 86400)


@dataclass
class Line:
    y: float
    label: str
    kind: str  # centre, sigma, limit, zero


@dataclass
class RunPoint:
    """One run on a run chart: start time (unix s), value, the limits it was judged by (None: none)."""

    t: float
    value: float
    hi: float | None
    lo: float | None
    label: str


@dataclass
class Chart:
    """One chart in SVG user units (W x H): points, horizontal lines, limit steps, both axes."""

    title: str
    unit: str
    points: list[tuple[float, float, str, str]] = field(default_factory=list)  # x, y, kind (""/out/sigma), tooltip
    lines: list[Line] = field(default_factory=list)
    steps: list[str] = field(default_factory=list)  # SVG polyline points of the per-run limit (one per stretch)
    bars: list[tuple[float, float, float, float, str]] = field(default_factory=list)  # x, y, w, h, axis
    ticks: list[tuple[float, str]] = field(default_factory=list)  # y, label
    xlabels: list[tuple[float, str]] = field(default_factory=list)
    xtitle: str = ""
    note: str = ""
    width: float = W
    height: float = H

    @property
    def path(self) -> str:
        return " ".join(f"{x:.1f},{y:.1f}" for x, y, _, _ in self.points)


def nice_step(span: float, n: int = 5) -> float:
    """The 1, 2 or 5 x 10^k step giving about ``n`` ticks over ``span`` (Heckbert's nice numbers)."""
    raw = max(span, 1e-300) / max(1, n - 1)
    k = math.floor(math.log10(raw))
    f = raw / 10.0 ** k
    return (1.0 if f < 1.5 else 2.0 if f < 3.5 else 5.0 if f < 7.5 else 10.0) * 10.0 ** k


def nice_axis(lo: float, hi: float, n: int = 5, floor_zero: bool = False) -> tuple[float, float, list[float], int]:
    """Axis bounds on whole steps around [lo, hi], its ticks and the decimals a tick label needs."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        lo, hi = 0.0, 1.0
    if hi - lo < 1e-12 * max(1.0, abs(hi)):
        pad = abs(hi) * 0.1 or 1.0
        lo, hi = lo - pad, hi + pad
    if floor_zero and lo >= 0:
        lo = 0.0
    step = nice_step(hi - lo, n)
    a, b = math.floor(lo / step) * step, math.ceil(hi / step) * step
    if floor_zero and a < 0 <= lo:
        a = 0.0
    ticks = [a + i * step for i in range(int(round((b - a) / step)) + 1)]
    return a, b, ticks, max(0, -math.floor(math.log10(step)))


def tick_label(v: float, decimals: int) -> str:
    s = f"{v:.{decimals}f}"
    return "0" if float(s) == 0 else s


def time_axis(t0: float, t1: float, n: int = 6) -> tuple[float, float, list[tuple[float, str]]]:
    """A time axis over [t0, t1] (unix s): padded bounds and ticks on whole UTC minutes/hours/days,
    labelled HH:MM (with the date where the day changes) or YYYY-MM-DD."""
    if t1 - t0 < 1800.0:  # one run, or runs minutes apart: half an hour around them, so ticks are drawn
        t0, t1 = (t0 + t1) / 2 - 900.0, (t0 + t1) / 2 + 900.0
    span = t1 - t0
    step = next((s for s in TIME_STEPS_S if span / s <= n), TIME_STEPS_S[-1])
    a, b = t0 - 0.04 * span, t0 + 1.04 * span
    ticks, day = [], None
    t = math.ceil(a / step) * step
    while t <= b:
        d = datetime.fromtimestamp(t, UTC)
        if step >= 86400:
            label = f"{d:%Y-%m-%d}"
        else:
            label = f"{d:%H:%M}" if d.date() == day else f"{d:%m-%d %H:%M}"
            day = d.date()
        ticks.append((float(t), label))
        t += step
    return a, b, ticks


def _y(v: float, lo: float, hi: float, h: float = H) -> float:
    return PAD_T + (h - PAD_T - PAD_B) * (1.0 - (v - lo) / (hi - lo))


def _x(t: float, a: float, b: float, w: float = W) -> float:
    return PAD_L + (w - PAD_L - PAD_R) * (t - a) / (b - a)


def _limit_steps(xs: list[float], lims: list[float | None], lo: float, hi: float) -> list[str]:
    """Polylines of a per-run limit: flat from each run to the next, a vertical step where it changes;
    a run judged without this limit breaks the line."""
    out: list[str] = []
    cur: list[str] = []
    for i, (x, v) in enumerate(zip(xs, lims, strict=True)):
        if v is None:
            if cur:
                out.append(" ".join(cur))
            cur = []
            continue
        y = _y(v, lo, hi)
        cur.append(f"{x:.1f},{y:.1f}")
        x_next = xs[i + 1] if i + 1 < len(xs) else x
        cur.append(f"{x_next:.1f},{y:.1f}")
    if cur:
        out.append(" ".join(cur))
    return out


def run_chart(title: str, unit: str, runs: list[RunPoint], nonneg: bool = False) -> Chart:
    """Runs over time against each run's own limits, with centre and 3-sigma lines (module docstring)."""
    chart = Chart(title, unit, xtitle="run start (UTC)")
    if not runs:
        chart.note = "no complete runs with this figure in the window"
        return chart
    runs = sorted(runs, key=lambda r: r.t)
    x = np.array([r.value for r in runs], dtype=float)
    c, lcl, ucl = control_limits(x)
    lims = [v for r in runs for v in (r.hi, r.lo) if v is not None]
    lo, hi, ticks, dec = nice_axis(min([float(x.min()), lcl, *lims]) if not nonneg else min(0.0, float(x.min())),
                                   max([float(x.max()), ucl, *lims]), floor_zero=nonneg)
    a, b, xt = time_axis(runs[0].t, runs[-1].t)
    xs = [_x(r.t, a, b) for r in runs]
    n_lim = n_sig = 0
    eps = 1e-9 * max(abs(c), 1e-12)  # the mean's rounding: a constant series is in control
    for xi, r in zip(xs, runs, strict=True):
        beyond = (r.hi is not None and r.value > r.hi) or (r.lo is not None and r.value < r.lo)
        sig = not beyond and not lcl - eps <= r.value <= ucl + eps
        n_lim, n_sig = n_lim + beyond, n_sig + sig
        kind = "out" if beyond else ("sigma" if sig else "")
        chart.points.append((xi, _y(r.value, lo, hi), kind, f"{r.label}: {r.value:.4g} {unit}".strip()))
    yc = _y(c, lo, hi)
    chart.lines = [Line(yc, f"mean {c:.3g}", "centre")] + [
        Line(_y(v, lo, hi), name, "sigma") for v, name in ((lcl, "-3σ"), (ucl, "+3σ"))
        if lo <= v <= hi and abs(_y(v, lo, hi) - yc) > 12]
    chart.steps = _limit_steps(xs, [r.hi for r in runs], lo, hi) + _limit_steps(xs, [r.lo for r in runs], lo, hi)
    chart.ticks = [(_y(v, lo, hi), tick_label(v, dec)) for v in ticks]
    chart.xlabels = [(_x(t, a, b), label) for t, label in xt]
    judged = sum(r.hi is not None or r.lo is not None for r in runs)
    chart.note = (f"{len(runs)} runs; {n_lim} beyond their own limit, {n_sig} more outside 3σ"
                  + ("" if judged == len(runs) else f"; {len(runs) - judged} without a limit for this figure"))
    return chart


def residual_chart(title: str, names: list[str], residuals_mg: np.ndarray) -> Chart:
    """Grouped bars: residual (mg) per pose and axis; the x axis names the poses."""
    chart = Chart(title, "mg", xtitle="pose")
    r = np.asarray(residuals_mg, dtype=float)
    m = max(float(np.max(np.abs(r))) if r.size else 1.0, 1e-6)
    lo, hi, ticks, dec = nice_axis(-m, m)
    group = (W - PAD_L - PAD_R) / max(1, len(names))
    bw = group / 4
    zero = _y(0.0, lo, hi)
    for i, name in enumerate(names):
        x0 = PAD_L + i * group + bw / 2
        for k, axis in enumerate("xyz"):
            y = _y(float(r[i, k]), lo, hi)
            chart.bars.append((x0 + k * bw, min(y, zero), bw * 0.9, abs(zero - y), axis))
        chart.xlabels.append((x0 + 1.5 * bw, name[:10]))
    chart.lines = [Line(zero, "0", "zero")]
    chart.ticks = [(_y(v, lo, hi), tick_label(v, dec)) for v in ticks]
    chart.note = f"RMS {float(np.sqrt(np.mean(r ** 2))):.3f} mg over {len(names)} poses" if r.size else ""
    return chart

"""Charts as plain numbers for inline SVG (templates draw them; nothing is fetched).

A control chart is a Shewhart individuals chart (lot/report.py ``control_limits``: centre
= mean, limits = mean +- 3 sigma, sigma = mean moving range / 1.128) with the acceptance
limit drawn beside it; a residual chart shows one run's residuals per pose and axis.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..lot.report import control_limits

W, H, PAD_L, PAD_R, PAD_T, PAD_B = 560.0, 200.0, 56.0, 12.0, 14.0, 26.0


@dataclass
class Line:
    y: float
    label: str
    kind: str  # centre, sigma, limit, zero


@dataclass
class Chart:
    """One chart in SVG user units (W x H): points, horizontal lines, axis labels."""

    title: str
    unit: str
    points: list[tuple[float, float, bool, str]] = field(default_factory=list)  # x, y, flagged, tooltip
    lines: list[Line] = field(default_factory=list)
    bars: list[tuple[float, float, float, float, str]] = field(default_factory=list)  # x, y, w, h, axis
    ticks: list[tuple[float, str]] = field(default_factory=list)  # y, label
    xlabels: list[tuple[float, str]] = field(default_factory=list)
    note: str = ""
    width: float = W
    height: float = H

    @property
    def path(self) -> str:
        return " ".join(f"{x:.1f},{y:.1f}" for x, y, _, _ in self.points)


def _scale(lo: float, hi: float) -> tuple[float, float]:
    if not np.isfinite(lo) or not np.isfinite(hi) or hi - lo < 1e-12:
        mid = 0.0 if not np.isfinite(lo) else lo
        return mid - 1.0, mid + 1.0
    pad = 0.08 * (hi - lo)
    return lo - pad, hi + pad


def _y(v: float, lo: float, hi: float) -> float:
    return PAD_T + (H - PAD_T - PAD_B) * (1.0 - (v - lo) / (hi - lo))


def control_chart(title: str, unit: str, values: list[float], labels: list[str], limit: float | None,
                  limit_lo: float | None = None) -> Chart:
    """Individuals chart of ``values`` (run order) with centre, 3-sigma lines and the acceptance limit."""
    chart = Chart(title, unit)
    x = np.asarray(values, dtype=float)
    if len(x) == 0:
        chart.note = "no complete runs with this figure yet"
        return chart
    c, lcl, ucl = control_limits(x)
    marks = [c, lcl, ucl] + [v for v in (limit, limit_lo) if v is not None]
    lo, hi = _scale(min(float(x.min()), *marks), max(float(x.max()), *marks))
    step = (W - PAD_L - PAD_R) / max(1, len(x) - 1)
    for i, (v, lab) in enumerate(zip(x, labels, strict=True)):
        out = v < lcl or v > ucl or (limit is not None and v > limit) or (limit_lo is not None and v < limit_lo)
        chart.points.append((PAD_L + i * step, _y(float(v), lo, hi), bool(out), f"{lab}: {v:.4g} {unit}"))
    yc = _y(c, lo, hi)
    chart.lines = [Line(yc, f"mean {c:.3g}", "centre")] + [  # 3-sigma lines on the mean are not drawn twice
        Line(_y(v, lo, hi), name, "sigma") for v, name in ((lcl, "-3σ"), (ucl, "+3σ")) if abs(_y(v, lo, hi) - yc) > 12]
    for v in (limit, limit_lo):
        if v is not None:
            chart.lines.append(Line(_y(v, lo, hi), f"limit {v:g}", "limit"))
    chart.ticks = [(_y(v, lo, hi), f"{v:.3g}") for v in np.linspace(lo, hi, 4)]
    n_out = sum(p[2] for p in chart.points)
    chart.note = f"{len(x)} runs; {n_out} outside 3σ or the limit" if n_out else f"{len(x)} runs, all in control"
    if limit is None:
        chart.note += "; no acceptance limit configured"
    return chart


def residual_chart(title: str, names: list[str], residuals_mg: np.ndarray) -> Chart:
    """Grouped bars: residual (mg) per pose and axis."""
    chart = Chart(title, "mg")
    r = np.asarray(residuals_mg, dtype=float)
    m = max(float(np.max(np.abs(r))) if r.size else 1.0, 1e-6)
    lo, hi = _scale(-m, m)
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
    chart.ticks = [(_y(v, lo, hi), f"{v:.2g}") for v in np.linspace(lo, hi, 5)]
    chart.note = f"RMS {float(np.sqrt(np.mean(r ** 2))):.3f} mg over {len(names)} poses" if r.size else ""
    return chart

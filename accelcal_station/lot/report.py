"""A lot report a production engineer can look at: one HTML file with embedded PNGs.

Parameter histograms against their acceptance limits, pass rate and failure reasons
over time, and a Shewhart individuals control chart per parameter (centre line = mean,
limits = mean +- 3 sigma, sigma from the average moving range / 1.128, Montgomery
"Introduction to Statistical Quality Control" section 6.4).  ``residual_figure`` draws
one run's residuals per pose.
"""
from __future__ import annotations

import base64
import html
import io
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..acceptance.reasons import codes
from ..atomic import atomic_write
from ..calibration import param_vector
from ..config.safe_yaml import HostileYAML, safe_load
from ..errors import AccelcalError, DataError
from ..fileguard.cells import safe_text
from ..jsontypes import JsonValue
from ..store.records import RunRecord, iso

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# shown parameters: name, index into calibration.param_vector, unit scale, limit key, limit centre
PARAMS = [(f"W{i}{i}", 4 * i, 1.0, "gain_error_max", 1.0) for i in range(3)] + \
         [(f"V{i} (mg)", 9 + i, 1e3, "offset_max_mg", 0.0) for i in range(3)] + \
         [("W01", 1, 1.0, "cross_axis_max", 0.0), ("W02", 2, 1.0, "cross_axis_max", 0.0),
          ("W12", 5, 1.0, "cross_axis_max", 0.0)]
D2 = 1.128  # d2 for moving ranges of two


def _pyplot() -> ModuleType:
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    try:
        import matplotlib
    except ImportError:
        raise AccelcalError("the lot report needs matplotlib: pip install 'accelcal-station[report]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig: Figure) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _limits(recs: list[RunRecord]) -> dict[str, float]:
    """The acceptance limits of the newest run whose config can be read."""
    for r in reversed(recs):
        try:
            acc = (safe_load(r.config_text or "") or {}).get("acceptance") or {}
        except (HostileYAML, ValueError, AttributeError):  # a stored config is only advisory here
            continue
        if isinstance(acc, dict):
            return {k: float(v) for k, v in acc.items() if isinstance(v, (int, float))}
    return {}


def control_limits(x: np.ndarray) -> tuple[float, float, float]:
    """Individuals chart: (centre, lower, upper) with sigma = mean moving range / d2."""
    centre = float(np.mean(x))
    sigma = float(np.mean(np.abs(np.diff(x)))) / D2 if len(x) > 1 else 0.0
    return centre, centre - 3 * sigma, centre + 3 * sigma


def _param_figures(plt: ModuleType, cals: Sequence[Mapping[str, JsonValue]], limits: dict[str, float]
                   ) -> list[tuple[str, str]]:
    """Per shown parameter: its histogram against the limits and its control chart."""
    vals = np.array([param_vector(c) for c in cals])
    out = []
    for name, idx, scale, key, centre in PARAMS:
        x = vals[:, idx] * scale
        fig, (a, b) = plt.subplots(1, 2, figsize=(10, 2.8))
        a.hist(x, bins=min(30, max(5, len(x) // 3)), color="#4878a8")
        if key in limits:
            lim = limits[key] * (1e-3 * scale if key == "offset_max_mg" else 1.0)
            for v in (centre - lim, centre + lim):
                a.axvline(v, color="red", ls="--")
            a.set_title(f"{name}: histogram, limits ({key} {limits[key]:g}) dashed")
        else:
            a.set_title(f"{name}: histogram (no limit configured)")
        c, lo, hi = control_limits(x)
        b.plot(np.arange(1, len(x) + 1), x, "o-", ms=3)
        for v, style in ((c, "-"), (lo, ":"), (hi, ":")):
            b.axhline(v, color="gray", ls=style)
        out_of = np.flatnonzero((x < lo) | (x > hi))
        b.plot(out_of + 1, x[out_of], "rs", ms=5)
        b.set_title(f"{name}: control chart ({len(out_of)} outside 3 sigma)")
        b.set_xlabel("board (in run order)")
        out.append((name, _png(fig)))
    return out


def _time_figure(plt: ModuleType, done: list[RunRecord]) -> str:
    """Pass rate per day and FAIL reasons (by code) per day."""
    days = sorted({(iso(r.started_at) or "")[:10] for r in done})
    reasons: Counter[str] = Counter()
    per_day: dict[str, Counter[str]] = {d: Counter() for d in days}
    for r in done:
        d = (iso(r.started_at) or "")[:10]
        per_day[d]["runs"] += 1
        per_day[d]["pass"] += r.verdict == "PASS"
        if r.verdict == "FAIL":
            for code in set(codes(r.reasons)):
                per_day[d][f"reason:{code}"] += 1
                reasons[code] += 1
    rate = [per_day[d]["pass"] / per_day[d]["runs"] * 100 for d in days]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 2.8))
    a.plot(days, rate, "o-")
    a.set_ylim(0, 105)
    a.set_title("pass rate per day (%)")
    bottom = np.zeros(len(days))
    for code, _ in reasons.most_common(8):
        h = np.array([per_day[d][f"reason:{code}"] for d in days], dtype=float)
        b.bar(days, h, bottom=bottom, label=code)
        bottom += h
    b.set_title("FAIL reasons per day")
    if reasons:
        b.legend(fontsize=7)
    for ax in (a, b):
        ax.tick_params(axis="x", labelrotation=45, labelsize=7)
    return _png(fig)


def lot_html(recs: list[RunRecord], title: str) -> str:
    """The whole report as one self-contained HTML page."""
    plt = _pyplot()
    done = [r for r in recs if r.status == "complete" and r.verdict]
    if not done:
        raise DataError("no complete runs match: nothing to report")
    cals = [r.calibration for r in done if r.calibration and not r.damaged]
    limits = _limits(done)
    n_pass = sum(r.verdict == "PASS" for r in done)
    def e(text: str) -> str:  # escaped for HTML, and inert in a spreadsheet that imports the page
        return html.escape(safe_text(text))

    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title></head><body>",
             f"<h1>{e(title)}</h1>",
             f"<p>{len(recs)} runs, {len(done)} complete: PASS {n_pass}, FAIL {len(done) - n_pass} "
             f"(pass rate {100 * n_pass / len(done):.1f} %), {iso(done[0].started_at)} .. "
             f"{iso(done[-1].started_at)}</p>",
             f"<h2>Pass rate and failure reasons over time</h2><img src='data:image/png;base64,"
             f"{_time_figure(plt, done)}'>"]
    if cals:
        parts.append("<h2>Parameters: histograms against limits, control charts</h2>")
        parts += [f"<h3>{e(n)}</h3><img src='data:image/png;base64,{png}'>"
                  for n, png in _param_figures(plt, cals, limits)]
    parts.append("</body></html>\n")
    return "\n".join(parts)


def write_lot_html(recs: list[RunRecord], path: str | Path, title: str = "accelcal lot report") -> None:
    text = lot_html(recs, title)
    try:
        atomic_write(path, text)
    except OSError as err:
        raise DataError(f"{path}: cannot write the report ({err.strerror})") from None


def residual_figure(rec: RunRecord, path: str | Path) -> None:
    """One run's residuals (reference minus calibrated, mg) per pose and axis, refitted from
    its stored poses with its model."""
    from ..models.fitting import fit_session

    plt = _pyplot()
    if not rec.poses:
        raise DataError(f"run {rec.id} has no poses to plot")
    fit = fit_session(rec.session(), rec.model or "12")
    res = fit.residuals_g * 1e3
    names = [p.name for p in rec.poses]
    fig, ax = plt.subplots(figsize=(max(5, len(names) * 0.7), 3.2))
    w = 0.27
    for k, axis in enumerate("xyz"):
        ax.bar(np.arange(len(names)) + (k - 1) * w, res[:, k], w, label=axis)
    ax.set_xticks(np.arange(len(names)), [n[:12] for n in names], rotation=45, fontsize=8)
    ax.axhline(0, color="gray")
    ax.set_ylabel("residual (mg)")
    ax.set_title(f"run {rec.id}, board {rec.device_serial}: model {fit.model}, "
                 f"RMS {fit.residual_rms_g * 1e3:.3f} mg")
    ax.legend()
    try:
        atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight"))
    except OSError as err:
        raise DataError(f"{path}: cannot write the figure ({err.strerror})") from None
    finally:
        plt.close(fig)

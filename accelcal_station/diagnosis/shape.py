"""The shape of what the diagnosis leaves unexplained: odd or even in g, a product of axes,
fixed per orientation, dependent on the approach direction, time-varying, changing with
temperature or with acquisition order on an axis; and where it is."""
from __future__ import annotations

from typing import NotRequired, TypedDict

import numpy as np

from .effects.pose_error import revisits
from .evaluation import Evaluation
from .gap_data import GapData, TimeData
from .order import order_basis
from .where import PoseGap, pose_gaps

SHAPES = ("odd in g", "even in g", "product of axes", "approach direction", "fixed per orientation")


class ShapeFit(TypedDict):
    """The share of the residual's standardised sum of squares a shape explains, and its p-value."""

    share: float
    p_value: float
    repeats_on_revisit: NotRequired[bool]  # "fixed per orientation": the revisits agree within their noise


class TimeShape(TypedDict):
    """The time view's residual: RMS ratio to its variance and the chi-square p-value."""

    ratio: float
    p_value: float


# a static shape, an axis-by-axis trend ("by temperature": {x: ShapeFit, ...}) or the time view's
Shape = ShapeFit | dict[str, ShapeFit] | TimeShape


class Leftover(TypedDict, total=False):
    """What the final model leaves (diagnose --json ``left``): its shapes, worst poses and axis, in words."""

    shapes: dict[str, Shape]
    worst_poses: list[PoseGap]
    worst_axis: str
    summary: str


def _bases(data: GapData, c: int) -> dict[str, np.ndarray]:
    """Candidate shapes as regressors for channel c's residual (columns of the pose readings g)."""
    g = data.g
    o = [k for k in range(3) if k != c]
    step = np.vstack([np.zeros((1, 3)), np.diff(g, axis=0)])
    step[1:][data.file[1:] != data.file[:-1]] = 0.0
    return {"odd in g": np.stack([g[:, c] ** 3, g[:, c]], 1),
            "even in g": np.stack([g[:, c] ** 2, np.abs(g[:, c])], 1),
            "product of axes": np.stack([g[:, o[0]] * g[:, o[1]], g[:, c] * g[:, o[0]], g[:, c] * g[:, o[1]]], 1),
            "approach direction": np.sign(np.round(step, 1))}


MIN_SPAN = 0.1  # a shape's regressor must vary by this much (g^k) over the poses to be judged at all


def _reduction(r: np.ndarray, w: np.ndarray, X: np.ndarray) -> float:
    """Drop of sum(w r^2) when r is regressed on X by weighted least squares (0 when the poses do not
    span X, or are too few to leave twice its columns as residual degrees of freedom)."""
    keep = np.ptp(X, axis=0) > MIN_SPAN
    if not keep.any() or len(r) < 3 * keep.sum():
        return 0.0
    sw = np.sqrt(w)
    Xw, rw = X * sw[:, None], r * sw
    beta = np.linalg.lstsq(Xw[:, keep], rw, rcond=None)[0]
    return float(rw @ rw - np.sum((rw - Xw[:, keep] @ beta) ** 2))


def _static_shapes(data: GapData, r: np.ndarray, v: np.ndarray, alpha: float) -> dict[str, ShapeFit]:
    """Share of the static residuals (P, m) each candidate shape explains, and its p-value."""
    from scipy import stats

    chans = range(3) if r.shape[1] == 3 else [int(k) for k in np.unique(np.argmax(np.abs(data.g), 1))]
    total = float(np.sum(r**2 / v))
    out: dict[str, ShapeFit] = {}
    for name in SHAPES[:4]:
        red, k = 0.0, 0
        for c in chans:
            X = _bases(data, c)[name]
            col = c if r.shape[1] == 3 else 0
            red += _reduction(r[:, col], 1.0 / v[:, col], X)
            k += X.shape[1]
        out[name] = {"share": red / total if total > 0 else 0.0, "p_value": float(stats.chi2.sf(red, k))}
    if data.ref is not None:
        groups = revisits(data.ref)
        if groups:
            between = sum(float(len(g) * np.sum(r[g].mean(0) ** 2 / v[g].mean(0))) for g in groups)
            within = sum(float(np.sum((r[g] - r[g].mean(0)) ** 2 / v[g])) for g in groups)
            n_in = sum(r.shape[1] * (len(g) - 1) for g in groups)
            repeat = within <= stats.chi2.ppf(1 - alpha, n_in)
            out["fixed per orientation"] = {"share": between / total if total > 0 else 0.0,
                                            "p_value": float(stats.chi2.sf(between, r.shape[1] * len(groups))),
                                            "repeats_on_revisit": bool(repeat)}
    return out


def _temperature_basis(data: GapData) -> np.ndarray | None:
    """A leftover that changes with temperature: dT g and dT^2 g (any gain or cross-axis term linear or
    quadratic in T), dT and dT^2 (an offset), dT = T - mean T; None below two temperatures."""
    if data.temp_c is None or data.n_temps < 2:
        return None
    dT = (data.temp_c - np.mean(data.temp_c)) / 25.0
    return np.column_stack([dT[:, None] * data.g, (dT**2)[:, None] * data.g, dT, dT**2])


def _temperature_phrase(data: GapData, r: np.ndarray, v: np.ndarray) -> str:
    """How one axis' leftover moves with temperature, from its gap per temperature (the by_temperature view)."""
    assert data.temp_c is not None
    tk = np.round(data.temp_c / 2.0)
    ts = [(float(np.mean(data.temp_c[tk == t])), float(np.sqrt(np.mean(r[tk == t] ** 2 / v[tk == t]))))
          for t in np.unique(tk)]
    lo, hi = int(np.argmin([g for _, g in ts])), int(np.argmax([g for _, g in ts]))
    gaps = ", ".join(f"{g:.2g} at {t:g} C" for t, g in ts)
    if 0 < lo < len(ts) - 1:
        return f"grows with |T - {ts[lo][0]:g} C| (gap {gaps})"
    if 0 < hi < len(ts) - 1:
        return f"changes with |T - {ts[hi][0]:g} C|, largest there (gap {gaps})"
    return f"grows as the temperature {'rises' if lo == 0 else 'falls'} (gap {gaps})"


def _axis_trends(data: GapData, r: np.ndarray, v: np.ndarray, alpha: float
                 ) -> tuple[list[str], dict[str, dict[str, ShapeFit]]]:
    """Per axis: does the leftover follow temperature or acquisition order (the where views as shapes)?
    A channel counts when the basis removes over a quarter of its sum of squares at p < alpha / 3."""
    from scipy import stats

    views = {"temperature": _temperature_basis(data), "acquisition order": order_basis(data, intercepts=False)}
    words: list[str] = []
    js: dict[str, dict[str, ShapeFit]] = {}
    for view, X in views.items():
        if X is None or r.shape[1] != 3:
            continue
        for c, a in enumerate("xyz"):
            total = float(np.sum(r[:, c] ** 2 / v[:, c]))
            red = _reduction(r[:, c], 1.0 / v[:, c], X)
            p = float(stats.chi2.sf(red, X.shape[1]))
            share = red / total if total > 0 else 0.0
            js.setdefault(view, {})[a] = {"share": share, "p_value": p}
            if p < alpha / 3 and share > 0.25:
                words.append(f"temperature-dependent on {a}: {_temperature_phrase(data, r[:, c], v[:, c])}"
                             if view == "temperature"
                             else f"trends with acquisition order on {a}")
    return words, js


def leftover_shape(data: GapData, ev: Evaluation, td: TimeData | None, alpha: float) -> Leftover:
    """Where the final model's held-out residual lies and which shape it has (module doc)."""
    from scipy import stats

    out: Leftover = {"shapes": {}}
    all_shapes: dict[str, Shape] = out["shapes"]
    names = []
    if ev.r_static is not None and ev.v_static is not None:
        r, v = ev.r_static, ev.v_static
        shapes = _static_shapes(data, r, v, alpha)
        all_shapes.update(shapes)
        out["worst_poses"] = pose_gaps(data, r, v, 3)
        if r.shape[1] == 3:
            ax = np.sqrt(np.mean(r**2 / v, axis=0))
            out["worst_axis"] = "xyz"[int(np.argmax(ax))]
        sig = [(n, s) for n, s in shapes.items() if s["p_value"] < alpha and s["share"] > 0.25]
        if "fixed per orientation" in shapes and not shapes["fixed per orientation"].get("repeats_on_revisit"):
            sig = [(n, s) for n, s in sig if n != "fixed per orientation"]
        trends, tj = _axis_trends(data, r, v, alpha)
        all_shapes.update({f"by {k}": x for k, x in tj.items()})
        names += trends + [n for n, _ in sorted(sig, key=lambda x: -x[1]["share"])]
    if ev.r_time is not None and ev.v_time is not None:
        N = ev.r_time.size
        x = float(np.sum(ev.r_time**2 / ev.v_time))
        p = float(stats.chi2.sf(x, N))
        all_shapes["time-varying"] = TimeShape(ratio=float(np.sqrt(x / N)), p_value=p)
        if p < alpha:
            names.append("time-varying within captures")
    odd = [p["pose"] for p in out.get("worst_poses", []) if p["stands_out"]]  # a pose named only if it stands out
    where = f" (largest on {out['worst_axis']}{', pose ' + odd[0] if odd else ''})" if "worst_axis" in out else ""
    out["summary"] = (", ".join(names) if names else "no single shape (scattered)") + where
    return out

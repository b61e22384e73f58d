"""The shape of what the diagnosis leaves unexplained: odd or even in g, a product of axes,
fixed per orientation, dependent on the approach direction, time-varying; and where it is."""
from __future__ import annotations

from typing import Any

import numpy as np

from .effects.pose_error import revisits
from .evaluation import Evaluation
from .gap_data import GapData, TimeData

SHAPES = ("odd in g", "even in g", "product of axes", "approach direction", "fixed per orientation")


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


def _static_shapes(data: GapData, r: np.ndarray, v: np.ndarray, alpha: float) -> dict[str, dict[str, Any]]:
    """Share of the static residuals (P, m) each candidate shape explains, and its p-value."""
    from scipy import stats

    chans = range(3) if r.shape[1] == 3 else [int(k) for k in np.unique(np.argmax(np.abs(data.g), 1))]
    total = float(np.sum(r**2 / v))
    out: dict[str, dict[str, Any]] = {}
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


def leftover_shape(data: GapData, ev: Evaluation, td: TimeData | None, alpha: float) -> dict[str, Any]:
    """Where the final model's held-out residual lies and which shape it has (module doc)."""
    from scipy import stats

    out: dict[str, Any] = {"shapes": {}}
    names = []
    if ev.r_static is not None and ev.v_static is not None:
        r, v = ev.r_static, ev.v_static
        shapes = _static_shapes(data, r, v, alpha)
        out["shapes"] = shapes
        z = np.sqrt(np.mean(r**2 / v, axis=1))
        out["worst_poses"] = [{"pose": data.names[i], "z_rms": float(z[i]), "residual_mg": (1e3 * r[i]).tolist()}
                              for i in np.argsort(-z)[:3]]
        if r.shape[1] == 3:
            ax = np.sqrt(np.mean(r**2 / v, axis=0))
            out["worst_axis"] = "xyz"[int(np.argmax(ax))]
        sig = [(n, s) for n, s in shapes.items() if s["p_value"] < alpha and s["share"] > 0.25]
        if "fixed per orientation" in shapes and not shapes["fixed per orientation"].get("repeats_on_revisit"):
            sig = [(n, s) for n, s in sig if n != "fixed per orientation"]
        names += [n for n, _ in sorted(sig, key=lambda x: -x[1]["share"])]
    if ev.r_time is not None and ev.v_time is not None:
        N = ev.r_time.size
        x = float(np.sum(ev.r_time**2 / ev.v_time))
        p = float(stats.chi2.sf(x, N))
        out["shapes"]["time-varying"] = {"ratio": float(np.sqrt(x / N)), "p_value": p}
        if p < alpha:
            names.append("time-varying within captures")
    where = f" (largest on {out['worst_axis']}, pose {out['worst_poses'][0]['pose']})" if "worst_axis" in out else ""
    out["summary"] = (", ".join(names) if names else "no single shape (scattered)") + where
    return out

"""Fits that must never be written: absurd readings, degenerate pose sets, absurd coefficients.

These are physical bounds, not acceptance limits: they hold for any accelerometer read
in g, whatever a configuration's limits say, so a config that leaves a limit out can
never let a degenerate calibration through.
"""
from __future__ import annotations

import numpy as np

from .linear import N_COEF

# a pose's reading of gravity, in g: far outside this the sample is not a reading of 1 g
READING_NORM_G = (0.3, 3.0)
# W maps reading (g) to g: a gain off by 2x or an inverted axis is no calibration
GAIN_RANGE = (0.5, 2.0)
CROSS_MAX = 0.5
COND_MAX = 10.0
OFFSET_MAX_G = 1.0
# two poses are one pose for counting when their readings point within this angle
DISTINCT_DEG = 5.0
PARAMS_PER_AXIS = {**N_COEF, "9": 9}  # model 9: nine parameters, all from every pose


def distinct_directions(readings_g: np.ndarray, tol_deg: float = DISTINCT_DEG) -> int:
    """How many distinct directions a pose set points in (greedy clustering of unit vectors)."""
    x = np.asarray(readings_g, dtype=float)
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    u = x / np.where(n > 0, n, 1.0)
    cos = np.cos(np.radians(tol_deg))
    reps = np.empty((len(u), 3))  # the representatives found so far, in place: O(P) memory
    k = 0
    for v in u:
        if k == 0 or np.max(reps[:k] @ v) < cos:
            reps[k] = v
            k += 1
    return k


def distinct_directions_batch(readings_g: np.ndarray, tol_deg: float = DISTINCT_DEG) -> np.ndarray:
    """``distinct_directions`` of each of B boards' (B, P, 3) readings, the same greedy
    clustering stepped over the poses for all boards at once; (B,) counts."""
    x = np.asarray(readings_g, dtype=float)
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    u = x / np.where(n > 0, n, 1.0)
    cos = np.cos(np.radians(tol_deg))
    B, P, _ = u.shape
    is_rep = np.zeros((B, P), bool)
    for p in range(P):
        dots = np.einsum("bqk,bk->bq", u[:, :p], u[:, p])
        near = np.any(is_rep[:, :p] & (dots >= cos), axis=1)
        is_rep[:, p] = ~near
    return is_rep.sum(axis=1)


def poses_needed(model: str) -> int:
    """Distinct poses a judged run needs: the model's unknowns per axis plus one, so that
    leaving any one pose out still determines it (cross-validation is always measurable)."""
    return PARAMS_PER_AXIS[str(model)] + 1


def absurd_readings(gf: np.ndarray) -> list[str]:
    """Per board of (D, P, 3) readings in g: '' or why some pose is not a reading of gravity."""
    with np.errstate(over="ignore"):  # 1e308 squared is inf: still refused
        norms = np.linalg.norm(gf, axis=-1)
    lo, hi = READING_NORM_G
    bad = ~((norms >= lo) & (norms <= hi))
    out = []
    for d in range(gf.shape[0]):
        idx = np.flatnonzero(bad[d])
        out.append("" if idx.size == 0 else
                   f"pose {idx[0] + 1} reads {norms[d, idx[0]]:.4g} g; a reading of gravity is "
                   f"{lo:g} to {hi:g} g (damaged data or a saturated axis)")
    return out


def absurd_coefficients(W: np.ndarray, V: np.ndarray) -> list[str]:
    """Per board of (D, 3, 3) W and (D, 3) V: '' or why the calibration is physically absurd."""
    out = []
    for w, v in zip(np.asarray(W, dtype=float), np.asarray(V, dtype=float), strict=True):
        diag = np.diag(w)
        off = w - np.diag(diag)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(v))):
            out.append("the fit gave non-finite coefficients")
        elif np.any((diag < GAIN_RANGE[0]) | (diag > GAIN_RANGE[1])):
            out.append(f"gains W diagonal {np.round(diag, 4).tolist()} outside {GAIN_RANGE[0]:g} to "
                       f"{GAIN_RANGE[1]:g}: the poses do not exercise every axis (degenerate pose set)")
        elif np.max(np.abs(off)) > CROSS_MAX:
            out.append(f"cross-axis term {np.max(np.abs(off)):.3g} > {CROSS_MAX:g}: degenerate pose set")
        elif np.linalg.cond(w) > COND_MAX:
            out.append(f"W condition number {np.linalg.cond(w):.3g} > {COND_MAX:g}: degenerate pose set")
        elif np.max(np.abs(v)) > OFFSET_MAX_G:
            out.append(f"offset {np.max(np.abs(v)):.3g} g > {OFFSET_MAX_G:g} g: absurd calibration")
        else:
            out.append("")
    return out


def absurd_norm_model(W: np.ndarray, norm_error_g: np.ndarray) -> list[str]:
    """Model 9 (any raw offset): '' or why the fit is absurd -- a singular or non-finite W,
    or a calibrated pose whose norm is not near 1 g (the fit did not converge on gravity)."""
    out = []
    for w, ne in zip(np.asarray(W, dtype=float), np.asarray(norm_error_g, dtype=float), strict=True):
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(ne))):
            out.append("the fit gave non-finite coefficients")
        elif np.linalg.cond(w) > COND_MAX:
            out.append(f"W condition number {np.linalg.cond(w):.3g} > {COND_MAX:g}: degenerate pose set")
        elif ne.size and np.max(np.abs(ne)) > READING_NORM_G[0]:
            out.append(f"a calibrated pose is {np.max(np.abs(ne)):.3g} g off 1 g: damaged data")
        else:
            out.append("")
    return out

"""jig_rotation: a fixed rotation of the jig, a deterministic 3-parameter rotation fitted on the references.

A small rotation w (rad) of every reference moves the reading by w x u (u: the unit reference):
across u only, never along it.  w is fitted jointly with the baseline by weighted least squares
(weights: the fixed floor) and kept when it lowers their chi-square significantly (chi2 with 3 dof) while the
component along the reference stays at the floor: a cubic, a quadratic or a product term leaves a
radial part, so the rotation is never named for them.  With the cross_axis matrix W in the model,
W R is another W: the rotation is absorbed and cannot be told from the board's own cross-axis.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...jsontypes import JsonObject
from .design import static_design

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import GapData


def _chi2_sf(x: float, dof: int) -> float:
    from scipy import stats

    return float(stats.chi2.sf(x, dof))


def _cross_matrix(u: np.ndarray) -> np.ndarray:
    """(P, 3, 3) matrices A with A w = w x u (= -[u]x w)."""
    z = np.zeros(len(u))
    x, y, w = u[:, 0], u[:, 1], u[:, 2]
    return np.stack([np.stack([z, w, -y], 1), np.stack([-w, z, x], 1), np.stack([y, -x, z], 1)], 1)


def _wls_chi2(A: np.ndarray, y: np.ndarray, sw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    th, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    return th, y - A @ th


def fit_rotation(data: GapData, floor_v: np.ndarray, baseline: tuple[str, ...], gamma: float,
                 alpha: float) -> JsonObject:
    """The baseline fitted jointly with a rotation w of the references, in-sample, weighted by the floor.

    Residual convention of the static view (design.static_design): gamma ref - b(readings) = A theta; a jig
    rotated by w gives the reading of R(w) ref, so the rotation enters as the columns -gamma [u]x applied to w.
    Its test: the chi-square drop of 3 dof; then what is left along the reference must be at the floor.
    """
    P, ref = data.P, data.ref
    if ref is None:
        raise ValueError("fit_rotation needs references (jig_rotation says why not without)")
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    A, b, _, _ = static_design(baseline, data.g, ref, dT, None, False, data.n_temps)
    u = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    y = (gamma * ref - b).reshape(-1)
    A0 = A.reshape(P * 3, -1)
    A1 = np.concatenate([A0, -gamma * _cross_matrix(u).reshape(P * 3, 3)], axis=1)
    sw = 1.0 / np.sqrt(floor_v.reshape(-1))
    _, r0 = _wls_chi2(A0, y, sw)
    th, r1 = _wls_chi2(A1, y, sw)
    chi0, chi1 = float(np.sum((r0 * sw) ** 2)), float(np.sum((r1 * sw) ** 2))
    p_rot = _chi2_sf(chi0 - chi1, 3)
    left, v = r1.reshape(P, 3), floor_v.reshape(P, 3)
    along = np.sum(left * u, axis=1)
    dof = max(P - A0.shape[1], 1)  # the baseline's terms take up mostly along-reference freedom
    z_along = float(np.sum(along**2 / np.sum(u**2 * v, axis=1)))
    p_along = _chi2_sf(z_along, dof)
    passed = bool(p_rot < alpha and p_along >= alpha / 2)
    deg = np.degrees(th[-3:])
    if passed:
        reason = (f"a fixed jig rotation of {np.linalg.norm(deg):.3f} deg fits the references (p = {p_rot:.2g}); "
                  "the residual along the reference stays at the floor")
    elif p_rot >= alpha:
        reason = f"no fixed rotation fits the references better than chance (p = {p_rot:.2g})"
    else:
        reason = (f"a rotation lowers the residual (p = {p_rot:.2g}) but the residual along the reference is "
                  f"{np.sqrt(z_along / dof):.2f} x the floor: a radial part that no rotation makes")
    return {"testable": True, "passed": passed, "rotation_deg": deg.tolist(),
            "angle_deg": float(np.linalg.norm(deg)), "p_value": p_rot, "p_along_excess": p_along,
            "chi2_before": chi0, "chi2_after": chi1,
            "test": "chi-square (3 dof) drop when the baseline is fitted jointly with a rotation of the references, "
                    "weighted by the fixed floor (alpha); along-reference residual at the floor (alpha/2)",
            "reason": reason}


def jig_rotation(data: GapData, base: Evaluation, baseline: tuple[str, ...], gamma: float,
                 alpha: float) -> JsonObject:
    """The report of a fixed jig rotation: fitted jointly with the baseline (fit_rotation), or why not."""
    if data.norm_only or base.r_static is None or base.floor_static is None or base.r_static.shape[1] != 3:
        return {"testable": False, "reason": "a rotation keeps |f| = 1 g: it needs references (a static view)"}
    if "cross_axis" in baseline:
        return {"testable": False,
                "reason": "the baseline's full cross_axis matrix W absorbs a fixed jig rotation exactly (W R is "
                          "another W), so it cannot be told from the board's own cross-axis"}
    return fit_rotation(data, base.floor_static, baseline, gamma, alpha)

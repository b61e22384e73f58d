"""pose_error: a pose error rotates gravity, so the reading moves across the reference, not along it."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...jsontypes import JsonObject
from .base import Signature, StochasticEffect

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import GapData, TimeData
    from ..noise_floor import Floor


def _chi2_sf(x: float, dof: float) -> float:
    from scipy import stats

    return float(stats.chi2.sf(x, dof)) if dof > 0 else 1.0


def revisits(ref: np.ndarray) -> list[np.ndarray]:
    """Groups of poses that share a reference direction (a face or tilt visited more than once)."""
    key = np.round(ref / np.linalg.norm(ref, axis=1, keepdims=True), 3)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    groups = [np.flatnonzero(inv.ravel() == k) for k in range(inv.max() + 1)]
    return [g for g in groups if len(g) > 1]


def _revisit_test(across: np.ndarray, v_across: np.ndarray, groups: list[np.ndarray]) -> tuple[float, JsonObject]:
    """Whether the across-reference residuals of revisited orientations differ between visits (a random pose
    error) more than the floor allows: (p-value, evidence)."""
    d2, vd, k = 0.0, 0.0, 0
    for g in groups:
        a = across[g] - across[g].mean(axis=0)
        d2 += float(np.sum(a**2))
        vd += float(np.sum(v_across[g]) * (len(g) - 1) / len(g))
        k += 2 * (len(g) - 1)
    p_rep = _chi2_sf(d2 / (vd / k) if vd > 0 else 0.0, k)
    return p_rep, {"revisits": len(groups), "revisit_ratio": float(np.sqrt(d2 / vd)) if vd > 0 else None,
                   "p_revisit_excess": p_rep}


class PoseError(StochasticEffect):
    name = "pose_error"
    static_columns = False
    time_columns = False

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if data.norm_only:
            return False, ("a rotation keeps |f| = 1 g, so a pose's orientation error is invisible without "
                           "references (norm-only data)")
        return True, ""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature:
        """Held-out residual r split along and across the reference u (r.u u and the rest).

        Each part is standardised by its predicted variance (floor + fit): the along part must
        stay at the floor (chi-square, 1 dof per pose) and the across part exceed it (2 dof per
        pose).  Where a direction is revisited, a random pose error differs between visits
        (Var = 2 s^2 across); a tilt that repeats exactly is fixed per orientation, not pose error.
        """
        r, fl, pv, ref = ev.r_static, ev.floor_static, ev.pv_static, data.ref
        assert r is not None and fl is not None and pv is not None and ref is not None, \
            "testable: references and a static view"
        v = fl + pv  # ev: fitted with pose scatter in its weights
        u = ref / np.linalg.norm(ref, axis=1, keepdims=True)
        along = np.sum(r * u, axis=1)
        v_along = np.sum(u**2 * v, axis=1)
        across = r - along[:, None] * u
        v_across = np.sum(v, axis=1) - v_along
        z_al, z_ac = float(np.sum(along**2 / v_along)), float(np.sum(np.sum(across**2, 1) / v_across))
        P = data.P
        p_along, p_across = _chi2_sf(z_al, P), _chi2_sf(z_ac, 2 * P)
        s2 = max(np.sum(np.sum(across**2, 1) - v_across) / (2 * P), 0.0)
        along_ratio, across_ratio = float(np.sqrt(z_al / P)), float(np.sqrt(z_ac / (2 * P)))
        scatter_deg = float(np.degrees(np.sqrt(s2)))
        ev_json: JsonObject = {"along_ratio": along_ratio, "across_ratio": across_ratio,
                               "p_along_excess": p_along, "p_across_excess": p_across, "scatter_deg": scatter_deg}
        rep = ""
        groups = revisits(ref)
        p_rep = 0.0
        if groups:
            p_rep, revisit = _revisit_test(across, v_across, groups)
            ev_json.update(revisit)
            if p_rep >= alpha:
                rep = "; but revisited orientations repeat their tilt exactly (fixed per orientation, not pose error)"
        passed = bool(p_across < alpha / 2 and p_along >= alpha / 2 and p_rep < alpha)
        if passed:
            reason = (f"the residual across the reference is {across_ratio:.2f} x the floor while along it "
                      f"stays at {along_ratio:.2f} x: a rotation of gravity, "
                      f"{scatter_deg:.3f} deg RMS per axis")
        elif p_across >= alpha / 2:
            reason = f"the residual across the reference is at the floor ({across_ratio:.2f} x)"
        elif p_along < alpha / 2:
            reason = (f"the residual along the reference is {along_ratio:.2f} x the floor: a radial part "
                      "that no rotation makes")
        else:
            reason = f"the residual across the reference is {across_ratio:.2f} x the floor" + rep
        return Signature(self.name, passed, max(p_across, p_rep) if passed else 1.0,
                         "chi-square: across-reference residual above the floor (alpha/2), along-reference at it "
                         "(alpha/2), revisits differ (alpha)", reason, ev_json)

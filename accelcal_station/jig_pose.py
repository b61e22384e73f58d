"""The jig's per-pose rotation, estimated jointly from every board of a panel.

All boards on a panel see the same true orientation at each pose: board b's reading at
pose p is the calibration model of ``R_p r_p`` (r_p the commanded reference, R_p the
jig's true, slightly wrong, rotation).  With references (models 6, 12, 15) each board's
fit leaves the part of ``R_p r_p - r_p`` its model cannot absorb in its residuals; that
part is common to all boards, while noise is not.  Averaging the residuals of the
*other* boards (leave one board out, so a board's own noise is never fitted back into
its references) and turning each reference by the small rotation that explains the
average (delta_p x r_p = mean residual, delta_p perpendicular to r_p) removes the jig's
per-pose scatter from every board's residuals and acceptance figures.

What no panel can estimate: the part of the scatter that a calibration model absorbs
(for a full W: a rotation common to all poses, and for cube-vertex designs such as
an4399-8 also a traceless scale pattern).  That part is the same for every board on the
panel, so it shifts every board's W alike; a constant jig rotation is the simplest case
and is simply absorbed in W (the calibration then refers to the jig's frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .models.linear import fit_linear_batch
from .sensor_model import rotation_matrix

REFERENCE_MODELS = ("6", "12", "15")
MIN_BOARDS = 4  # leave-one-out over 3 others: a board's own noise never sets its references


@dataclass
class JigPoseEstimate:
    """Per-board references after joint estimation, and what was estimated.

    references_g: (B, P, 3) each board's corrected references (its leave-one-out estimate);
    rotvec_deg: (P, 3) the jig's per-pose rotation estimated from all boards (degrees, the
    part perpendicular to each reference; zeros when not estimated);
    note: why it was not estimated (None when it was).
    """

    references_g: np.ndarray
    rotvec_deg: np.ndarray
    boards: int
    note: str | None = None

    @property
    def estimated(self) -> bool:
        return self.note is None

    @property
    def rms_deg(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.rotvec_deg**2, axis=-1))))


def _turn(refs: np.ndarray, err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate refs (..., 3) by delta with delta x r = err's part perpendicular to r: (new refs, delta rad)."""
    delta = np.cross(refs, err) / np.sum(refs**2, axis=-1, keepdims=True)
    return (rotation_matrix(np.degrees(delta)) @ refs[..., None])[..., 0], delta


def estimate_jig_poses(readings_g: np.ndarray, references_g: np.ndarray, model: str,
                       iterations: int = 3) -> JigPoseEstimate:
    """Joint per-pose jig rotation from B boards' readings (B, P, 3) in g at references (P, 3)."""
    gf = np.asarray(readings_g, dtype=float)
    ref = np.asarray(references_g, dtype=float)
    B, P = gf.shape[:2]
    refs = np.broadcast_to(ref, (B, P, 3)).copy()
    zero = np.zeros((P, 3))
    model = str(model)
    if model not in REFERENCE_MODELS:
        return JigPoseEstimate(refs, zero, B, f"model {model} has no pose references; the jig's pose error "
                                              "is not estimated (models 6, 12, 15 estimate it)")
    if B < MIN_BOARDS:
        return JigPoseEstimate(refs, zero, B, f"panel of {B} board{'s' * (B != 1)} is too small to estimate the "
                                              f"jig's per-pose rotation (needs at least {MIN_BOARDS}: each board's "
                                              "references come from the other boards)")
    panel = np.broadcast_to(ref, (P, 3)).copy()
    total = np.zeros((P, 3))
    for _ in range(iterations):
        fit = fit_linear_batch(gf, refs, model)
        ok = fit.ok
        if ok.sum() < MIN_BOARDS:
            return JigPoseEstimate(np.broadcast_to(ref, (B, P, 3)).copy(), zero, B,
                                   f"only {int(ok.sum())} boards could be fitted; the jig's per-pose rotation "
                                   f"needs at least {MIN_BOARDS}")
        err = -fit.residuals_g  # calibrated minus reference (B, P, 3)
        err = np.where(ok[:, None, None], err, 0.0)
        s, n = err.sum(axis=0), int(ok.sum())
        loo = (s - err) / np.where(ok, n - 1, n)[:, None, None]
        refs, _ = _turn(refs, loo)
        panel, d = _turn(panel, s / n)
        total += d
    return JigPoseEstimate(refs, np.degrees(total), B)

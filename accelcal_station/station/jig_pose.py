"""The jig's per-pose rotation, estimated jointly from every board of a panel.

All boards on a panel see the same true orientation at each pose: board b's reading at
pose p is the calibration model of ``R_p r_p`` (r_p the commanded reference, R_p the
jig's true, slightly wrong, rotation).  With references (models 6, 12, 15) each board's
fit leaves the part of ``R_p r_p - r_p`` its model cannot absorb in its residuals; that
part is common to all boards, while noise is not.  One linear least squares over the
*other* boards (leave one board out, so a board's own noise is never fitted back into
its references) finds the small move of each reference, perpendicular to it (a rotation),
that best explains what their fits leave; it removes the jig's per-pose scatter from
every board's residuals and acceptance figures.

What no panel can estimate: the part of the scatter that a calibration model absorbs
(for a full W: a rotation common to all poses, and for cube-vertex designs such as
an4399-8 also a traceless scale pattern).  That part is the same for every board on the
panel, so it shifts every board's W alike; a constant jig rotation is the simplest case
and is simply absorbed in W (the calibration then refers to the jig's frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.linear import regressors

REFERENCE_MODELS = ("6", "12", "15")
MIN_BOARDS = 4
# patterns every board's fit absorbs (model 12 on an4399-8: 3 rotations and 2 traceless scale
# patterns) have eigenvalues 1e-10..1e-6 of the largest: they are cut, never fitted to noise
RCOND = 1e-3  # leave-one-out over 3 others: a board's own noise never sets its references


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


def _tangents(refs: np.ndarray) -> np.ndarray:
    """Two unit vectors perpendicular to each reference (P, 2, 3): the directions a small
    rotation can move it."""
    r = refs / np.linalg.norm(refs, axis=-1, keepdims=True)
    seed = np.eye(3)[np.argmin(np.abs(r), axis=-1)]
    t1 = np.cross(r, seed)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return np.stack([t1, np.cross(r, t1)], axis=1)


def _annihilators(gf: np.ndarray, model: str) -> np.ndarray:
    """I - H per board and channel (B, 3, P, P): what of a reference pattern a board's fit cannot
    absorb (H the hat matrix of AN4399 Eqn 46's least squares on that board's readings)."""
    X = regressors(gf, model)
    H = X @ np.linalg.pinv(X)
    return np.eye(X.shape[-2]) - H


def estimate_jig_poses(readings_g: np.ndarray, references_g: np.ndarray, model: str,
                       iterations: int = 2) -> JigPoseEstimate:
    """Joint per-pose jig rotation from B boards' readings (B, P, 3) in g at references (P, 3).

    Linear least squares over all boards: the tangential move u of every reference that
    minimises sum_b |(I - H_b)(ref + T u)|^2 (min-norm: the patterns every fit absorbs are
    left alone); each board's own move leaves that board out.
    """
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
    M = _annihilators(gf, model)  # (B, 3, P, P)
    panel = ref.copy()
    for _ in range(iterations):
        T = _tangents(panel)  # (P, 2, 3): moves of pose p along its two tangents
        # A_b: (3P, 2P) columns = (I - H_b) applied per channel to each unit move
        basis = np.zeros((P, 2, P, 3))
        basis[np.arange(P), :, np.arange(P)] = T
        cols = basis.reshape(2 * P, P, 3).transpose(0, 2, 1)  # (2P, 3, P)
        A = np.einsum("bcpq,kcq->bcpk", M, cols).reshape(B, 3 * P, 2 * P)
        r0 = np.einsum("bcpq,bqc->bcp", M, refs).reshape(B, 3 * P)
        N_b = A.transpose(0, 2, 1) @ A  # (B, 2P, 2P)
        g_b = np.einsum("bkr,br->bk", A.transpose(0, 2, 1), r0)
        N, g = N_b.sum(0), g_b.sum(0)
        u_all = -np.linalg.pinv(N, rcond=RCOND) @ g
        u_loo = -np.einsum("bij,bj->bi", np.linalg.pinv(N - N_b, rcond=RCOND), g - g_b)
        refs = refs + np.einsum("bpk,pkc->bpc", u_loo.reshape(B, P, 2), T)
        panel = panel + np.einsum("pk,pkc->pc", u_all.reshape(P, 2), T)
    refs /= np.linalg.norm(refs, axis=-1, keepdims=True) / np.linalg.norm(ref, axis=-1)[None, :, None]
    panel /= np.linalg.norm(panel, axis=-1, keepdims=True) / np.linalg.norm(ref, axis=-1)[:, None]
    rotvec = np.degrees(np.cross(ref, panel) / np.sum(ref**2, axis=-1, keepdims=True))
    return JigPoseEstimate(refs, rotvec, B)

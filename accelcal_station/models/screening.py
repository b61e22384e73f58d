"""What a lot's shared design certifies about its boards' readings without comparing their poses
or forming their design matrices (``screen``): each certificate is exact (the answer
identifiability.first_of_orientation / assess_batch would give), so the lot path does per-board
work only for the boards not certified (models/fitting.fit_batch)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..identifiability import (
    APART_MARGIN_RAD,
    COEFFS,
    DISTINCT_TOL_DEG,
    REL_SV_MIN,
    SPREAD_MIN_G,
    _closest_pair_rad,
    _design,
    _shared_unit,
)


@dataclass(frozen=True)
class Screen:
    """What the boards' nominal design (their references) certifies about their readings, with
    no pose pair compared and no design matrix formed; each True is exact (the answer of
    ``first_of_orientation`` / ``assess_batch``), a False only means "not certified: compute it".

    apart (D,): every pose is the first of its orientation (``directions_apart``, and the
    readings' centre is 0, so ``first_of_orientation``'s directions are the readings' own);
    determined (D,): apart, and ``assess_batch`` finds the model determined; sq (D, P): each
    reading's squared norm, g^2 (for the plausibility and absurd-reading checks), None where
    nothing was certified (no boards-last copy made)."""

    apart: np.ndarray
    determined: np.ndarray
    sq: np.ndarray | None


def screen(gf: np.ndarray, ref: np.ndarray | None, model: str, tol_deg: float = DISTINCT_TOL_DEG) -> Screen:
    """The ``Screen`` of D boards' readings gf (D, P, 3) in g against references (P, 3) or
    (D, P, 3) (None, or references that differ between boards: nothing certified), from one
    boards-last copy of the readings.

    determined: the relative singular value sigma_min / sigma_max of the column-normalised design
    A (identifiability's test, >= REL_SV_MIN) is bounded from the references' design A_r by Weyl's
    inequality: |sigma_i(A) - sigma_i(A_r)| <= ||A - A_r||_F = e, and for unit columns a, b,
    ||a - b||^2 = 2 (1 - a.b); so rel >= (sigma_min(A_r) - e) / (sigma_max(A_r) + e)."""
    D, P, _ = gf.shape
    none = np.zeros(D, dtype=bool)
    rn = _shared_unit(ref, D)
    if rn is None or len(rn[0]) != P:  # nothing to certify: no copy made (a 200,000-pose table)
        return Screen(none, none, None)
    r, ru = rn
    g = np.ascontiguousarray(gf.transpose(2, 1, 0))  # (3, P, D): boards last
    g2 = g * g
    sq = g2.sum(axis=0)  # (P, D)
    delta = 0.5 * (_closest_pair_rad(ru) - math.radians(tol_deg)) - APART_MARGIN_RAD
    if not delta > 0:
        return Screen(none, none, sq.T)
    with np.errstate(over="ignore", invalid="ignore"):
        hi, lo = g.max(axis=1), g.min(axis=1)  # (3, D)
        mid = 0.5 * (hi + lo)
        centred = ~(np.sqrt((mid * mid).sum(axis=0)) > 0.5)  # _centre gives 0: directions about 0
        along = (g * ru.T[:, :, None]).sum(axis=0)  # (P, D) reading . unit reference
        apart = np.all(along > np.sqrt(sq) * math.cos(delta), axis=0) & centred
        determined = apart & _design_certified(g, g2, r, model) if COEFFS[model] <= P else np.zeros(D, dtype=bool)
        if model == "6":
            determined &= np.all(hi - lo >= SPREAD_MIN_G, axis=0)
    return Screen(apart, determined, sq.T)


def _design_certified(g: np.ndarray, g2: np.ndarray, r: np.ndarray, model: str) -> np.ndarray:
    """(D,) boards whose design over every pose (g (3, P, D), g2 = g * g) is certified to have a
    relative singular value >= REL_SV_MIN by the references' design r (P, 3) (``screen``)."""
    D = g.shape[2]
    if model not in ("6", "12", "15"):
        return np.zeros(D, dtype=bool)
    # per non-constant column (a function of one channel): 1 - cos(board column, reference column)
    cols = [(g, g2, r.T)]
    if model == "15":
        g3 = g2 * g
        cols.append((g3, g3 * g3, r.T ** 3))
    gap = []
    for a, a2, b in cols:  # a (3, P, D), b (3, P)
        bn = np.sqrt((b * b).sum(axis=1))  # (3,)
        with np.errstate(divide="ignore", invalid="ignore"):
            cos = (a * b[:, :, None]).sum(axis=1) / (np.sqrt(a2.sum(axis=1)) * bn[:, None])  # (3, D)
        gap.append(2.0 * (1.0 - cos))
    # the columns of each solve: 12 one solve of x, y, z, 1; 6 per channel c: c, 1; 15 per channel: x, y, z, 1, c^3
    if model == "12":
        e2 = gap[0].sum(axis=0)[None]
    elif model == "6":
        e2 = gap[0]
    else:
        e2 = gap[0].sum(axis=0)[None] + gap[1]
    X = _design(r[None], model)[0]  # (S, P, k) the references' design
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    if not np.all(norms > 0):
        return np.zeros(D, dtype=bool)
    s = np.linalg.svd(X / norms, compute_uv=False)  # (S, k) descending
    e = np.sqrt(np.maximum(e2, 0.0))  # (S, D); NaN stays NaN (not certified)
    with np.errstate(invalid="ignore"):
        bound = (s[:, -1:] - e) / (s[:, :1] + e)
        return np.all(bound >= REL_SV_MIN * (1.0 + 1e-6), axis=0)

"""What a lot's shared design certifies about its boards' readings without comparing their poses
or forming their design matrices (``screen``): each certificate is exact (the answer
identifiability.first_of_orientation / assess_batch would give), so the lot path does per-board
work only for the boards not certified (models/fitting.fit_batch)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..identifiability import COEFFS, DISTINCT_TOL_DEG, REL_SV_MIN, SMALL_P, SPREAD_MIN_G, _design
from . import boardwise as bw

APART_MARGIN_RAD = 1e-6  # far above the rounding of a cosine (1e-16), far below any pose's scatter


def directions_apart(gf: np.ndarray, ref: np.ndarray | None, tol_deg: float = DISTINCT_TOL_DEG) -> np.ndarray:
    """(D,) bool: boards whose reading directions (D, P, 3) are, for certain, pairwise more than
    ``tol_deg`` apart, certified against their references (P, 3) or (D, P, 3) instead of
    comparing every pair: the sphere's angle is a metric, so when each reading points within
    delta of its own reference and the references' closest pair is theta_min apart, every two
    readings are at least theta_min - 2 delta apart.  True only where theta_min - 2 max delta
    clears ``tol_deg`` by APART_MARGIN_RAD; False where unsure (no references, references that
    differ between boards, revisits in the design, a reading far off its reference, a zero or
    non-finite reading): there the pairs are compared (``first_of_orientation``,
    ``sanity.distinct_directions_batch``).  Every pose of a True board is the first of its
    orientation by both definitions (``>`` or ``>=`` the cosine, centred or not where the
    centre is 0), so the answer is theirs exactly."""
    D, P = gf.shape[:2]
    out = np.zeros(D, dtype=bool)
    shared = _shared_unit(ref, D)
    if shared is None or len(shared[0]) != P:
        return out
    ru = shared[1]
    delta = 0.5 * (_closest_pair_rad(ru) - math.radians(tol_deg)) - APART_MARGIN_RAD
    if not delta > 0:
        return out
    # cos(angle(x_p, r_p)) > cos(delta), as x_p . u_p > cos(delta) |x_p| (u_p the unit reference)
    with np.errstate(over="ignore", invalid="ignore"):
        along = np.einsum("dpk,pk->dp", gf, ru)
        norms = np.sqrt(np.einsum("dpk,dpk->dp", gf, gf))
        norms *= math.cos(delta)
        return np.all(along > norms, axis=1)


def _shared_unit(ref: np.ndarray | None, D: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The references (P, 3) shared by all D boards and their unit directions, or None."""
    if ref is None or D == 0:
        return None
    r = np.asarray(ref, dtype=float)
    if r.ndim == 3:
        if r.strides[0] != 0 and not np.array_equal(r, np.broadcast_to(r[0], r.shape)):
            return None  # boards of several designs: each is computed
        r = r[0]
    rn = np.sqrt(np.einsum("pk,pk->p", r, r))
    # a few poses (a fixture's design) only: the closest pair is found among P x P cosines
    if not 2 <= len(r) <= SMALL_P or not np.all(np.isfinite(rn) & (rn > 0)):
        return None
    return r, r / rn[:, None]


def _closest_pair_rad(ru: np.ndarray) -> float:
    """The angle (rad) of the closest pair of unit directions ru (P, 3), P <= SMALL_P (a P x P matrix)."""
    cosines = np.clip(ru @ ru.T, -1.0, 1.0)[np.triu_indices(len(ru), 1)]
    return float(np.arccos(np.max(cosines)))


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
    boards_last: np.ndarray | None = None  # the readings as (3, P, D), the copy screen made


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
    if model == "9":  # no references: the boards' own consensus directions stand in for them
        return _screen9(gf, tol_deg) if 2 <= P <= SMALL_P and D else Screen(none, none, None)
    rn = _shared_unit(ref, D)
    if rn is None or len(rn[0]) != P:  # nothing to certify: no copy made (a 200,000-pose table)
        return Screen(none, none, None)
    r, ru = rn
    g = bw.boards_last(gf)  # (3, P, D)
    sq = np.einsum("kpd,kpd->pd", g, g)  # (P, D) squared norms, one pass and no (3, P, D) temporary
    delta = 0.5 * (_closest_pair_rad(ru) - math.radians(tol_deg)) - APART_MARGIN_RAD
    if not delta > 0:
        return Screen(none, none, sq.T)
    with np.errstate(over="ignore", invalid="ignore"):
        hi, lo = g.max(axis=1), g.min(axis=1)  # (3, D)
        mid = 0.5 * (hi + lo)
        centred = ~(np.sqrt((mid * mid).sum(axis=0)) > 0.5)  # _centre gives 0: directions about 0
        along = np.einsum("kpd,pk->pd", g, ru)  # (P, D) reading . unit reference
        apart = np.all(along > np.sqrt(sq) * math.cos(delta), axis=0) & centred
        determined = apart & _design_certified(g, r, model) if COEFFS[model] <= P else np.zeros(D, dtype=bool)
        if model == "6":
            determined &= np.all(hi - lo >= SPREAD_MIN_G, axis=0)
    return Screen(apart, determined, sq.T, g)


def _design_certified(g: np.ndarray, r: np.ndarray, model: str) -> np.ndarray:
    """(D,) boards whose design over every pose (g (3, P, D)) is certified to have a relative
    singular value >= REL_SV_MIN by the references' design r (P, 3) (``screen``)."""
    D = g.shape[2]
    if model not in ("6", "12", "15"):
        return np.zeros(D, dtype=bool)
    # per non-constant column (a function of one channel): 1 - cos(board column, reference column)
    cols = [(g, r.T)]
    if model == "15":
        cols.append((g * g * g, r.T ** 3))
    gap = []
    for a, b in cols:  # a (3, P, D), b (3, P)
        bn = np.sqrt((b * b).sum(axis=1))  # (3,)
        with np.errstate(divide="ignore", invalid="ignore"):
            an = np.sqrt(np.einsum("kpd,kpd->kd", a, a))  # (3, D) the board columns' norms
            cos = np.einsum("kpd,kp->kd", a, b) / (an * bn[:, None])  # (3, D)
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


CONSENSUS_BOARDS = 1024  # boards whose mean directions stand in for model 9's references


def _screen9(gf: np.ndarray, tol_deg: float) -> Screen:
    """``screen`` for model 9, which has no references: the certificates hold for any set of
    reference directions (the triangle inequality on the sphere, Weyl's inequality), so the
    boards' consensus (each pose's mean unit direction over the stack) stands in for them; a
    stack whose boards do not share a design certifies nothing and is computed pose by pose.

    determined: the normalised design's columns (u_x^2, u_y^2, u_z^2, 2 u_x u_y, 2 u_x u_z,
    2 u_y u_z, u_x, u_y, u_z of the unit directions u, identifiability._design) against the
    consensus design's, as for the linear models."""
    D, P, _ = gf.shape
    none = np.zeros(D, dtype=bool)
    g = bw.boards_last(gf)  # (3, P, D)
    sq = (g * g).sum(axis=0)  # (P, D)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        hi, lo = g.max(axis=1), g.min(axis=1)
        mid = 0.5 * (hi + lo)
        centred = ~(np.sqrt((mid * mid).sum(axis=0)) > 0.5)  # _centre gives 0: directions are the readings'
        u = g / np.sqrt(sq)
        # any directions serve: the first CONSENSUS_BOARDS centred boards' mean is enough
        some = u[:, :, :CONSENSUS_BOARDS]
        if not (centred[:CONSENSUS_BOARDS].all() and np.isfinite(some).all()):
            keep = centred & np.isfinite(u).all(axis=(0, 1))
            some = u[:, :, np.flatnonzero(keep)[:CONSENSUS_BOARDS]]
        mean = np.median(some, axis=2) if some.shape[2] else np.full((3, P), np.nan)  # an odd board moves it little
        ru = (mean / np.sqrt((mean * mean).sum(axis=0))).T  # (P, 3) consensus unit directions
    if not np.all(np.isfinite(ru)):
        return Screen(none, none, sq.T)
    delta = 0.5 * (_closest_pair_rad(ru) - math.radians(tol_deg)) - APART_MARGIN_RAD
    if not delta > 0:
        return Screen(none, none, sq.T)
    with np.errstate(over="ignore", invalid="ignore"):
        along = (g * ru.T[:, :, None]).sum(axis=0)  # (P, D) reading . consensus direction
        apart = np.all(along > np.sqrt(sq) * math.cos(delta), axis=0) & centred
    determined = apart & _design9_certified(u, ru) if COEFFS["9"] <= P else none
    return Screen(apart, determined, sq.T)


def _norm_columns(u: np.ndarray) -> list[np.ndarray]:
    """Model 9's design columns of unit directions u (3, P, ...): identifiability._design's order."""
    return [u[0] * u[0], u[1] * u[1], u[2] * u[2], 2 * u[0] * u[1], 2 * u[0] * u[2], 2 * u[1] * u[2], u[0], u[1], u[2]]


def _design9_certified(u: np.ndarray, ru: np.ndarray) -> np.ndarray:
    """(D,) boards whose model 9 design (unit directions u (3, P, D)) has a relative singular
    value >= REL_SV_MIN by the consensus design of ru (P, 3) and Weyl's inequality (``screen``)."""
    B = np.stack(_norm_columns(ru.T), axis=1)  # (P, 9)
    bn = np.sqrt((B * B).sum(axis=0))
    if not np.all(bn > 0):
        return np.zeros(u.shape[2], dtype=bool)
    e2 = np.zeros(u.shape[2])
    with np.errstate(divide="ignore", invalid="ignore"):
        for c, a in enumerate(_norm_columns(u)):  # a (P, D): 2 (1 - cos(board column, consensus column))
            e2 += 2.0 * (1.0 - (B[:, c] @ a) / (np.sqrt(np.einsum("pd,pd->d", a, a)) * bn[c]))
    s = np.linalg.svd(B / bn, compute_uv=False)
    e = np.sqrt(np.maximum(e2, 0.0))  # NaN stays NaN (not certified)
    with np.errstate(invalid="ignore"):
        return (s[-1] - e) / (s[0] + e) >= REL_SV_MIN * (1.0 + 1e-6)

"""Cross-validation by orientation: leave out every pose of one distinct orientation at a time.

Leave-one-pose-out (the fitters' ``crossval_rms_g``) is optimistic when orientations are
revisited: the left-out pose's twins stay in the fit and pin the model where it is tested.
Here the poses are grouped into distinct orientations (identifiability.DISTINCT_TOL_DEG: a
pose within 5 degrees of an earlier one is a revisit of it), each group is left out in turn,
the model is refitted on the rest with the same held terms (the fold fitter given by the
caller, models/fitting.py) and the left-out poses are predicted:

  models 6, 12, 15   reference - (W g + V + Gamma g^3), every axis   RMS over 3 x P components
  model 9            |W g + V| - 1 g                                   RMS over P poses

the same residuals and averaging as the fitters' leave-one-pose-out, so where no orientation
repeats the two are the same figure (and it is taken from the fitters, not refitted).  Each fold
is a refit, so boards sharing one grouping of poses (a lot's design) are refitted together, and a
board with more than MAX_FOLDS distinct orientations among revisits, or more than MAX_POSES
poses, is not cross-validated this way (NaN, ``ok`` False).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..identifiability import DISTINCT_TOL_DEG, _centre, distinct_count, first_of_orientation
from .result import BatchFit

MAX_FOLDS = 256  # refits per board
MAX_POSES = 2048  # the pose-pair cosines of one board held at once
PAIRS_AT_ONCE = 1 << 22  # pose-pair cosines formed at once (32 MB of float64): memory linear in the boards

# fold_fit(rows, keep): the fit of boards ``rows`` on poses ``keep`` only, with their held terms
FoldFit = Callable[[np.ndarray, np.ndarray], BatchFit]


def orientation_labels(gf: np.ndarray, tol_deg: float = DISTINCT_TOL_DEG) -> np.ndarray:
    """(D, P) int: each pose's orientation, the index of the first pose of it (a pose within
    ``tol_deg`` of an earlier pose takes that pose's label; revisits of revisits chain)."""
    x = gf - _centre(gf)[..., None, :]
    u = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    D, P = u.shape[:2]
    close = np.einsum("dpi,dqi->dpq", u, u) > math.cos(math.radians(tol_deg))
    close &= np.tri(P, P, -1, dtype=bool)[None]  # only earlier poses
    labels = np.tile(np.arange(P), (D, 1))
    has = close.any(axis=2)
    first = np.argmax(close, axis=2)
    for p in range(P):  # earlier labels are final when p is reached
        labels[:, p] = np.where(has[:, p], labels[np.arange(D), first[:, p]], p)
    return labels


def _held_out(fit: BatchFit, g: np.ndarray, ref: np.ndarray | None) -> np.ndarray:
    """Squared held-out residuals (D, Q) summed over their components, of poses g (D, Q, 3)."""
    out = np.einsum("dij,dqj->dqi", fit.W, g) + fit.V[:, None, :] + fit.Gamma[:, None, :] * g**3
    if ref is None:
        return (np.linalg.norm(out, axis=-1) - 1.0) ** 2
    return np.sum((ref - out) ** 2, axis=-1)


def crossval_by_orientation(gf: np.ndarray, ref: np.ndarray | None, model: str, fold_fit: FoldFit,
                            loo_rms: np.ndarray, loo_ok: np.ndarray, first: np.ndarray | None = None
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rms (D,), ok (D,), distinct orientations (D,)) of D boards' readings gf (D, P, 3) in g
    (module doc); ``ref`` (D, P, 3) the references of models 6/12/15 (None: model 9); ``first``:
    gf's first_of_orientation when the caller has it."""
    D, P, _ = gf.shape
    rms, ok = np.array(loo_rms, dtype=float, copy=True), np.array(loo_ok, dtype=bool, copy=True)
    first = first_of_orientation(gf) if first is None else first  # cheap, blocked: most lots revisit nothing
    distinct = distinct_count(first)
    rep = np.flatnonzero(distinct < P)
    if not rep.size:
        return rms, ok, distinct
    if P > MAX_POSES:
        rms[rep], ok[rep] = np.nan, False
        return rms, ok, distinct
    step = max(1, PAIRS_AT_ONCE // (P * P))
    labels = np.concatenate([orientation_labels(gf[rep[a:a + step]]) for a in range(0, len(rep), step)])
    patterns, inverse = np.unique(labels, axis=0, return_inverse=True)
    for k, pattern in enumerate(patterns):
        rows = rep[np.asarray(inverse).reshape(-1) == k]
        groups = np.unique(pattern)
        if len(groups) > MAX_FOLDS:
            rms[rows], ok[rows] = np.nan, False
            continue
        sq, good = np.zeros(len(rows)), np.ones(len(rows), dtype=bool)
        for grp in groups:
            out = pattern == grp
            fit = fold_fit(rows, ~out)
            r = None if ref is None else ref[rows][:, out]
            with np.errstate(over="ignore", invalid="ignore"):
                sq += _held_out(fit, gf[rows][:, out], r).sum(axis=1)
            good &= np.asarray(fit.ok, dtype=bool)
        n = P if ref is None else 3 * P
        ok[rows] = good & np.isfinite(sq)
        rms[rows] = np.where(ok[rows], np.sqrt(sq / n), np.nan)
    return rms, ok, distinct


def held_out_by_orientation(gf: np.ndarray, ref: np.ndarray | None, fold_fit: FoldFit
                            ) -> tuple[np.ndarray, np.ndarray]:
    """(sq (D, K), ok (D, K)): each board's squared held-out residual summed over the poses of each
    of its K distinct orientations, that orientation left out and the rest refitted by ``fold_fit``
    (the module doc's residuals); the boards share one grouping of poses (a lot's design, or one
    board), K at most MAX_FOLDS.  ``ok`` False where a fold's fit failed (sq NaN there)."""
    D = len(gf)
    pattern = orientation_labels(gf[:1])[0]
    groups = np.unique(pattern)[:MAX_FOLDS]
    sq, ok = np.full((D, len(groups)), np.nan), np.zeros((D, len(groups)), dtype=bool)
    rows = np.arange(D)
    for k, grp in enumerate(groups):
        out = pattern == grp
        fit = fold_fit(rows, ~out)
        with np.errstate(over="ignore", invalid="ignore"):
            e = _held_out(fit, gf[:, out], None if ref is None else ref[:, out]).sum(axis=1)
        ok[:, k] = np.asarray(fit.ok, dtype=bool) & np.isfinite(e)
        sq[:, k] = np.where(ok[:, k], e, np.nan)
    return sq, ok


SCATTER_Z = 2.5  # one-sided: t with 5 degrees of freedom (six orientations) exceeds 2.5 with probability 2.7 %


@dataclass(frozen=True)
class HeldOutComparison:
    """Fit b against fit a on the same held-out orientations (``compare_held_out``).

    rms_*_g: the leave-one-orientation-out RMS of each (NaN: a fold not computable); diff_g2: the
    mean over orientations of b's squared held-out residual minus a's; se_g2: its standard error
    from the orientations' own scatter, std(d_k) / sqrt(K)."""

    rms_a_g: float
    rms_b_g: float
    diff_g2: float
    se_g2: float
    orientations: int

    @property
    def b_worse(self) -> bool:
        """b is worse beyond the held-out figures' scatter: not computable where a is, or its mean
        excess squared residual above SCATTER_Z standard errors (a paired test over orientations)."""
        if not math.isfinite(self.rms_b_g):
            return math.isfinite(self.rms_a_g)
        if not math.isfinite(self.rms_a_g) or self.orientations < 3:
            return False
        return self.diff_g2 > SCATTER_Z * self.se_g2

    def b_far_worse(self, ratio: float) -> bool:
        """``b_worse``, or b's held-out RMS above ``ratio`` times a's (a difference carried by one or two
        orientations has a wide scatter, yet is far worse for the design's own poses)."""
        return self.b_worse or (math.isfinite(self.rms_b_g) and self.rms_b_g > ratio * self.rms_a_g)

    @property
    def text(self) -> str:
        def mg(v: float) -> str:
            return f"{v * 1e3:.3f} mg" if math.isfinite(v) else "n/a (a fold leaves it undetermined)"

        return (f"{mg(self.rms_b_g)} against {mg(self.rms_a_g)} left out by orientation "
                f"({self.orientations} orientations)")


def compare_held_out(sq_a: np.ndarray, sq_b: np.ndarray, components: int) -> HeldOutComparison:
    """Compare two fits' per-orientation squared held-out residuals (K,) of one board
    (``held_out_by_orientation``); ``components`` the residuals averaged (3 P for models
    6/12/15, P for model 9), as the fits' own cross-validation RMS averages them."""
    K = len(sq_a)
    rms = [float(np.sqrt(np.sum(s) / components)) if np.all(np.isfinite(s)) else math.nan for s in (sq_a, sq_b)]
    d = sq_b - sq_a
    if not np.all(np.isfinite(d)) or K < 2:
        return HeldOutComparison(rms[0], rms[1], math.nan, math.nan, K)
    return HeldOutComparison(rms[0], rms[1], float(np.mean(d)), float(np.std(d, ddof=1) / math.sqrt(K)), K)


__all__ = ["MAX_FOLDS", "MAX_POSES", "SCATTER_Z", "HeldOutComparison", "compare_held_out", "crossval_by_orientation",
           "held_out_by_orientation", "orientation_labels"]

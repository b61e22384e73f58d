"""Fits that must never be written: absurd readings, degenerate pose sets, absurd coefficients.

These are physical bounds, not acceptance limits: they hold for any accelerometer read
in g, whatever a configuration's limits say, so a config that leaves a limit out can
never let a degenerate calibration through.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

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


def distinct_directions_batch(readings_g: np.ndarray, tol_deg: float = DISTINCT_DEG,
                              apart: np.ndarray | None = None) -> np.ndarray:
    """``distinct_directions`` of each of B boards' (B, P, 3) readings, the same greedy
    clustering stepped over the poses for all boards at once; (B,) counts.  ``apart`` (B,):
    models.screening.directions_apart of these readings: those boards' P poses are all distinct
    (no pair is compared), the others are clustered."""
    x = np.asarray(readings_g, dtype=float)
    if apart is not None and x.ndim == 3 and np.any(apart):
        out = np.full(len(x), x.shape[1], dtype=np.intp)
        rest = np.flatnonzero(~apart)
        if rest.size:
            out[rest] = distinct_directions_batch(x[rest], tol_deg)
        return out
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    u = x / np.where(n > 0, n, 1.0)
    cos = np.cos(np.radians(tol_deg))
    B, P, _ = u.shape
    ut = np.ascontiguousarray(u.transpose(1, 2, 0))  # (P, 3, B): boards last, each step a few long ufunc calls
    is_rep = np.zeros((P, B), bool)
    for p in range(P):
        dots = ut[:p, 0] * ut[p, 0]
        dots += ut[:p, 1] * ut[p, 1]
        dots += ut[:p, 2] * ut[p, 2]
        is_rep[p] = ~np.any(is_rep[:p] & (dots >= cos), axis=0)
    return is_rep.sum(axis=0)


def poses_needed(model: str) -> int:
    """Distinct poses a judged run needs: the model's unknowns per axis plus one, so that
    leaving any one pose out still determines it (cross-validation is always measurable)."""
    return PARAMS_PER_AXIS[str(model)] + 1


@dataclass(frozen=True)
class Refusal:
    """Which of D boards a check refuses (``mask`` (D,) bool) and why: the words are formatted
    only for the boards refused (``why``), so a clean chunk costs no per-board Python."""

    mask: np.ndarray  # (D,) bool
    _words: Callable[[int], str]

    def why(self, d: int | np.integer) -> str:
        """'' or the reason board ``d`` is refused."""
        return self._words(int(d)) if self.mask[d] else ""

    def reasons(self) -> list[str]:
        """(D,) '' or the reason, per board (formats only the refused ones)."""
        out = [""] * len(self.mask)
        for d in np.flatnonzero(self.mask):
            out[d] = self._words(int(d))
        return out


def absurd_readings(gf: np.ndarray, sq: np.ndarray | None = None) -> Refusal:
    """Boards of (D, P, 3) readings in g with a pose whose norm is not a reading of gravity
    (outside READING_NORM_G), over the whole stack at once; ``sq`` (D, P): the squared norms
    when the caller has them."""
    lo, hi = READING_NORM_G
    with np.errstate(over="ignore", invalid="ignore"):  # 1e308 squared is inf: still refused
        # every norm well inside (the usual chunk; the margin covers the squares' rounding): none refused
        if sq is not None and np.all((sq >= lo * lo * (1 + 1e-9)) & (sq <= hi * hi * (1 - 1e-9))):
            return Refusal(np.zeros(len(gf), dtype=bool), str)
        norms = np.sqrt(np.einsum("dpk,dpk->dp", gf, gf))
    bad = ~((norms >= lo) & (norms <= hi))
    first = np.argmax(bad, axis=1)

    def words(d: int) -> str:
        return (f"pose {first[d] + 1} reads {norms[d, first[d]]:.4g} g; a reading of gravity is "
                f"{lo:g} to {hi:g} g (damaged data or a saturated axis)")
    return Refusal(bad.any(axis=1), words)


def _sym3_extreme_eigenvalues(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest and smallest eigenvalue of each symmetric (D, 3, 3) A in closed form (Smith 1961:
    the trigonometric roots of the characteristic cubic of (A - q I) / p, q = tr A / 3)."""
    a, d, f = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    b, c, e = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    q = (a + d + f) / 3.0
    p = np.sqrt(((a - q) ** 2 + (d - q) ** 2 + (f - q) ** 2 + 2.0 * (b * b + c * c + e * e)) / 6.0)
    ps = np.where(p > 0, p, 1.0)
    a1, d1, f1, b1, c1, e1 = (a - q) / ps, (d - q) / ps, (f - q) / ps, b / ps, c / ps, e / ps
    r = 0.5 * (a1 * (d1 * f1 - e1 * e1) - b1 * (b1 * f1 - e1 * c1) + c1 * (b1 * e1 - d1 * c1))
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    return q + 2.0 * p * np.cos(phi), q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)


def condition_numbers(W: np.ndarray) -> np.ndarray:
    """2-norm condition number sigma_max / sigma_min of each (D, 3, 3) W (inf where singular or
    not finite): sqrt of the extreme eigenvalues' ratio of W^T W in closed form over the stack;
    near or above COND_MAX, where a verdict and its words depend on it, by LAPACK's SVD."""
    W = np.asarray(W, dtype=float)
    finite = np.isfinite(W).all(axis=(-2, -1))
    Wf = np.where(finite[:, None, None], W, np.eye(3))
    hi, lo = _sym3_extreme_eigenvalues(np.matmul(Wf.swapaxes(1, 2), Wf))
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.sqrt(hi / lo)
    unsure = np.flatnonzero(finite & ~((lo > 0) & (cond < 0.9 * COND_MAX)))
    if unsure.size:
        s = np.linalg.svd(Wf[unsure], compute_uv=False)  # (n, 3) descending
        with np.errstate(divide="ignore", invalid="ignore"):
            cond[unsure] = np.where(s[:, -1] > 0, s[:, 0] / np.where(s[:, -1] > 0, s[:, -1], 1.0), np.inf)
    return np.where(finite, cond, np.inf)


def _first_code(*conds: np.ndarray | np.bool_) -> np.ndarray:
    """(D,) 0 where no condition holds, else 1 + the index of the first that does."""
    stack = np.stack(conds)  # (k, D)
    if not stack.any():  # the usual chunk: nothing refused
        return np.zeros(stack.shape[1], dtype=np.intp)
    return np.where(stack.any(axis=0), np.argmax(stack, axis=0) + 1, 0)


def absurd_coefficients(W: np.ndarray, V: np.ndarray) -> Refusal:
    """Boards of (D, 3, 3) W and (D, 3) V whose calibration is physically absurd: non-finite,
    a gain outside GAIN_RANGE, a cross-axis term over CROSS_MAX, cond(W) over COND_MAX or an
    offset over OFFSET_MAX_G (the first that applies names the reason)."""
    W, V = np.asarray(W, dtype=float), np.asarray(V, dtype=float)
    D = len(W)
    if _all_sane(W, V):  # the usual stack: a few reductions over it clear every board
        return Refusal(np.zeros(D, dtype=bool), lambda d: "")
    # boards last (9, D) and (3, D), copied once: every step below is a few long contiguous rows,
    # no reduction over a short axis and no strided pass
    Wt, Vt = np.ascontiguousarray(W.reshape(D, 9).T), np.ascontiguousarray(V.T)
    with np.errstate(over="ignore", invalid="ignore"):  # one sum clears most stacks
        finite = np.ones(D, dtype=bool) if np.isfinite(Wt.sum() + Vt.sum()) else \
            np.isfinite(Wt).all(axis=0) & np.isfinite(Vt).all(axis=0)
    if not finite.all():
        Wt = np.where(finite, Wt, np.eye(3).reshape(9, 1))
        Vt = np.where(finite, Vt, 0.0)
    diag = Wt[[0, 4, 8]]  # (3, D)
    cross = np.abs(Wt[[1, 2, 3, 5, 6, 7]]).max(axis=0)
    # ||W - I||_F = e bounds every singular value of W within 1 +- e, so cond(W) <= (1 + e) / (1 - e):
    # at most 9 for e <= 0.8 (every real calibration); the condition number is formed for the rest only
    dd = diag - 1.0
    e = np.sqrt((dd * dd).sum(axis=0) + (Wt[[1, 2, 3, 5, 6, 7]] ** 2).sum(axis=0))
    cond = np.ones(D)
    far = np.flatnonzero(~(e <= 0.8))
    if far.size:
        cond[far] = condition_numbers(Wt[:, far].T.reshape(-1, 3, 3))
    offset = np.abs(Vt).max(axis=0)
    code = _first_code(~finite, ((diag < GAIN_RANGE[0]) | (diag > GAIN_RANGE[1])).any(axis=0),
                       cross > CROSS_MAX, cond > COND_MAX, offset > OFFSET_MAX_G)
    diag = diag.T

    def words(d: int) -> str:
        return [
            "the fit gave non-finite coefficients",
            f"gains W diagonal {np.round(diag[d], 4).tolist()} outside {GAIN_RANGE[0]:g} to {GAIN_RANGE[1]:g}: "
            "the poses do not exercise every axis (degenerate pose set)",
            f"cross-axis term {cross[d]:.3g} > {CROSS_MAX:g}: degenerate pose set",
            f"W condition number {cond[d]:.3g} > {COND_MAX:g}: degenerate pose set",
            f"offset {offset[d]:.3g} g > {OFFSET_MAX_G:g} g: absurd calibration"][code[d] - 1]
    return Refusal(code > 0, words)


def _all_sane(W: np.ndarray, V: np.ndarray) -> bool:
    """True when no board of W (D, 3, 3), V (D, 3) can be absurd (absurd_coefficients's tests,
    over the whole stack at once): every entry of W - I within 0.8 / 3, so every gain within
    GAIN_RANGE, every cross-axis term under CROSS_MAX and ||W - I||_F <= 0.8, so cond(W) <=
    (1 + 0.8) / (1 - 0.8) = 9 < COND_MAX; every offset within OFFSET_MAX_G.  A NaN or an
    infinity fails a comparison: the boards are then judged one by one."""
    if not len(W):
        return True
    d = W - _EYE3  # in W's own memory order (the stacked fitters' W is boards last): no copy, no per-board row
    with np.errstate(invalid="ignore"):
        return bool(max(d.max(), -d.min()) <= 0.8 / 3 and max(V.max(), -V.min()) <= OFFSET_MAX_G)


_EYE3 = np.eye(3)
assert GAIN_RANGE[0] <= 1 - 0.8 / 3 and GAIN_RANGE[1] >= 1 + 0.8 / 3 and CROSS_MAX >= 0.8 / 3 and COND_MAX > 9


def absurd_norm_model(W: np.ndarray, norm_error_g: np.ndarray) -> Refusal:
    """Model 9 (any raw offset): boards whose fit is absurd -- a singular or non-finite W,
    or a calibrated pose whose norm is not near 1 g (the fit did not converge on gravity)."""
    W, ne = np.asarray(W, dtype=float), np.asarray(norm_error_g, dtype=float)
    finite = np.isfinite(W).all(axis=(1, 2)) & np.isfinite(ne).all(axis=1)
    cond = condition_numbers(np.where(finite[:, None, None], W, np.eye(3)))
    worst = np.abs(np.where(finite[:, None], ne, 0.0)).max(axis=1, initial=0.0)
    code = _first_code(~finite, cond > COND_MAX, worst > READING_NORM_G[0])

    def words(d: int) -> str:
        return ["the fit gave non-finite coefficients",
                f"W condition number {cond[d]:.3g} > {COND_MAX:g}: degenerate pose set",
                f"a calibrated pose is {worst[d]:.3g} g off 1 g: damaged data"][code[d] - 1]
    return Refusal(code > 0, words)

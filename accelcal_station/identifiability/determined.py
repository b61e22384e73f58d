"""Can the data determine a model?  Judged from the poses themselves, before fitting.

The poses are first grouped into distinct orientations (orientations.py).  The design is then the
model's regressors over those orientations:

  6   per channel c: [g_c, 1]                     (AN4399 Eqns 6-17)
  12  [g_x, g_y, g_z, 1]                          (AN4399 Eqn 46's X)
  15  [g_x, g_y, g_z, 1, g_c^3] per channel       (AN4399 Eqns 67-72)
  9   the norm model linearised at M = I, B = 0:  |u|' = [u_x^2, u_y^2, u_z^2, 2u_xu_y,
      2u_xu_z, 2u_yu_z, u_x, u_y, u_z] for each unit direction u (nine-position paper)

A model is determined when there are at least as many distinct orientations as
coefficients per solve and no column of the (column-normalised) design is close to a
combination of the others.  The reason a model is refused is said in words.

``assess_batch`` is vectorised for `accelcal batch`; ``assess`` is one board.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UnderdeterminedError
from .orientations import _centre, distinct_count, first_of_orientation

SPREAD_MIN_G = 0.25  # a channel must see gravity change by this much for its gain (model 6)
REL_SV_MIN = 0.05  # smallest / largest singular value of the normalised design
COEFFS = {"6": 2, "12": 4, "15": 5, "9": 9}  # coefficients per least-squares solve
PARAMS = {"6": 6, "12": 12, "15": 15, "9": 9}
AXES = "xyz"


@dataclass(frozen=True)
class Identifiability:
    """Whether ``model`` is determined by the poses, and how well.

    distinct: distinct orientations among ``poses``; dof: distinct orientations minus the
    coefficients of one solve (per channel for 6/12/15); barely: determined with so few
    spare orientations that one bad pose moves the fit (dof < max(2, coefficients / 4)).
    """

    model: str
    poses: int
    distinct: int
    coefficients: int
    determined: bool
    reason: str

    @property
    def dof(self) -> int:
        return self.distinct - self.coefficients

    @property
    def barely(self) -> bool:
        return self.determined and self.dof < max(2, math.ceil(self.coefficients / 4))


def _design(gf: np.ndarray, model: str) -> np.ndarray:
    """Regressors per solve, (D, S, P, k): S = 3 channels for 6/15, 1 for 12 and 9."""
    D, P, _ = gf.shape
    ones = np.ones((D, P, 1))
    if model == "6":
        return np.stack([gf, np.ones_like(gf)], axis=-1).transpose(0, 2, 1, 3)
    if model == "9":
        x = gf - _centre(gf)[:, None, :]
        u = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
        ux, uy, uz = u[..., 0], u[..., 1], u[..., 2]
        J = np.stack([ux**2, uy**2, uz**2, 2 * ux * uy, 2 * ux * uz, 2 * uy * uz, ux, uy, uz], axis=-1)
        return J[:, None]
    base = np.concatenate([gf, ones], axis=-1)[:, None]
    if model == "12":
        return base
    cubic = (gf**3).transpose(0, 2, 1)[..., None]
    return np.concatenate([np.broadcast_to(base, (D, 3, P, 4)), cubic], axis=-1)


def _design_t(gf: np.ndarray, model: str) -> np.ndarray:
    """``_design`` boards last: (S, k, P, D), so the Gram matrix is sums of P contiguous rows."""
    D, P, _ = gf.shape
    g = np.ascontiguousarray(gf.transpose(2, 1, 0))  # (3, P, D)
    if model == "9":  # _design's norm-model columns, formed boards last (no stack, no transposed copy)
        mid = 0.5 * (g.max(axis=1) + g.min(axis=1))  # (3, D): _centre, boards last
        far = np.sqrt((mid * mid).sum(axis=0)) > 0.5
        x = g - np.where(far, mid, 0.0)[:, None, :]
        u = x / np.maximum(np.sqrt((x * x).sum(axis=0)), 1e-12)
        out = np.empty((1, 9, P, D))
        out[0, :3] = u * u
        out[0, 3], out[0, 4], out[0, 5] = 2 * u[0] * u[1], 2 * u[0] * u[2], 2 * u[1] * u[2]
        out[0, 6:] = u
        return out
    if model == "6":
        out = np.empty((3, 2, P, D))
        out[:, 0] = g
        out[:, 1] = 1.0
        return out
    k = 4 if model == "12" else 5
    S = 1 if model == "12" else 3
    out = np.empty((S, k, P, D))
    out[:, :3] = g
    out[:, 3] = 1.0
    if model == "15":
        out[:, 4] = g**3
    return out


def _rel_sv_floor(A: np.ndarray) -> np.ndarray:
    """A lower bound (N,) on sqrt(lambda_min / lambda_max) of N symmetric (k, k) matrices with unit
    diagonal, given boards last as A (k, k, N), elementwise over the boards (no LAPACK call per
    board): lambda_min >= 1 / tr(Gn^-1), tr(Gn^-1) the squared Frobenius norm of L^-1 (Gn = L L^T,
    Cholesky by columns), and lambda_max <= the largest absolute row sum (Gershgorin).  0 where
    Gn is not positive definite."""
    k, N = A.shape[0], A.shape[2]
    L = np.zeros_like(A)
    ok = np.ones(N, dtype=bool)
    for j in range(k):
        s = A[j, j] - np.einsum("kn,kn->n", L[j, :j], L[j, :j])
        ok &= s > 1e-12
        r = 1.0 / np.sqrt(np.where(ok, s, 1.0))
        L[j, j] = np.where(ok, s, 1.0) * r
        L[j + 1:, j] = (A[j + 1:, j] - np.einsum("ikn,kn->in", L[j + 1:, :j], L[j, :j])) * r
    Li = np.zeros_like(L)  # L^-1 by forward substitution
    for i in range(k):
        Li[i, i] = 1.0 / L[i, i]
        if i:
            Li[i, :i] = -np.einsum("kn,kjn->jn", L[i, :i], Li[:i, :i]) / L[i, i]
    tr_inv = np.einsum("ijn,ijn->n", Li, Li)
    lmax = np.abs(A).sum(axis=0).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok & np.isfinite(tr_inv), np.sqrt(1.0 / (tr_inv * lmax)), 0.0)


def _rel_sv(Xt: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Smallest / largest singular value (D,) of the column-normalised design Xt (S, k, P, D)
    over distinct orientations (``first`` (D, P)), the min over the S solves; exact where it may
    fall below REL_SV_MIN; above, possibly a lower bound (``_rel_sv_floor``) that already clears
    it, so a well-posed chunk makes no LAPACK call per board."""
    S, k, P, D = Xt.shape
    if not first.all():  # revisits count once: zeroed rows
        Xt = Xt * first.T
    # the Gram matrix (S, k, k, D) as k (k + 1) / 2 products summed over the poses, boards last:
    # no small matmul per board
    G = np.empty((S, k, k, D))
    for i in range(k):
        for j in range(i, k):
            G[:, i, j] = (Xt[:, i] * Xt[:, j]).sum(axis=1)
            G[:, j, i] = G[:, i, j]
    d = np.sqrt(np.einsum("siid->sid", G))  # column norms
    d = np.where(d > 0, d, 1.0)
    # the normalised design's singular values squared are the eigenvalues of D^-1 G D^-1; at the
    # REL_SV_MIN threshold their ratio is ~2.5e-3, far above the Gram form's rounding (~1e-16)
    A = (G / (d[:, :, None] * d[:, None, :])).transpose(1, 2, 0, 3).reshape(k, k, S * D)
    rel = _rel_sv_floor(A)
    # a non-finite design (a reading overflowing, 1e300) is not determined: no LAPACK call on it
    unsure = np.flatnonzero((rel < REL_SV_MIN) & np.isfinite(A).all(axis=(0, 1)))
    if unsure.size:
        w = np.linalg.eigvalsh(np.ascontiguousarray(A[:, :, unsure].transpose(2, 0, 1)))  # ascending
        rel[unsure] = np.sqrt(np.maximum(w[:, 0], 0.0) / np.maximum(w[:, -1], 1e-300))
    return np.min(rel.reshape(S, D), axis=0)


def assess_batch(gf: ArrayLike, model: str, first: np.ndarray | None = None, sure: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised check of D boards: (determined (D,) bool, distinct orientations (D,) int).

    gf: (D, P, 3) uncalibrated readings in (about) g; ``first``: their ``first_of_orientation``
    when the caller has it already; ``sure`` (D,): boards already certified determined
    (``screen``), whose design is not formed.  ``assess`` says why a board fails.
    """
    gf = np.asarray(gf, dtype=float)
    model = str(model)
    k = COEFFS[model]
    first = first_of_orientation(gf) if first is None else first
    distinct = distinct_count(first)
    if sure is not None and np.any(sure):
        ok = np.array(sure, dtype=bool, copy=True)
        rest = np.flatnonzero(~ok)
        if rest.size:
            ok[rest] = assess_batch(gf[rest], model, first[rest])[0]
        return ok, distinct
    ok = distinct >= k
    ok &= _rel_sv(_design_t(gf, model), first) >= REL_SV_MIN
    if model == "6":
        spread = gf.max(axis=1) - gf.min(axis=1)
        ok &= np.all(spread >= SPREAD_MIN_G, axis=-1)
    return ok, distinct


def _alignment(gf: np.ndarray) -> str | None:
    """'along one axis (x)' / 'in one plane (normal ...)' when the directions span < 3 dims."""
    if len(gf) < 2:
        return None
    _, s, vt = np.linalg.svd(gf - gf.mean(axis=0), full_matrices=False)  # affine: the models have an offset
    s = np.concatenate([s, np.zeros(3 - len(s))])
    if s[1] < 0.15 * s[0]:
        axis = int(np.argmax(np.abs(vt[0])))
        return f"every pose is along one axis ({AXES[axis]} up or down)"
    if s[2] < 0.1 * s[0]:
        n = vt[2]
        return f"every pose lies in one plane (normal {n[0]:+.2f}, {n[1]:+.2f}, {n[2]:+.2f})"
    return None


def _reason(gf: np.ndarray, model: str, distinct: int, first: np.ndarray) -> str:
    P, k = len(gf), COEFFS[model]
    seen = f"{distinct} distinct orientation{'s' if distinct != 1 else ''}" + \
        (f" among {P} poses (revisits add no information)" if distinct < P else "")
    if model == "9":
        if distinct < 9:
            return f"{seen}; the 9-parameter norm model needs at least 9 well spread"
        return (f"{seen}, but they are not spread enough to determine the 9-parameter norm model "
                f"({_alignment(gf[first]) or 'too close together'}); add poses in other directions")
    if model == "6":
        spread = gf.max(axis=0) - gf.min(axis=0)
        flat = [AXES[c] for c in range(3) if spread[c] < SPREAD_MIN_G]
        if flat:
            where = _alignment(gf[first])
            return (f"{where + ': ' if where else ''}the {', '.join(flat)} gain{'s are' if len(flat) > 1 else ' is'} "
                    f"not determined (gravity on {', '.join(flat)} changes by less than {SPREAD_MIN_G:g} g "
                    f"across the poses); model 6 needs each axis both up and down")
    if distinct < k:
        return f"{seen}; model {model} needs at least {k} poses in distinct orientations"
    spread = gf.max(axis=0) - gf.min(axis=0)
    for c in range(3):
        if spread[c] < 0.05:  # a stuck channel or no tilt of that axis at all
            return (f"channel {AXES[c]} has no spread across the {P} poses (all within {spread[c]:.3f} g): "
                    f"add poses that tilt the {AXES[c]} axis toward and away from gravity")
    where = _alignment(gf[first])
    if where:
        return f"{where}: model {model} needs poses out of it ({seen})"
    if model == "15":
        g = gf[first]
        near = np.all((np.abs(np.abs(g) - 1) < 0.1) | (np.abs(g) < 0.1), axis=0)
        if np.any(near):
            return ("a cubic cannot be told from the gain when every reading is about +-1 g or 0 "
                    f"(channel{'s' if near.sum() > 1 else ''} {', '.join(AXES[c] for c in range(3) if near[c])}); "
                    "model 15 needs intermediate tilts, e.g. the an4399-8 design")
        return "the cubic terms cannot be told from gain and cross-axis with these poses; use e.g. the an4399-8 design"
    return f"the {seen} do not determine model {model} (two coefficients move together); add poses in other directions"


def assess(gf: ArrayLike, model: str) -> Identifiability:
    """One board: readings (P, 3) in about g (see ``assess_batch``)."""
    gf = np.asarray(gf, dtype=float)
    model = str(model)
    ok, distinct = assess_batch(gf[None], model)
    d = int(distinct[0])
    reason = "" if ok[0] else _reason(gf, model, d, first_of_orientation(gf[None])[0])
    return Identifiability(model, len(gf), d, COEFFS[model], bool(ok[0]), reason)


def require(gf: ArrayLike, model: str) -> Identifiability:
    """``assess`` that raises UnderdeterminedError with the reason when the model is not determined."""
    a = assess(gf, model)
    if not a.determined:
        raise UnderdeterminedError(a.reason)
    return a


_TIE_REL = 1e-9  # relative: far above rounding noise (1e-16), far below the 3 digits printed


def worst_parameter(stderr: dict[str, np.ndarray] | None, model: str) -> tuple[str, str] | None:
    """(name, standard error in the parameter's own units) of the least certain parameter.

    Parameters are compared by their effect on the output at 1 g; a cross term is shown
    as an angle in degrees, a gain in percent, an offset in mg, a cubic in mg/g^3.
    """
    if stderr is None:
        return None
    W, V, G = (np.asarray(stderr[k], dtype=float) for k in ("W", "V", "Gamma"))
    cands: list[tuple[float, str, str]] = []
    for r in range(3):
        for c in range(3):
            if model == "6" and r != c:
                continue
            name = f"W_{AXES[r]}{AXES[c]}"
            if r == c:
                cands.append((W[r, c], name, f"{100 * W[r, c]:.3g} %"))
            else:
                cands.append((W[r, c], name, f"{math.degrees(math.asin(min(W[r, c], 1.0))):.3g} deg"))
        cands.append((V[r], f"V_{AXES[r]}", f"{1e3 * V[r]:.3g} mg"))
        if model == "15":
            cands.append((G[r], f"Gamma_{AXES[r]}{AXES[r]}", f"{1e3 * G[r]:.3g} mg/g^3"))
    # symmetric designs give several parameters the same error up to float noise: the tie goes
    # to the first in the order above (W row by row, V, Gamma), not to the machine's last digits
    top = max(c[0] for c in cands)
    _, name, text = next((c for c in cands if c[0] >= top * (1.0 - _TIE_REL)), max(cands, key=lambda c: c[0]))
    return name, text

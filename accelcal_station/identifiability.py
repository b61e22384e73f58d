"""Can the data determine a model?  Judged from the poses themselves, before fitting.

Revisiting a face adds no information, so the poses are first grouped into distinct
orientations (readings within ``DISTINCT_TOL_DEG`` of each other are one orientation).
The design is then the model's regressors over those orientations:

  6   per channel c: [g_c, 1]                     (AN4399 Eqns 6-17)
  12  [g_x, g_y, g_z, 1]                          (AN4399 Eqn 46's X)
  15  [g_x, g_y, g_z, 1, g_c^3] per channel       (AN4399 Eqns 67-72)
  9   the norm model linearised at M = I, B = 0:  |u|' = [u_x^2, u_y^2, u_z^2, 2u_xu_y,
      2u_xu_z, 2u_yu_z, u_x, u_y, u_z] for each unit direction u (nine-position paper)

A model is determined when there are at least as many distinct orientations as
coefficients per solve and no column of the (column-normalised) design is close to a
combination of the others.  The reason a model is refused is said in words.

``assess_batch`` is vectorised for `accelcal batch`; ``assess`` is one board.

`accelcal diagnose` asks the same question of any model of the effects catalog:
``describe_terms`` takes the static design of those effects (built by
gap_effects.describe_design on ideal readings), and names the terms along every relative singular value below
``TERM_REL_SV_MIN`` (confounded: no data of this design can separate them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NotRequired, TypedDict

import numpy as np
from numpy.typing import ArrayLike

from .errors import UnderdeterminedError

DISTINCT_TOL_DEG = 5.0  # readings closer than this are the same orientation (a revisit)
SPREAD_MIN_G = 0.25  # a channel must see gravity change by this much for its gain (model 6)
REL_SV_MIN = 0.05  # smallest / largest singular value of the normalised design
TERM_REL_SV_MIN = 1e-6  # describe_terms: terms along a smaller relative singular value are not determined
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


def _centre(gf: np.ndarray) -> np.ndarray:
    """Directions are taken about 0 unless the data sit far off it (unsigned counts)."""
    if gf.ndim == 3 and gf.shape[1] <= SMALL_P:  # a few poses: P - 1 elementwise steps beat a short-axis reduction
        hi, lo = gf[:, 0].copy(), gf[:, 0].copy()
        for p in range(1, gf.shape[1]):
            np.maximum(hi, gf[:, p], out=hi)
            np.minimum(lo, gf[:, p], out=lo)
        mid = 0.5 * (hi + lo)
    else:
        mid = 0.5 * (gf.max(axis=-2) + gf.min(axis=-2))
    far = np.sqrt(np.einsum("...k,...k->...", mid, mid))[..., None] > 0.5
    return np.where(far, mid, 0.0)


SMALL_P = 32  # poses per board up to which the P x P cosines of a block of boards are formed at once


BLOCK_ELEMS = 1 << 19  # pose-pair cosines held at once (4 MB of float64): memory stays linear in P
WINDOWED_FROM = 2048  # poses per board from which pairs are looked for in a sorted window only


def distinct_count(first: np.ndarray) -> np.ndarray:
    """(D,) distinct orientations of each board from its first_of_orientation (D, P): P for
    every board when every pose is a first (the usual stack: no per-board sum over a short axis)."""
    return np.full(first.shape[:-1], first.shape[-1]) if first.all() else first.sum(axis=-1)


def first_of_orientation(gf: np.ndarray, tol_deg: float = DISTINCT_TOL_DEG, apart: np.ndarray | None = None
                         ) -> np.ndarray:
    """(D, P) bool: pose p is the first of its orientation (no earlier pose q < p with
    u_p . u_q > cos(tol_deg), u the unit directions).  The P x P cosines are formed a block of
    rows at a time, so memory is O(D P), not O(D P^2) (a 100,000-pose table); a large table
    compares each pose only with those in neighbouring cubes of the chord 2 sin(tol/2).
    ``apart`` (D,): boards known to have every pose a first (``screen``'s certificate); only the
    other boards' pairs are compared."""
    if apart is not None and gf.ndim == 3 and np.any(apart):
        first = np.ones(gf.shape[:2], dtype=bool)
        rest = np.flatnonzero(~apart)
        if rest.size:
            first[rest] = first_of_orientation(gf[rest], tol_deg)
        return first
    x = gf - _centre(gf)[..., None, :]
    u = x / np.maximum(np.sqrt(np.einsum("...k,...k->...", x, x)), 1e-12)[..., None]
    D, P = u.shape[:2]
    cos = math.cos(math.radians(tol_deg))
    if P <= SMALL_P:  # boards last, a block at a time: P - 1 elementwise steps, no matmul per board
        first = np.empty((D, P), dtype=bool)
        nb = max(1, BLOCK_ELEMS // (P * P))
        for a in range(0, D, nb):
            first[a:a + nb] = _first_small(u[a:a + nb], cos)
        return first
    if P >= WINDOWED_FROM:
        return np.stack([_first_windowed(ub, cos, 2 * math.sin(math.radians(tol_deg) / 2)) for ub in u])
    first = np.ones((D, P), dtype=bool)
    step = max(1, BLOCK_ELEMS // max(1, D * P))
    for a in range(1, P, step):
        b = min(P, a + step)
        close = (u[:, a:b] @ np.swapaxes(u[:, :b - 1], -1, -2)) > cos  # (D, rows, earlier candidates)
        close &= np.arange(b - 1)[None, :] < np.arange(a, b)[:, None]  # only earlier poses count
        first[:, a:b] = ~np.any(close, axis=-1)
    return first


def _first_small(u: np.ndarray, cos: float) -> np.ndarray:
    """``first_of_orientation`` of a block of boards' (D, P, 3) unit directions, P small: pose p
    against every earlier pose of all D boards at once (u_p . u_q summed over x, y, z)."""
    ut = np.ascontiguousarray(u.transpose(1, 2, 0))  # (P, 3, D)
    P = ut.shape[0]
    first = np.ones((P, ut.shape[2]), dtype=bool)
    for p in range(1, P):
        dots = ut[:p, 0] * ut[p, 0]
        dots += ut[:p, 1] * ut[p, 1]
        dots += ut[:p, 2] * ut[p, 2]
        first[p] = ~np.any(dots > cos, axis=0)
    return first.T


def _first_windowed(u: np.ndarray, cos: float, chord: float) -> np.ndarray:
    """``first_of_orientation`` of one board's (P, 3) unit directions, comparing each pose only
    with the poses in its own and the 26 neighbouring cubes of side ``chord`` (a closer pair
    cannot be further apart), a block of rows at a time."""
    P = len(u)
    cell = np.floor(u / chord).astype(np.int64) + int(1 / chord) + 2  # |u| <= 1: 0 < cell < 2**20
    key = (cell[:, 0] << 40) | (cell[:, 1] << 20) | cell[:, 2]
    order = np.argsort(key, kind="stable")
    skey, us = key[order], u[order]
    cells, starts = np.unique(skey, return_index=True)
    ends = np.append(starts[1:], P)
    near = [(dx << 40) + (dy << 20) + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]
    first = np.ones(P, dtype=bool)
    for c, a0, b0 in zip(cells.tolist(), starts.tolist(), ends.tolist(), strict=True):
        lo = np.searchsorted(cells, [c + d for d in near])
        hit = lo[(lo < len(cells)) & (cells[np.minimum(lo, len(cells) - 1)] == np.array(near) + c)]
        cand = np.concatenate([np.arange(starts[j], ends[j]) for j in hit])
        uc, ic = us[cand], order[cand]
        step = max(1, BLOCK_ELEMS // max(1, len(cand)))
        for a in range(a0, b0, step):
            b = min(b0, a + step)
            close = (us[a:b] @ uc.T) > cos
            close &= ic[None, :] < order[a:b, None]  # earlier in the table
            first[order[a:b]] = ~np.any(close, axis=1)
    return first


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


class TermsCounts(TypedDict):
    """How many distinct orientations, poses and fitted terms a design has."""

    distinct_orientations: int
    poses: int
    parameters: int


class TermsDescription(TermsCounts):
    """What ``describe_terms`` finds (diagnose --json ``identifiability``; key order as declared)."""

    relative_singular_values: NotRequired[list[float]]  # absent without fitted terms
    confounded: NotRequired[list[list[str]]]  # the terms of each undetermined combination
    text: str


def describe_terms(A: np.ndarray, labels: list[tuple[str, str]], ideal: np.ndarray) -> TermsDescription:
    """Distinct orientations of ``ideal`` (P, 3), relative singular values of the column-scaled
    design ``A`` (..., n_terms) whose columns are ``labels`` ((effect, detail) pairs), and which
    terms are confounded; the text says it in words (diagnose's untestable reasons)."""
    n_or = int(first_of_orientation(ideal[None])[0].sum())
    counts: TermsCounts = {"distinct_orientations": n_or, "poses": len(ideal), "parameters": len(labels)}
    if not labels:
        return {**counts, "text": f"{n_or} distinct orientations; no fitted terms"}
    M = A.reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    _, s, Vt = np.linalg.svd(M / np.where(sc > 0, sc, 1.0), full_matrices=False)
    rel = s / s[0]
    bad = np.flatnonzero(rel < TERM_REL_SV_MIN)
    if not bad.size:
        return {**counts, "relative_singular_values": rel.tolist(),
                "text": (f"{n_or} distinct orientations determine all {len(labels)} terms "
                         f"(smallest relative singular value {rel[-1]:.2g})")}
    groups = []
    for k in bad:
        v = np.abs(Vt[k]) / np.max(np.abs(Vt[k]))
        groups.append([f"{e} {d}" for (e, d), x in zip(labels, v, strict=True) if x > 0.2])
    return {**counts, "relative_singular_values": rel.tolist(), "confounded": groups,
            "text": (f"{n_or} distinct orientations cannot determine {len(bad)} combination(s) of the "
                     f"{len(labels)} terms: " + "; ".join(" with ".join(g) for g in groups)
                     + f" (relative singular value {rel[bad[0]]:.1g})")}


__all__ = ["DISTINCT_TOL_DEG", "Identifiability", "TermsCounts", "TermsDescription", "assess",
           "assess_batch", "describe_terms", "first_of_orientation", "require",
           "worst_parameter"]

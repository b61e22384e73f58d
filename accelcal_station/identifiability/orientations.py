"""Distinct orientations: revisiting a face adds no information, so poses whose readings lie within
``DISTINCT_TOL_DEG`` of an earlier one are one orientation.  Vectorised over boards, memory linear in the
poses (a block of pose pairs at a time; a sorted window for very long tables)."""
from __future__ import annotations

import math

import numpy as np

DISTINCT_TOL_DEG = 5.0  # readings closer than this are the same orientation (a revisit)


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

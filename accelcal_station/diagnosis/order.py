"""Acquisition order: a pose table's row order is the order its poses were taken (docs/pose-table
format), a raw log's static intervals are in time order, and several files are taken one after
another.  Whatever changed over the session (an offset relaxing after mounting, warm-up) is a
smooth function of that order.

The order basis is, per file, Legendre polynomials P1..P3 of the pose's position in the file
scaled to [-1, 1] (a cubic in row number: an exponential relaxation over the session is within
a few percent of one).  A selected effect is *confounded with acquisition order* when one of its
static columns (on the ideal readings, as identifiability judges designs) is that smooth in
order: R^2 of the column regressed on the basis (plus a mean per file) above ORDER_R2_MAX.
0.8 is where a trend over time could stand in for the column with less than half its
standard deviation left over (sqrt(1 - 0.8) = 0.45): the held-out test cannot then tell which
of the two moved the readings.  A design that revisits poses later in the run, or takes them in
shuffled order, makes the column rough in order and the R^2 low: only such a design separates them.
"""
from __future__ import annotations

from typing import Literal, TypedDict

import numpy as np

from .effects.design import static_design
from .gap_data import GapData

ORDER_DEGREE = 3
ORDER_R2_MAX = 0.8


def order_position(data: GapData) -> np.ndarray:
    """(P,) each pose's position in its file, scaled to [-1, 1] (0 for a file of one pose)."""
    s = np.zeros(data.P)
    for f in np.unique(data.file):
        idx = np.flatnonzero(data.file == f)
        if len(idx) > 1:
            s[idx] = np.linspace(-1.0, 1.0, len(idx))
    return s


def order_basis(data: GapData, intercepts: bool = True) -> np.ndarray:
    """(P, k): Legendre P1..P3 of the position in each file (module doc), with a mean per file."""
    s = order_position(data)
    leg = np.polynomial.legendre.legvander(s, ORDER_DEGREE)[:, 1:]
    files = np.unique(data.file)
    cols = [leg * (data.file == f)[:, None] for f in files]
    if intercepts:
        cols.append((data.file[:, None] == files[None, :]).astype(float))
    return np.concatenate(cols, axis=1)


def order_r2(X: np.ndarray, data: GapData) -> np.ndarray:
    """R^2 of each column of X (P, m) regressed on the order basis, about each file's mean (0 for a flat column)."""
    B = order_basis(data)
    files = (data.file[:, None] == np.unique(data.file)[None, :]).astype(float)
    mean = files @ np.linalg.lstsq(files, X, rcond=None)[0]
    tot = np.sum((X - mean) ** 2, axis=0)
    res = np.sum((X - B @ np.linalg.lstsq(B, X, rcond=None)[0]) ** 2, axis=0)
    return np.where(tot > 1e-12 * max(float(np.max(tot)), 1e-300), 1.0 - res / np.where(tot > 0, tot, 1.0), 0.0)


# an effect whose columns follow acquisition order: the term that does and its R^2 ("with" is a keyword)
OrderConfound = TypedDict("OrderConfound", {"with": Literal["acquisition order"], "term": str, "r2": float,
                                            "threshold": float})


def confounded_with_order(data: GapData, effects: list[str]) -> dict[str, OrderConfound]:
    """Per selected effect whose columns follow acquisition order (module doc): the term and its R^2."""
    if data.P < 2 * (ORDER_DEGREE + 1):
        return {}
    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    out: dict[str, OrderConfound] = {}
    for e in effects:
        A, _, _, labels = static_design({e}, ideal, data.ref, dT, None, data.ref is None, data.n_temps)
        if not labels:
            continue
        cols = A.sum(axis=1)  # (P, p): each column acts on one channel (or is the same on each)
        r2 = order_r2(cols, data)
        k = int(np.argmax(r2))
        if r2[k] > ORDER_R2_MAX:
            out[e] = {"with": "acquisition order", "term": labels[k][1], "r2": float(r2[k]),
                      "threshold": ORDER_R2_MAX}
    return out


def order_words(c: dict[str, OrderConfound]) -> str:
    """The confound in words, with what separates the two."""
    parts = [f"{e} ({v['term']}: R^2 {v['r2']:.2f} against a cubic in row number, above {v['threshold']:g})"
             for e, v in c.items()]
    return (f"confounded with acquisition order: {', '.join(parts)}; a change over the session (drift) fits the "
            "same readings; revisit poses later in the run or take them in shuffled order to tell them apart")


__all__ = ["ORDER_R2_MAX", "OrderConfound", "confounded_with_order", "order_basis", "order_position", "order_r2",
           "order_words"]

"""Acquisition order: a pose table's row order is the order its poses were taken (docs/pose-table
format), a raw log's static intervals are in time order, and several files are taken one after
another.  Whatever changed over the session (an offset relaxing after mounting, warm-up) is a
smooth function of that order.

The order basis is, per file, Legendre polynomials P1..Pd of the pose's position in the file
scaled to [-1, 1] (d = 3, a cubic in row number, where the file has 12 poses or more; an
exponential relaxation over the session is within a few percent of one; d = n // 4 for a file of
n < 12 poses, so a trend never has fewer than four poses a coefficient), with a mean per file (the
order trend leaves out the first file's: trend_basis).
The basis restarts in every file: a file is its own capture (a board mounted, powered and warmed
up anew), so a trend need not continue across files and each file may have its own offset; where
the files are one continuous session the restart costs d + 1 coefficients per channel and file but
misses no trend.

Confounding is judged by competition (engine's module doc, step 3): the *order trend*, an offset
per channel that follows the order basis (``order_trend``, effects/order_trend.py), is fitted in the
same held-out test as every catalog candidate.  A candidate is selected only when it beats the
baseline and the order trend; the terms of it the order trend could stand in for (R^2 of the term's
column, on the ideal readings as identifiability judges designs, regressed on the basis above
ORDER_R2_MAX) are named in ``confounded`` with their R^2, and the effect keeps the rest.  A candidate
that beats the baseline but not the order trend is ``confounded`` alone (not selected).
0.8 is where a trend over time could stand in for the column with less than half its standard
deviation left over (sqrt(1 - 0.8) = 0.45).  A design that revisits poses later in the run, or takes
them in shuffled order, makes a column rough in order and its R^2 low: only such a design separates them.
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


def file_degree(n_poses: int) -> int:
    """The order basis's degree in a file of ``n_poses`` poses (module doc): 3, or n // 4 below 12 poses."""
    return min(ORDER_DEGREE, n_poses // 4)


def order_basis(data: GapData, intercepts: bool = True) -> np.ndarray:
    """(P, k): Legendre P1..Pd of the position in each file (module doc), with a mean per file."""
    s = order_position(data)
    files = np.unique(data.file)
    cols = []
    for f in files:
        m = data.file == f
        d = file_degree(int(np.sum(m)))
        if d:
            cols.append(np.polynomial.legendre.legvander(s, d)[:, 1:] * m[:, None])
    if intercepts:
        cols.append((data.file[:, None] == files[None, :]).astype(float))
    return np.concatenate(cols, axis=1) if cols else np.zeros((data.P, 0))


def trend_basis(data: GapData) -> tuple[np.ndarray, list[str]]:
    """(P, k) and k names: the order trend's columns per channel (module doc): the order basis without the
    first file's mean, which is a constant offset, not a change over the session (with it, the trend would
    contain the offset candidate and no model without an offset could beat it).

    The polynomial columns are made orthogonal to the ideal readings (the references, or the unit readings
    without) and the files' means, and dropped where nothing is left: in a design whose references follow
    row order (u_z linear in row number in order of z) a trend column would otherwise be a noise-free copy
    of a reference, and a "drift" that reproduces the references predicts held-out poses without reading
    them.  What is dropped is in the span the baseline's gain and offset fit already.
    """
    files = np.unique(data.file)
    B = order_basis(data)
    names = [f"P{j}" + (f"@{f}" if len(files) > 1 else "")
             for f in files for j in range(1, file_degree(int(np.sum(data.file == f))) + 1)]
    names += [f"mean@{f}" for f in files]
    n_poly = B.shape[1] - len(files)
    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    Q = np.linalg.qr(np.concatenate([ideal, B[:, n_poly:]], axis=1))[0]
    poly = B[:, :n_poly] - Q @ (Q.T @ B[:, :n_poly])
    keep = np.linalg.norm(poly, axis=0) > 1e-6 * np.maximum(np.linalg.norm(B[:, :n_poly], axis=0), 1e-300)
    B = np.concatenate([poly[:, keep], B[:, n_poly + 1:]], axis=1)
    names = [n for n, k in zip(names[:n_poly], keep, strict=True) if k] + names[n_poly + 1:]
    return B, names


def order_r2(X: np.ndarray, data: GapData) -> np.ndarray:
    """R^2 of each column of X (P, m) regressed on the order basis, about each file's mean (0 for a flat column)."""
    B = order_basis(data)
    files = (data.file[:, None] == np.unique(data.file)[None, :]).astype(float)
    mean = files @ np.linalg.lstsq(files, X, rcond=None)[0]
    tot = np.sum((X - mean) ** 2, axis=0)
    res = np.sum((X - B @ np.linalg.lstsq(B, X, rcond=None)[0]) ** 2, axis=0)
    return np.where(tot > 1e-12 * max(float(np.max(tot)), 1e-300), 1.0 - res / np.where(tot > 0, tot, 1.0), 0.0)


class OrderTerm(TypedDict):
    """One term of an effect that follows acquisition order: its label, channel and R^2 on the order basis."""

    term: str
    channel: str
    r2: float


# an effect whose terms follow acquisition order ("with" is a keyword).  ``alone``: the order trend explains
# the gap as well as the effect, which is then not selected; else only ``terms`` are in doubt and the effect
# is kept.  ``term`` and ``r2`` are the first of ``terms`` (the most order-like).
# ``why`` (alone only): the order trend explains the gap as well, or the effect's evidence rests on its
# order-like terms (confounding.py)
OrderConfound = TypedDict("OrderConfound", {"with": Literal["acquisition order"], "term": str, "r2": float,
                                            "threshold": float, "terms": list[OrderTerm], "alone": bool,
                                            "why": str})


def term_r2(data: GapData, effect: str) -> list[OrderTerm]:
    """Every static term of ``effect`` with its channel and R^2 on the order basis (module doc), most
    order-like first; judged on the ideal readings, as identifiability judges designs."""
    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    A, _, _, labels = static_design({effect}, ideal, data.ref, dT, None, data.ref is None, data.n_temps)
    if not labels:
        return []
    r2 = order_r2(A.sum(axis=1), data)  # (P, p): each column acts on one channel (or is the same on each)
    chans = ["".join("xyz"[c] for c in np.flatnonzero(np.any(A[:, :, k] != 0, axis=0))) for k in range(len(labels))]
    out: list[OrderTerm] = [{"term": labels[k][1], "channel": chans[k], "r2": float(r2[k])} for k in range(len(labels))]
    return sorted(out, key=lambda t: -t["r2"])


def confounded_terms(data: GapData, effect: str, alone: bool) -> OrderConfound | None:
    """The terms of ``effect`` that follow acquisition order (R^2 above ORDER_R2_MAX), or None when none does;
    ``alone`` (the order trend explained the gap as well): always an entry, led by its most order-like term."""
    terms = term_r2(data, effect)
    top = [t for t in terms if t["r2"] > ORDER_R2_MAX]
    if not top and not (alone and terms):
        return None
    lead = (top or terms)[0]
    return {"with": "acquisition order", "term": lead["term"], "r2": lead["r2"], "threshold": ORDER_R2_MAX,
            "terms": top, "alone": alone,
            "why": "a smooth change over the session explains the gap as well" if alone else ""}


def _terms_text(v: OrderConfound) -> str:
    terms = v["terms"] or [{"term": v["term"], "channel": "", "r2": v["r2"]}]
    return ", ".join(f"{t['term']}: R^2 {t['r2']:.2f}" for t in terms)


def order_words(c: dict[str, OrderConfound]) -> str:
    """The confounds in words, with what separates the two: the parts in doubt of a kept effect, and the
    effects the order trend explains as well."""
    parts = []
    for e, v in c.items():
        if v["alone"]:
            parts.append(f"{e} is confounded with acquisition order ({_terms_text(v)} against the order basis): "
                         f"{v['why']}, so it is not selected; revisit poses later in the run or take them in "
                         "shuffled order to tell them apart")
        else:
            ch = sorted({ch for t in v["terms"] for ch in t["channel"]})
            parts.append(f"the {', '.join(ch)} part of {e} ({_terms_text(v)} against the order basis) could also "
                         "be a change over the session; shuffle or revisit the poses to tell")
    return "; ".join(parts)


__all__ = ["ORDER_R2_MAX", "OrderConfound", "OrderTerm", "confounded_terms", "file_degree", "order_basis",
           "order_position", "order_r2", "order_words", "term_r2", "trend_basis"]

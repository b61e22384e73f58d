"""The static view's design: the catalog's columns for a model's effects, and whether these poses
determine them (the static view of gap_effects' module doc; AN4399 Eqns 46 and 67 extended).

Below both the held-out evaluation (static_view) and the fitted jig rotation (jig_rotation).
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ...identifiability import TermsDescription, describe_terms
from ..gap_data import TAU_DRIFT_S, GapData, time_data
from ..least_squares import norm_resid
from .catalog import DETERMINISTIC
from .columns import StaticView


@dataclass(frozen=True)
class ColumnChoice:
    """How the static view's columns are built beyond the effects: ``g0`` (3,) the zero-g reading the
    nonlinear columns are centred on (None: zero), ``order`` the order trend's basis (P, k) and names
    (order.trend_basis) when the effects have ``order_trend``, ``drop`` the "effect:detail" columns left out."""

    g0: ArrayLike | None = None
    order: tuple[np.ndarray, list[str]] | None = None
    drop: frozenset[str] = frozenset()


def static_design(E: Collection[str], g: np.ndarray, ref: np.ndarray | None, dT: np.ndarray | None,
                  drift_h: np.ndarray | None, norm: bool, n_temps: int, columns: ColumnChoice = ColumnChoice(),
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[str, str]]]:
    """Design of the static view for effects E.

    g: (..., P, 3) readings; ref: (P, 3) or None; dT: (P,) or None; drift_h: (..., P, 2) or None;
    columns.g0: a sensor's nonlinearity acts on its response to force, G - g0 (reading = S a + c (S a)^3 + b),
    so the cubic and square columns are centred there (ColumnChoice).
    Returns A (..., P, 3, p), b (..., P, 3), d (p,) norm-shift flags, labels (p,) of (effect, detail).
    """
    g0, order, drop = columns.g0, columns.order, columns.drop
    lead = g.shape[:-2]
    if drift_h is not None:
        lead = np.broadcast_shapes(lead, drift_h.shape[:-2])
    g = np.broadcast_to(g, lead + g.shape[-2:])
    P = g.shape[-2]
    z0 = np.zeros(3) if g0 is None else np.asarray(g0, float)
    view = StaticView(g, ref, dT, drift_h, norm, n_temps, z0, frozenset(E), order, drop)
    for name, effect in DETERMINISTIC.items():
        if name in E:
            effect.columns(view)
    # W = I without gain or cross_axis: the nominal sensitivity is taken as exact
    b = np.zeros(lead + (P, 3)) + (0.0 if {"gain", "cross_axis"} & set(E) else g)
    A = np.stack(view.cols, axis=-1) if view.cols else np.zeros(lead + (P, 3, 0))
    return A, b, np.array(view.shifts), view.labels


def describe_design(data: GapData, effects: Collection[str]) -> TermsDescription:
    """identifiability.describe_terms of the static design of ``effects`` on ideal readings
    (g = ref, or unit readings without references)."""
    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    A, _, _, labels = static_design(set(effects), ideal, data.ref, dT, dh, data.ref is None, data.n_temps)
    return describe_terms(A, labels, ideal)


def design_rank_ok(E: Collection[str], data: GapData, norm: bool, rows: np.ndarray | None = None
                   ) -> tuple[bool, float]:
    """Whether the static terms of E are identifiable on ideal readings (g = ref, or unit readings),
    from the poses ``rows`` ((P,) bool: a fold's training poses; None: all).

    Judged on ideal data, like designs.predict_stderr, so that noise never makes a
    degenerate term look identifiable.  Returns (ok, column-scaled condition number).
    """
    ideal = data.g / np.linalg.norm(data.g, axis=1, keepdims=True) if norm or data.ref is None else data.ref
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    td = time_data(data) if "drift" in E else None
    dh = None if td is None else np.stack([td.cap_drift1[len(TAU_DRIFT_S) // 2], td.cap_drift2], axis=-1)
    A, b, d, labels = static_design(E, ideal, data.ref, dT, dh, norm, data.n_temps)
    if not labels:
        return True, 1.0
    if norm:  # at the ideal solution W = I, everything else 0
        th = np.array([1.0 if det.startswith("W_") and det[2] == det[3] else 0.0 for _, det in labels])
        _, J, _ = norm_resid(A[None], b[None], d, 1.0, th[None])
        M = J[0] if rows is None else J[0][rows]
    else:
        M = (A if rows is None else A[rows]).reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    if np.any(sc == 0):
        return False, np.inf
    s = np.linalg.svd(M / sc, compute_uv=False)
    cond = float(s[0] / max(s[-1], 1e-300))
    return cond < 1e6, cond

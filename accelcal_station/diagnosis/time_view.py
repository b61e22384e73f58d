"""The time view of the held-out evaluation (raw captures only): block means within each capture
against drift (warm-up and trend, shared terms) and settling (a transient whose amplitude is a random
effect per capture and axis); gap_effects' module doc, "Time view"."""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from .evaluation import FitParams
from .evaluation import nll as _nll
from .folds import Folds, NoiseModel, heldout
from .gap_data import TAU_DRIFT_S, TAU_SETTLE_S, TimeData
from .least_squares import wls
from .noise_floor import random_var

_PSI2_GRID = np.concatenate([[0.0], np.geomspace(1e-14, 1e-2, 73)])  # settling amplitude variance, g^2


@dataclass
class TimeFit:
    """The time view's held-out block residuals (R,) and what settling hands the static view."""

    r: np.ndarray  # (R,) held-out block residuals, g
    v: np.ndarray  # (R,) their predicted variance, g^2
    floor: np.ndarray  # (R,) the floor alone
    nll_rows: np.ndarray  # (R,) negative log density of each row before settling's marginal gain
    nll_gain: np.ndarray | None  # (P, 3) settling's held-out log marginal density gain per capture-axis
    corr: np.ndarray  # (F, P, 3) settling's transient mean in each pose mean, g
    extra: np.ndarray  # (F, P, 3) variance that removing it adds, g^2
    n_params: int
    params: FitParams


@dataclass
class _SettleFit:
    """Settling's fit per fold: the BLUP transient on every row, its posterior variance, and per pose."""

    fit_rows: np.ndarray  # (F, R)
    post_rows: np.ndarray  # (F, R)
    corr: np.ndarray  # (F, P, 3)
    extra: np.ndarray  # (F, P, 3)
    gain: np.ndarray | None  # (F, G) log marginal density gain of every capture-axis
    params: FitParams


def _drift_time(td: TimeData, target: np.ndarray, wtr: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Warm-up and trend per axis on the block rows, tau on a grid per fold: (data minus fit, its prediction
    variance, the whole-data fit's parameters)."""
    F, R = wtr.shape
    y = np.broadcast_to(td.e, (F, R)).copy()
    pv = np.zeros((F, R))
    best_cost = np.full(F, np.inf)
    params: dict[str, float] = {}
    for a in range(len(TAU_DRIFT_S)):
        D = np.zeros((R, 6))
        for c in range(3):
            on = td.axis == c
            D[on, 2 * c], D[on, 2 * c + 1] = td.drift1[a][on], td.drift2[on]
        th, C = wls(np.broadcast_to(D, (F, R, 6)), target, wtr)
        cost = np.sum(wtr * (target - th @ D.T) ** 2, axis=1)
        b = cost < best_cost
        best_cost[b] = cost[b]
        y[b] = td.e[None] - th[b] @ D.T
        pv[b] = np.einsum("rp,fpq,rq->fr", D, C[b], D)
        if b[-1]:
            params["drift_tau_s_time"] = float(TAU_DRIFT_S[a])
            params.update({f"drift_time:{k}_{ax}": float(v) for (ax, k), v in
                           zip([(ax, k) for ax in "xyz" for k in ("warmup", "trend")], th[-1], strict=True)})
    return y, pv, params


def _settling_time(td: TimeData, y: np.ndarray, v_row: np.ndarray, fo: Folds, P: int) -> _SettleFit:
    """tau and psi^2 by maximum marginal likelihood on training captures; each capture's amplitude by BLUP.

    A capture-axis with design f and weights w gains log N(e; 0, V + psi^2 f f^T) - log N(e; 0, V)
    = 0.5 (psi^2 Sfe^2 / (1 + psi^2 Sff) - log(1 + psi^2 Sff)), Sff = f^T W f, Sfe = f^T W e.
    """
    F, train = fo.F, fo.train
    gkey = td.unit * 3 + td.axis
    wv = 1.0 / v_row  # (F, R)
    Sff = np.stack([np.stack([np.bincount(gkey, wv[fo_] * f * f, minlength=3 * P) for fo_ in range(F)])
                    for f in td.settle])  # (Gs, F, G)
    Sfe = np.stack([np.stack([np.bincount(gkey, wv[fo_] * f * y[fo_], minlength=3 * P) for fo_ in range(F)])
                    for f in td.settle])
    psi2 = _PSI2_GRID[:, None, None, None]
    gain = 0.5 * (psi2 * Sfe**2 / (1 + psi2 * Sff) - np.log1p(psi2 * Sff))  # (Q, Gs, F, G)
    ll = np.sum(gain * np.repeat(train, 3, axis=1), axis=-1)  # (Q, Gs, F): training captures only
    qi, si = np.unravel_index(ll.reshape(-1, F).argmax(axis=0), ll.shape[:2])
    fi = np.arange(F)
    p2, sff, sfe = _PSI2_GRID[qi][:, None], Sff[si, fi], Sfe[si, fi]  # (F, 1), (F, G)
    post = np.where(p2 > 0, 1.0 / (1.0 / np.where(p2 > 0, p2, 1.0) + sff), 0.0)  # Var(a | e), g^2
    a_hat = post * sfe  # BLUP amplitude at the capture's start, g
    f_rows = td.settle[si]  # (F, R)
    cap = td.cap_settle[si]  # (F, P)
    params: FitParams = {"settling_tau_s": float(TAU_SETTLE_S[si[-1]]),
              "settling_amplitude_mg_rms": float(1e3 * np.sqrt(p2[-1, 0])),
              "_settling_a_g": heldout(a_hat.reshape(F, P, 3), fo.fold)}  # each capture's, held out
    return _SettleFit(a_hat[:, gkey] * f_rows, post[:, gkey] * f_rows**2, a_hat.reshape(F, P, 3) * cap[:, :, None],
                      post.reshape(F, P, 3) * cap[:, :, None] ** 2, gain[qi, si, fi], params)


def time_view(td: TimeData, E: Collection[str], nm: NoiseModel, fo: Folds, P: int) -> TimeFit:
    """Drift (shared terms, held out by capture) and settling (tau shared, each capture's transient
    amplitude a random effect a ~ N(0, psi^2) per axis: auto-segmentation trims every capture's
    transient by a different amount, so the amplitude is a property of the capture, not of the
    board).  A held-out capture is scored by its marginal density N(e; 0, V + psi^2 f f^T) (proper,
    comparable with the baseline's N(e; 0, V)); its amplitude (BLUP) extrapolates the settled mean
    for the static view."""
    F, R = fo.F, len(td.e)
    rows = np.arange(R)
    fr = fo.fold[td.unit]
    v_row = random_var(nm.sigma[:, td.axis], nm.q[:, None]) * td.inv_m  # (F, R)
    wtr = fo.train[:, td.unit] / v_row
    y = np.broadcast_to(td.e, (F, R)).copy()  # data minus the fitted drift
    pv_d = np.zeros((F, R))  # drift's prediction variance
    zero = np.zeros((F, P, 3))
    st = _SettleFit(np.zeros((F, R)), np.zeros((F, R)), zero, zero, None, {})
    drift_params: dict[str, float] = {}
    for _ in range(2 if {"drift", "settling"} <= set(E) else 1):
        if "drift" in E:
            y, pv_d, drift_params = _drift_time(td, td.e[None] - st.fit_rows, wtr)
        if "settling" in E:
            st = _settling_time(td, y, v_row, fo, P)
    nll_gain = None if st.gain is None else st.gain[np.repeat(fo.fold, 3), np.arange(3 * P)].reshape(P, 3)
    return TimeFit(r=(y - st.fit_rows)[fr, rows], v=(v_row + pv_d - st.post_rows)[fr, rows],  # V - f^2 Var(a|e)
                   floor=v_row[fr, rows], nll_rows=_nll(y[fr, rows], (v_row + pv_d)[fr, rows]), nll_gain=nll_gain,
                   corr=st.corr, extra=st.extra, n_params=(6 if "drift" in E else 0) + (2 if "settling" in E else 0),
                   params={**drift_params, **st.params})

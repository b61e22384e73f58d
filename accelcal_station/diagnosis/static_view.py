"""The static view of the held-out evaluation: pose means against the references (weighted least squares)
or the norm (Levenberg-Marquardt), on every fold at once, with the drift tau on a grid and the pose
scatter by maximum likelihood (gap_effects' module doc, "Static view" and "Floor")."""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from .effects.design import ColumnChoice, static_design
from .effects.order_trend import NAME
from .evaluation import nll as _nll
from .folds import Folds, NoiseModel, heldout
from .gap_data import TAU_DRIFT_S, GapData, TimeData
from .least_squares import lm_norm, norm_resid, norm_start, wls
from .noise_floor import Floor, mean_var
from .order import trend_basis

_S2_GRID = np.concatenate([[0.0], np.geomspace(1e-12, 1e-2, 121)])  # pose scatter variance, rad^2


@dataclass
class StaticFit:
    """The static view's held-out residuals (P, m) and their variances (gap_effects' module doc)."""

    r: np.ndarray
    v: np.ndarray  # floor + fit
    floor: np.ndarray
    fitted: np.ndarray  # in-sample residuals of the whole-data fit
    pv: np.ndarray  # the fit's own prediction variance
    nll: np.ndarray  # (P, 3)
    n_params: int
    params: dict[str, float]


@dataclass
class _StaticTry:
    """One static fit for every fold (one drift tau): cost (F,), residuals r, variances v0 and pv, leverage."""

    cost: np.ndarray
    r: np.ndarray
    v0: np.ndarray
    pv: np.ndarray
    lev: np.ndarray
    th: np.ndarray
    labels: list[tuple[str, str]]
    p: int


def _static_try(data: GapData, gamma: float, E: Collection[str], g: np.ndarray, dT: np.ndarray | None,
                dh: np.ndarray | None, v0: np.ndarray, train: np.ndarray) -> _StaticTry:
    """Fit the static view on every fold at once: weighted least squares with references (3 rows a pose),
    Levenberg-Marquardt on the norm without (1 row); v0 (F, P, 3) with references, (F, P) on the norm."""
    ref, F, P = data.ref, train.shape[0], data.P
    order = trend_basis(data) if NAME in E else None
    A, b, d, labels = static_design(E, g, ref, dT, dh, ref is None, data.n_temps,
                                    ColumnChoice(data.zero_g, order, data.drop_terms))
    p = A.shape[-1]
    if ref is None:  # norm only
        w = train / v0
        th0 = np.broadcast_to(norm_start(data.g, labels, gamma), (F, p))
        th, C = lm_norm(A, b, d, gamma, w, th0)
        r, J, _ = norm_resid(A, b, d, gamma, th)
        pv = np.einsum("fpq,fqr,fpr->fp", J, C, J)
        r, v0, pv = r[..., None], v0[..., None], pv[..., None]
        lev = w[..., None] * pv
    else:
        y = (gamma * ref)[None] - b  # (F, P, 3)
        Af = A.reshape(F, P * 3, p)
        wf = (train[:, :, None] / v0).reshape(F, P * 3)
        th, C = wls(Af, y.reshape(F, P * 3), wf)
        r = y - np.einsum("fpcq,fq->fpc", A, th)
        pv = np.einsum("fpcq,fqr,fpcr->fpc", A, C, A)
        lev = (train[:, :, None] / v0) * pv
    cost = np.sum(train[:, :, None] * r**2 / v0, axis=(1, 2))
    return _StaticTry(cost, r, v0, pv, lev, th, labels, p)


def _best_try(tries: list[_StaticTry]) -> tuple[_StaticTry, int]:
    """Per fold, the try of least training cost (the drift tau grid); and the whole-data fit's index."""
    best = np.argmin(np.stack([t.cost for t in tries]), axis=0)
    F = len(best)

    def pick(k: str) -> np.ndarray:
        return np.stack([getattr(tries[best[f]], k)[f] for f in range(F)])

    last = tries[best[-1]]
    return _StaticTry(pick("cost"), pick("r"), pick("v0"), pick("pv"), pick("lev"), pick("th"), last.labels,
                      last.p), int(best[-1])


def _scatter_ml(t: _StaticTry, base_v: np.ndarray, shape: np.ndarray, train: np.ndarray) -> np.ndarray:
    """Maximum likelihood pose-scatter variance s^2 (rad^2) per fold on leverage-corrected training residuals."""
    rc2 = t.r**2 / np.clip(1.0 - t.lev, 0.05, 1.0)
    vb = base_v[:, None] + _S2_GRID[None, :, None, None] * shape[None, None]  # (F, S, P, 3)
    ll = -0.5 * np.sum(train[:, None, :, None] * (np.log(vb) + rc2[:, None] / vb), axis=(2, 3))
    return _S2_GRID[np.argmax(ll, axis=1)]


def _scatter_shape(ref: np.ndarray | None) -> np.ndarray | None:
    """Pose scatter s (rad) adds s^2 (1 - ref_c^2) to axis c of a pose mean; None on the norm."""
    return None if ref is None else 1.0 - (ref / np.linalg.norm(ref, axis=1, keepdims=True)) ** 2


def _residual_var(g: np.ndarray, base_v: np.ndarray, s2: np.ndarray, shape: np.ndarray | None) -> np.ndarray:
    """Floor variance of every static residual: along the reading on the norm (F, P), per axis plus the
    pose scatter s2 (F,) with references (F, P, 3)."""
    if shape is None:
        uh = g / np.linalg.norm(g, axis=1, keepdims=True)
        return np.sum(uh**2 * base_v, axis=-1)
    return base_v + s2[:, None, None] * shape[None]


def _floor_alone(g: np.ndarray, floor_mean: np.ndarray, scatter_rad: float, shape: np.ndarray | None) -> np.ndarray:
    """The floor of every static residual with the configured pose scatter: (F, P, m)."""
    if shape is None:
        uh = g / np.linalg.norm(g, axis=1, keepdims=True)
        return np.sum(uh**2 * floor_mean, axis=-1)[..., None]
    return floor_mean + scatter_rad**2 * shape[None]


def _drift_shapes(td: TimeData | None, a: int | None) -> np.ndarray | None:
    """Each capture's mean of the drift shapes (P, 2) at tau grid point a (None: no drift term)."""
    return None if a is None or td is None else np.stack([td.cap_drift1[a], td.cap_drift2], axis=-1)


def static_view(data: GapData, floor: Floor, E: Collection[str], added: Collection[str], td: TimeData | None,
                nm: NoiseModel, fo: Folds, corr: np.ndarray, extra: np.ndarray) -> StaticFit:
    """Pose means (settling's transient mean removed) against the references or the norm (gap_effects)."""
    norm, F, P, train = data.norm_only, fo.F, data.P, fo.train
    g = data.g[None] - corr  # (F, P, 3)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    use_drift = "drift" in E and td is not None
    grid: list[int | None] = list(range(len(TAU_DRIFT_S))) if use_drift else [None]
    s2 = np.full(F, floor.scatter_rad**2)
    floor_mean = np.broadcast_to(mean_var(nm.sigma[:, None, :], nm.q[:, None, None], data.n[None, :, None]),
                                 (F, P, 3))
    base_v = floor_mean + extra  # (F, P, 3)
    shape = _scatter_shape(data.ref)
    params: dict[str, float] = {}
    n_iter = 3 if "pose_error" in added and not norm else 1
    for it in range(n_iter):
        v0 = _residual_var(data.g, base_v, s2, shape)
        tries = [_static_try(data, floor.gamma, E, g, dT, _drift_shapes(td, a), v0, train) for a in grid]
        t, best = _best_try(tries)
        if use_drift:
            params["drift_tau_s"] = float(TAU_DRIFT_S[grid[best]])
        if it < n_iter - 1:
            assert shape is not None  # n_iter > 1 only with references
            s2 = _scatter_ml(t, base_v, shape, train)
    params.update({f"{e}:{det}": float(v) for (e, det), v in zip(t.labels, t.th[-1], strict=True)})
    if "pose_error" in added and not norm:
        params["scatter_deg"] = float(np.degrees(np.sqrt(s2[-1])))
    r_s, v_s = heldout(t.r, fo.fold), heldout(t.v0 + t.pv, fo.fold)
    nll = np.zeros((P, 3))
    if norm:  # a norm residual goes to the axis nearest gravity
        np.add.at(nll, (np.arange(P), np.argmax(np.abs(data.g), axis=1)), _nll(r_s, v_s)[:, 0])
    else:
        nll = _nll(r_s, v_s)
    floor0 = _floor_alone(data.g, floor_mean, floor.scatter_rad, shape)
    return StaticFit(r_s, v_s, heldout(floor0, fo.fold), t.r[-1], heldout(t.pv, fo.fold), nll, t.p, params)

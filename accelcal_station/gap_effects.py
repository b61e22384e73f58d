"""The effects catalog as fitted measurement-model terms, and their held-out evaluation.

This is the engine of `accelcal diagnose` (accelcal_station/diagnose.py).  A model is
the simulator configuration's enabled effects plus the candidates added to them; every
effect is a parametric term in one of two views of the data, and the noise floor is
the variance the simulator predicts for every residual.

Static view (pose means).  The calibrated output of pose i is linear in the
parameters, ``u_i = A_i theta + b_i`` (AN4399 Eqns 46 and 67 extended):

  with references     r_i = gamma ref_i - u_i         3 rows, weighted least squares
  without (norm only) r_i = |u_i| - gamma - d_i theta 1 row, Levenberg-Marquardt (nine-position paper)

where ``gamma`` is the configured local gravity in standard g.  Terms, per channel c
(g the reading in nominal g, dT = T - T_mid, t the capture time):

  gain         W diagonal: u_c += w_c g_c
  cross_axis   W full (norm only: symmetric -- a rotation keeps the norm, so its
               antisymmetric part is invisible)
  offset       u_c += v_c
  cubic        u_c += Gamma_c g_c^3                       (AN4399 Eqn 67: inverts the sim exactly)
  quadratic    u_c += q_c g_c^2                           (inverts the sim's square term exactly)
  temperature  u_c += (a_c g_c + b_c) dT  (+ (a2_c g_c + b2_c) dT^2 at three or more temperatures)
  drift        u_c -= a_c (1 - exp(-t / tau)) + b_c t / T (warm-up and trend; tau on a grid; raw only)
  gravity      gamma -> gamma (1 + delta)                 (degenerate whenever a gain is fitted)

Time view (raw captures only).  Each capture is cut into blocks; a block's mean minus
its capture's mean is ``e_kb = F_kb theta`` plus noise (3 rows per block):

  drift        the same d(t) as above, within the capture
  settling     x(t) += a_k exp(-(t - t0_k) / tau): tau shared, the amplitude a_k a random
               effect per capture and axis (a ~ N(0, psi^2)), because automatic segmentation
               trims each capture's transient by a different amount; the transient's mean
               is removed from the static view too (see evaluate)

Spread view (std and n, or raw samples).  Each pose's within-pose variance against the
per-sample variance the model predicts; scored, not part of the headline gap.

Floor.  The variance of a pose mean of n samples with white noise sigma and
quantization step q is ``B + (sigma^2 + q^2/12 - B) / n`` per axis, where
``B = sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2 / q^2)`` is the part of the
quantization error that averaging cannot remove (the Fourier series of the
rounding error smoothed by the noise; B = q^2/12 without noise, 0 when the noise
dithers).  Pose scatter s (rad, per rotation axis) adds ``s^2 (1 - ref_c^2)``.
Stochastic candidates refit these from the data instead of taking them from the
configuration: ``noise`` (sigma from the poses' std or raw first differences),
``quantization`` (q from the raw samples' value grid), ``pose_error`` (s by maximum
likelihood on training residuals).

Held-out evaluation.  Poses (captures) are split into K folds; each fold's
residuals come from a fit on the others, and their variance is the floor plus the
fit's own prediction variance ``a^T (A^T V^-1 A)^-1 a``, so a model that explains
the data scores a held-out gap of 1 (with raw captures: the RMS of the static and time
views' gaps).  The score of a model is its Gaussian log predictive density per
(pose, axis) -- a proper score: it rewards neither inflated nor shrunken variance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .effects import DETERMINISTIC
from .effects.columns import StaticView
from .evaluation import Evaluation, nll as _nll
from .identifiability import describe_terms
from .gap_data import (MAX_FOLDS, TAU_DRIFT_S, TAU_SETTLE_S, Capture, GapData, TimeData,  # noqa: F401  (API)
                       time_data, value_step)
from .noise_floor import (Floor, bias_var, mean_var, random_var, sigma_from_within,  # noqa: F401  (API)
                          within_spread)

_S2_GRID = np.concatenate([[0.0], np.geomspace(1e-12, 1e-2, 121)])  # pose scatter variance, rad^2
_PSI2_GRID = np.concatenate([[0.0], np.geomspace(1e-14, 1e-2, 73)])  # settling amplitude variance, g^2


# -- static design ---------------------------------------------------------------------------

def static_design(E, g, ref, dT, drift_h, norm: bool, n_temps: int, g0=None):
    """Design of the static view for effects E.

    g: (..., P, 3) readings; ref: (P, 3) or None; dT: (P,) or None; drift_h: (..., P, 2) or None;
    g0: (3,) the zero-g reading: a sensor's nonlinearity acts on its response to force, G - g0
    (reading = S a + c (S a)^3 + b), so the cubic and square columns are centred there.
    Returns A (..., P, 3, p), b (..., P, 3), d (p,) norm-shift flags, labels (p,) of (effect, detail).
    """
    lead = g.shape[:-2]
    if drift_h is not None:
        lead = np.broadcast_shapes(lead, drift_h.shape[:-2])
    g = np.broadcast_to(g, lead + g.shape[-2:])
    P = g.shape[-2]
    z0 = np.zeros(3) if g0 is None else np.asarray(g0, float)
    view = StaticView(g, ref, dT, drift_h, norm, n_temps, z0, frozenset(E))
    for name, effect in DETERMINISTIC.items():
        if name in E:
            effect.columns(view)
    # W = I without gain or cross_axis: the nominal sensitivity is taken as exact
    b = np.zeros(lead + (P, 3)) + (0.0 if {"gain", "cross_axis"} & set(E) else g)
    A = np.stack(view.cols, axis=-1) if view.cols else np.zeros(lead + (P, 3, 0))
    return A, b, np.array(view.shifts), view.labels


def describe_design(data, effects) -> dict:
    """identifiability.describe_terms of the static design of ``effects`` on ideal readings
    (g = ref, or unit readings without references).  data: a gap_data.GapData."""
    ideal = data.ref if data.ref is not None else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    A, _, _, labels = static_design(set(effects), ideal, data.ref, dT, dh, data.ref is None, data.n_temps)
    return describe_terms(A, labels, ideal)


def _pinv(G: np.ndarray) -> np.ndarray:
    return np.linalg.pinv(G, rcond=1e-12, hermitian=True)


def _wls(A, y, w):
    """Weighted least squares for a batch: A (N, R, p), y (N, R), w (N, R) -> theta (N, p), C (N, p, p)."""
    Aw = A * w[..., None]
    C = _pinv(A.swapaxes(-1, -2) @ Aw)
    theta = (C @ (Aw.swapaxes(-1, -2) @ y[..., None]))[..., 0]
    return theta, C


def _norm_resid(A, b, d, gamma, theta):
    u = np.einsum("npcq,nq->npc", A, theta) + b
    nrm = np.linalg.norm(u, axis=-1)
    r = nrm - gamma - (theta @ d)[:, None]
    uh = u / np.maximum(nrm, 1e-300)[..., None]
    J = np.einsum("npc,npcq->npq", uh, A) - d
    return r, J, uh


def _lm_norm(A, b, d, gamma, w, theta0, iters: int = 40):
    """Levenberg-Marquardt on r = |A theta + b| - gamma - d theta, weights w (N, P); batch N."""
    theta = np.array(theta0, float)
    N, p = theta.shape
    lam = np.full(N, 1e-3)
    r, J, _ = _norm_resid(A, b, d, gamma, theta)
    cost = np.sum(w * r**2, axis=1)
    for _ in range(iters):
        JtJ = np.einsum("npq,np,npr->nqr", J, w, J)
        grad = np.einsum("npq,np->nq", J, w * r)
        dg = np.maximum(np.einsum("nqq->nq", JtJ), 1e-12)
        M = JtJ + (lam[:, None] * dg)[..., None] * np.eye(p)
        step = -np.linalg.solve(M, grad[..., None])[..., 0]
        tn = theta + step
        rn, Jn, _ = _norm_resid(A, b, d, gamma, tn)
        cn = np.sum(w * rn**2, axis=1)
        ok = np.isfinite(cn) & (cn <= cost)
        theta[ok], r[ok], J[ok] = tn[ok], rn[ok], Jn[ok]
        small = ok & (cost - cn <= 1e-12 * np.maximum(cost, 1e-300))
        cost[ok] = cn[ok]
        lam = np.where(ok, np.maximum(lam / 10, 1e-12), lam * 10)
        if np.all(small | (lam > 1e10)):
            break
    C = _pinv(np.einsum("npq,np,npr->nqr", J, w, J))
    return theta, C


def _norm_start(g: np.ndarray, labels, gamma: float) -> np.ndarray:
    """Start of the norm fit: a sphere centred at the mid-range, radius the median norm."""
    c = 0.5 * (g.max(axis=0) + g.min(axis=0))
    s = float(np.median(np.linalg.norm(g - c, axis=1))) / gamma
    th = np.zeros(len(labels))
    for k, (eff, det) in enumerate(labels):
        if det.startswith("W_") and det[2] == det[3]:
            th[k] = 1.0 / s
        elif det.startswith("V_"):
            th[k] = -c["xyz".index(det[2])] / s
    return th


def design_rank_ok(E, data: GapData, norm: bool) -> tuple[bool, float]:
    """Whether the static terms of E are identifiable on ideal readings (g = ref, or unit readings).

    Judged on ideal data, like designs.predict_stderr, so that noise never makes a
    degenerate term look identifiable.  Returns (ok, column-scaled condition number).
    """
    ideal = data.ref if not norm else data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    td = time_data(data) if "drift" in E else None
    dh = None if td is None else np.stack([td.cap_drift1[len(TAU_DRIFT_S) // 2], td.cap_drift2], axis=-1)
    A, b, d, labels = static_design(E, ideal, data.ref, dT, dh, norm, data.n_temps)
    if not labels:
        return True, 1.0
    if norm:  # at the ideal solution W = I, everything else 0
        th = np.array([1.0 if det.startswith("W_") and det[2] == det[3] else 0.0 for _, det in labels])
        _, J, _ = _norm_resid(A[None], b[None], d, 1.0, th[None])
        M = J[0]
    else:
        M = A.reshape(-1, A.shape[-1])
    sc = np.linalg.norm(M, axis=0)
    if np.any(sc == 0):
        return False, np.inf
    s = np.linalg.svd(M / sc, compute_uv=False)
    cond = float(s[0] / max(s[-1], 1e-300))
    return cond < 1e6, cond


# -- evaluation ------------------------------------------------------------------------------

@dataclass
class Folds:
    """The held-out split: fold (P,) of every pose; train (F, P), F = K + 1: fold K is the whole-data fit."""

    fold: np.ndarray
    train: np.ndarray

    @property
    def F(self) -> int:
        return self.train.shape[0]


@dataclass
class NoiseModel:
    """Per-fold white-noise sigma (F, 3) g and quantization step q (F,) g: the configuration's, or refitted."""

    sigma: np.ndarray
    q: np.ndarray


@dataclass
class SpreadFit:
    """Each pose's within-pose variance against the predicted one: residual and variance (P, 3), g^2."""

    r: np.ndarray
    v: np.ndarray
    nll: np.ndarray  # (P, 3)


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
    params: dict


@dataclass
class StaticFit:
    """The static view's held-out residuals (P, m) and their variances (module doc)."""

    r: np.ndarray
    v: np.ndarray  # floor + fit
    floor: np.ndarray
    fitted: np.ndarray  # in-sample residuals of the whole-data fit
    pv: np.ndarray  # the fit's own prediction variance
    nll: np.ndarray  # (P, 3)
    n_params: int
    params: dict


@dataclass
class _StaticTry:
    """One static fit for every fold (one drift tau): cost (F,), residuals r, variances v0 and pv, leverage."""

    cost: np.ndarray
    r: np.ndarray
    v0: np.ndarray
    pv: np.ndarray
    lev: np.ndarray
    th: np.ndarray
    labels: list
    p: int


def _heldout(x: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Pick each pose's entry from its own fold: x (F, P, ...) -> (P, ...)."""
    return x[fold, np.arange(x.shape[1])]


def _folds(data: GapData) -> Folds:
    fold = data.folds()
    K = int(fold.max()) + 1
    train = np.ones((K + 1, data.P), bool)
    train[:K] = fold[None, :] != np.arange(K)[:, None]
    return Folds(fold, train)


def _noise_model(data: GapData, floor: Floor, added, td: TimeData | None, fo: Folds, params: dict) -> NoiseModel:
    """The floor's sigma and q per fold; ``quantization`` and ``noise`` refit them on the training poses."""
    F, train = fo.F, fo.train
    sigma = np.broadcast_to(floor.sigma_g, (F, 3)).copy()
    q = np.full(F, floor.q_g)
    if "quantization" in added and td is not None:
        q = np.array([td.lsb_g(train[f]) for f in range(F)])
        params["lsb_g"] = float(q[-1])
    if "noise" in added:
        if td is not None:
            w2 = np.array([np.nanmean(td.diff_var[train[f]], axis=0) for f in range(F)])
        else:
            nn = data.n[:, None] - 1.0
            w2 = np.array([np.sum(nn[train[f]] * data.std_g[train[f]] ** 2, 0) / np.sum(nn[train[f]]) for f in range(F)])
        sigma = sigma_from_within(w2, q[:, None])
        params["sigma_g"] = sigma[-1].tolist()
    return NoiseModel(sigma, q)


def _spread_view(data: GapData, td: TimeData | None, nm: NoiseModel, fo: Folds) -> SpreadFit | None:
    """Within-pose variance against the per-sample variance predicted (sample variance: var 2 s^4/(n-1);
    half the mean squared first difference: 3 s^4/(n-1)); scored, not part of the gap."""
    w2_obs, c_var = (td.diff_var, 3.0) if td is not None else (data.std_g**2 if data.std_g is not None else None, 2.0)
    if w2_obs is None:
        return None
    F, P = fo.F, data.P
    sigma, q = nm.sigma[:, None, :], nm.q[:, None, None]
    pred = np.broadcast_to(random_var(sigma, q), (F, P, 3))
    vs = c_var * pred**2 / np.maximum(data.n[None, :, None] - 1.0, 1.0) \
        + np.broadcast_to(within_spread(sigma, q), (F, P, 3))
    ok = np.isfinite(w2_obs)
    r = _heldout(np.where(ok, w2_obs - pred, 0.0), fo.fold)
    v = _heldout(vs, fo.fold)
    return SpreadFit(r, v, np.where(ok, _nll(r, v), 0.0))


def _drift_time(td: TimeData, target: np.ndarray, wtr: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
    """Warm-up and trend per axis on the block rows, tau on a grid per fold: (data minus fit, its prediction
    variance, the whole-data fit's parameters)."""
    F, R = wtr.shape
    y = np.broadcast_to(td.e, (F, R)).copy()
    pv = np.zeros((F, R))
    best_cost = np.full(F, np.inf)
    params: dict = {}
    for a in range(len(TAU_DRIFT_S)):
        D = np.zeros((R, 6))
        for c in range(3):
            on = td.axis == c
            D[on, 2 * c], D[on, 2 * c + 1] = td.drift1[a][on], td.drift2[on]
        th, C = _wls(np.broadcast_to(D, (F, R, 6)), target, wtr)
        cost = np.sum(wtr * (target - th @ D.T) ** 2, axis=1)
        b = cost < best_cost
        best_cost[b] = cost[b]
        y[b] = td.e[None] - th[b] @ D.T
        pv[b] = np.einsum("rp,fpq,rq->fr", D, C[b], D)
        if b[-1]:
            params["drift_tau_s_time"] = float(TAU_DRIFT_S[a])
            params.update({f"drift_time:{k}_{ax}": float(v) for (ax, k), v in
                           zip([(ax, k) for ax in "xyz" for k in ("warmup", "trend")], th[-1])})
    return y, pv, params


@dataclass
class _SettleFit:
    """Settling's fit per fold: the BLUP transient on every row, its posterior variance, and per pose."""

    fit_rows: np.ndarray  # (F, R)
    post_rows: np.ndarray  # (F, R)
    corr: np.ndarray  # (F, P, 3)
    extra: np.ndarray  # (F, P, 3)
    gain: np.ndarray | None  # (F, G) log marginal density gain of every capture-axis
    params: dict


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
    params = {"settling_tau_s": float(TAU_SETTLE_S[si[-1]]),
              "settling_amplitude_mg_rms": float(1e3 * np.sqrt(p2[-1, 0])),
              "_settling_a_g": _heldout(a_hat.reshape(F, P, 3), fo.fold)}  # each capture's, held out
    return _SettleFit(a_hat[:, gkey] * f_rows, post[:, gkey] * f_rows**2, a_hat.reshape(F, P, 3) * cap[:, :, None],
                      post.reshape(F, P, 3) * cap[:, :, None] ** 2, gain[qi, si, fi], params)


def _time_view(td: TimeData, E: set, nm: NoiseModel, fo: Folds, P: int) -> TimeFit:
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
    drift_params: dict = {}
    for _ in range(2 if {"drift", "settling"} <= E else 1):
        if "drift" in E:
            y, pv_d, drift_params = _drift_time(td, td.e[None] - st.fit_rows, wtr)
        if "settling" in E:
            st = _settling_time(td, y, v_row, fo, P)
    nll_gain = None if st.gain is None else st.gain[np.repeat(fo.fold, 3), np.arange(3 * P)].reshape(P, 3)
    return TimeFit(r=(y - st.fit_rows)[fr, rows], v=(v_row + pv_d - st.post_rows)[fr, rows],  # V - f^2 Var(a|e)
                    floor=v_row[fr, rows], nll_rows=_nll(y[fr, rows], (v_row + pv_d)[fr, rows]), nll_gain=nll_gain,
                    corr=st.corr, extra=st.extra, n_params=(6 if "drift" in E else 0) + (2 if "settling" in E else 0),
                    params={**drift_params, **st.params})


def _static_try(data: GapData, gamma: float, E: set, g: np.ndarray, dT, dh, v0: np.ndarray,
                train: np.ndarray) -> _StaticTry:
    """Fit the static view on every fold at once: weighted least squares with references (3 rows a pose),
    Levenberg-Marquardt on the norm without (1 row); v0 (F, P, 3) with references, (F, P) on the norm."""
    norm, F, P = data.norm_only, train.shape[0], data.P
    A, b, d, labels = static_design(E, g, data.ref, dT, dh, norm, data.n_temps, data.zero_g)
    p = A.shape[-1]
    if norm:
        w = train / v0
        th0 = np.broadcast_to(_norm_start(data.g, labels, gamma), (F, p))
        th, C = _lm_norm(A, b, d, gamma, w, th0)
        r, J, _ = _norm_resid(A, b, d, gamma, th)
        pv = np.einsum("fpq,fqr,fpr->fp", J, C, J)
        r, v0, pv = r[..., None], v0[..., None], pv[..., None]
        lev = w[..., None] * pv
    else:
        y = (gamma * data.ref)[None] - b  # (F, P, 3)
        Af = A.reshape(F, P * 3, p)
        wf = (train[:, :, None] / v0).reshape(F, P * 3)
        th, C = _wls(Af, y.reshape(F, P * 3), wf)
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


def _static_view(data: GapData, floor: Floor, E: set, added, td: TimeData | None, nm: NoiseModel, fo: Folds,
                 corr: np.ndarray, extra: np.ndarray) -> StaticFit:
    """Pose means (settling's transient mean removed) against the references or the norm (module doc)."""
    norm, F, P, train = data.norm_only, fo.F, data.P, fo.train
    g = data.g[None] - corr  # (F, P, 3)
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    use_drift = "drift" in E and td is not None
    grid = range(len(TAU_DRIFT_S)) if use_drift else [None]
    s2 = np.full(F, floor.scatter_rad**2)
    floor0 = np.broadcast_to(mean_var(nm.sigma[:, None, :], nm.q[:, None, None], data.n[None, :, None]), (F, P, 3))
    base_v = floor0 + extra  # (F, P, 3)
    shape = None if norm else 1.0 - (data.ref / np.linalg.norm(data.ref, axis=1, keepdims=True)) ** 2
    uh = data.g / np.linalg.norm(data.g, axis=1, keepdims=True) if norm else None
    floor0 = np.sum(uh**2 * floor0, axis=-1)[..., None] if norm else floor0 + floor.scatter_rad**2 * shape[None]
    params: dict = {}
    n_iter = 3 if "pose_error" in added and not norm else 1
    for it in range(n_iter):
        v0 = np.sum(uh**2 * base_v, axis=-1) if norm else base_v + s2[:, None, None] * shape[None]
        tries = [_static_try(data, floor.gamma, E, g, dT, None if a is None else
                             np.stack([td.cap_drift1[a], td.cap_drift2], axis=-1), v0, train) for a in grid]
        t, best = _best_try(tries)
        if use_drift:
            params["drift_tau_s"] = float(TAU_DRIFT_S[grid[best]])
        if it < n_iter - 1:
            s2 = _scatter_ml(t, base_v, shape, train)
    params.update({f"{e}:{det}": float(v) for (e, det), v in zip(t.labels, t.th[-1])})
    if "pose_error" in added and not norm:
        params["scatter_deg"] = float(np.degrees(np.sqrt(s2[-1])))
    r_s, v_s = _heldout(t.r, fo.fold), _heldout(t.v0 + t.pv, fo.fold)
    nll = np.zeros((P, 3))
    if norm:  # a norm residual goes to the axis nearest gravity
        np.add.at(nll, (np.arange(P), np.argmax(np.abs(data.g), axis=1)), _nll(r_s, v_s)[:, 0])
    else:
        nll = _nll(r_s, v_s)
    return StaticFit(r_s, v_s, _heldout(floor0, fo.fold), t.r[-1], _heldout(t.pv, fo.fold), nll, t.p, params)


def evaluate(data: GapData, floor: Floor, baseline: tuple[str, ...], added: tuple[str, ...] = (),
             td: TimeData | None = None, static_ok: bool = True) -> Evaluation:
    """Held-out evaluation of the model ``baseline + added`` (module doc).

    ``baseline``: the configuration's deterministic effects (fitted); ``added``: candidates.
    Fold K (the last) is the whole-data fit whose parameters are reported.  The score is summed
    per test unit (pose, axis): spread view, then time view, then static view.
    """
    E = set(baseline) | set(added)
    P = data.P
    fo = _folds(data)
    params: dict = {}
    nm = _noise_model(data, floor, added, td, fo, params)
    nll = np.zeros((P, 3))
    sp = _spread_view(data, td, nm, fo)
    if sp is not None:
        nll += sp.nll
    tv = None if td is None else _time_view(td, E, nm, fo, P)
    if tv is not None:
        params.update(tv.params)
        np.add.at(nll, (td.unit, td.axis), tv.nll_rows)
        if tv.nll_gain is not None:
            nll -= tv.nll_gain
    sv = None
    if static_ok:
        zero = np.zeros((fo.F, P, 3))
        sv = _static_view(data, floor, E, added, td, nm, fo, zero if tv is None else tv.corr,
                          zero if tv is None else tv.extra)
        params.update(sv.params)
        nll += sv.nll
    n_var = {"pose_error": 1}  # noise and quantization are measured within poses, not fitted to residuals
    n_params = (sv.n_params if sv else 0) + (tv.n_params if tv else 0) + sum(n_var.get(a, 0) for a in added)
    return Evaluation(tuple(added), n_params, _part(sv, "r"), _part(sv, "v"), _part(sv, "floor"), _part(tv, "r"),
                      _part(tv, "v"), nll, params, _part(sv, "fitted"), _part(sp, "r"), _part(sp, "v"),
                      _part(tv, "floor"), _part(sv, "pv"))


def _part(view, name: str) -> np.ndarray | None:
    """A view's array, or None when the view was not evaluated."""
    return None if view is None else getattr(view, name)

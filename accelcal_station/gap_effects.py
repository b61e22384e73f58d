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

import numpy as np

from .effects import DETERMINISTIC
from .effects.columns import StaticView
from .evaluation import Evaluation, nll as _nll
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

def _heldout(x: np.ndarray, fold: np.ndarray) -> np.ndarray:
    """Pick each pose's entry from its own fold: x (F, P, ...) -> (P, ...)."""
    return x[fold, np.arange(x.shape[1])]


def evaluate(data: GapData, floor: Floor, baseline: tuple[str, ...], added: tuple[str, ...] = (),
             td: TimeData | None = None, static_ok: bool = True) -> Evaluation:
    """Held-out evaluation of the model ``baseline + added`` (module doc).

    ``baseline``: the configuration's deterministic effects (fitted); ``added``: candidates.
    Fold K (the last) is the whole-data fit whose parameters are reported.
    """
    E = set(baseline) | set(added)
    P = data.P
    fold = data.folds()
    K = int(fold.max()) + 1
    F = K + 1
    train = np.ones((F, P), bool)
    train[:K] = fold[None, :] != np.arange(K)[:, None]
    params: dict = {}

    # the variance model, per fold
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

    # spread view: each pose's within-pose variance against the per-sample variance predicted
    # (sample variance: var 2 s^4/(n-1); half the mean squared first difference: 3 s^4/(n-1))
    nll = np.zeros((P, 3))  # test units: (pose, axis); a norm residual goes to the axis nearest gravity
    r_sp = v_sp = None
    w2_obs, c_var = (td.diff_var, 3.0) if td is not None else (data.std_g**2 if data.std_g is not None else None, 2.0)
    if w2_obs is not None:
        pred = np.broadcast_to(random_var(sigma[:, None, :], q[:, None, None]), (F, P, 3))
        vs = c_var * pred**2 / np.maximum(data.n[None, :, None] - 1.0, 1.0) \
            + np.broadcast_to(within_spread(sigma[:, None, :], q[:, None, None]), (F, P, 3))
        ok = np.isfinite(w2_obs)
        r_sp = _heldout(np.where(ok, w2_obs - pred, 0.0), fold)
        v_sp = _heldout(vs, fold)
        nll += np.where(ok, _nll(r_sp, v_sp), 0.0)

    # time view.  Drift: shared terms (held out by capture).  Settling: tau shared, and the
    # transient's amplitude at the start of each capture a random effect a ~ N(0, psi^2) per
    # axis -- auto-segmentation trims every capture's transient by a different amount, so the
    # amplitude is a property of the capture, not of the board.  tau and psi^2 are fitted on
    # training captures by maximum marginal likelihood; a held-out capture is scored by its
    # marginal density N(e; 0, V + psi^2 f f^T) (proper, comparable with the baseline's N(e; 0, V)),
    # and its amplitude estimated (BLUP) to extrapolate the settled mean for the static view.
    r_time = v_time = fl_time = None
    corr = np.zeros((F, P, 3))
    extra = np.zeros((F, P, 3))  # variance the settled-mean extrapolation adds to a pose mean
    n_time = 0
    if td is not None:
        R = len(td.e)
        rows = np.arange(R)
        fr = fold[td.unit]
        v_row = random_var(sigma[:, td.axis], q[:, None]) * td.inv_m  # (F, R)
        wtr = train[:, td.unit] / v_row
        gkey = td.unit * 3 + td.axis
        n_time = (6 if "drift" in E else 0) + (2 if "settling" in E else 0)
        y = np.broadcast_to(td.e, (F, R)).copy()  # data minus the fitted drift
        pv_d = np.zeros((F, R))  # drift's prediction variance
        settle_fit = np.zeros((F, R))
        post_rows = np.zeros((F, R))
        g_all = None
        for _ in range(2 if {"drift", "settling"} <= E else 1):
            if "drift" in E:
                target = td.e[None] - settle_fit
                best_cost = np.full(F, np.inf)
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
                    pv_d[b] = np.einsum("rp,fpq,rq->fr", D, C[b], D)
                    if b[-1]:
                        params["drift_tau_s_time"] = float(TAU_DRIFT_S[a])
                        params.update({f"drift_time:{k}_{ax}": float(v) for (ax, k), v in
                                       zip([(ax, k) for ax in "xyz" for k in ("warmup", "trend")], th[-1])})
            if "settling" in E:
                wv = 1.0 / v_row  # (F, R)
                Sff = np.stack([np.stack([np.bincount(gkey, wv[fo] * f * f, minlength=3 * P) for fo in range(F)])
                                for f in td.settle])  # (Gs, F, G)
                Sfe = np.stack([np.stack([np.bincount(gkey, wv[fo] * f * y[fo], minlength=3 * P) for fo in range(F)])
                                for f in td.settle])
                psi2 = _PSI2_GRID[:, None, None, None]
                gain = 0.5 * (psi2 * Sfe**2 / (1 + psi2 * Sff) - np.log1p(psi2 * Sff))  # (Q, Gs, F, G)
                ll = np.sum(gain * np.repeat(train, 3, axis=1), axis=-1)  # (Q, Gs, F): training captures only
                qi, si = np.unravel_index(ll.reshape(-1, F).argmax(axis=0), ll.shape[:2])
                fi = np.arange(F)
                p2, sff, sfe = _PSI2_GRID[qi][:, None], Sff[si, fi], Sfe[si, fi]  # (F, 1), (F, G)
                g_all = gain[qi, si, fi]  # (F, G): log marginal density gain of every capture-axis
                post = np.where(p2 > 0, 1.0 / (1.0 / np.where(p2 > 0, p2, 1.0) + sff), 0.0)  # Var(a | e), g^2
                a_hat = post * sfe  # BLUP amplitude at the capture's start, g
                f_rows = td.settle[si]  # (F, R)
                settle_fit = a_hat[:, gkey] * f_rows
                post_rows = post[:, gkey] * f_rows**2
                cap = td.cap_settle[si]  # (F, P)
                corr = a_hat.reshape(F, P, 3) * cap[:, :, None]
                extra = post.reshape(F, P, 3) * cap[:, :, None] ** 2
                params["settling_tau_s"] = float(TAU_SETTLE_S[si[-1]])
                params["settling_amplitude_mg_rms"] = float(1e3 * np.sqrt(p2[-1, 0]))
                params["_settling_a_g"] = _heldout(a_hat.reshape(F, P, 3), fold)  # each capture's, held out
        r_time = (y - settle_fit)[fr, rows]
        fl_time = v_row[fr, rows]
        v_time = (v_row + pv_d - post_rows)[fr, rows]  # Var(e - f a_hat) = V - f^2 Var(a | e)
        np.add.at(nll, (td.unit, td.axis), _nll(y[fr, rows], (v_row + pv_d)[fr, rows]))
        if g_all is not None:
            nll -= g_all[np.repeat(fold, 3), np.arange(3 * P)].reshape(P, 3)

    # static view
    r_s = v_s = fl_s = fit_s = pv_s = None
    n_static = 0
    if static_ok:
        norm = data.norm_only
        g = data.g[None] - corr  # (F, P, 3): settling's transient mean removed
        dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
        use_drift = "drift" in E and td is not None
        grid = range(len(TAU_DRIFT_S)) if use_drift else [None]
        s2 = np.full(F, floor.scatter_rad**2)
        floor0 = np.broadcast_to(mean_var(sigma[:, None, :], q[:, None, None], data.n[None, :, None]), (F, P, 3))
        base_v = floor0 + extra  # (F, P, 3)
        shape = None if norm else 1.0 - (data.ref / np.linalg.norm(data.ref, axis=1, keepdims=True)) ** 2
        if norm:
            uh0 = data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
            floor0 = np.sum(uh0**2 * floor0, axis=-1)[..., None]
        else:
            floor0 = floor0 + floor.scatter_rad**2 * shape[None]
        n_iter = 3 if "pose_error" in added and not norm else 1
        for it in range(n_iter):
            outs = []
            for a in grid:
                dh = None if a is None else np.stack([td.cap_drift1[a], td.cap_drift2], axis=-1)
                A, b, d, labels = static_design(E, g, data.ref, dT, dh, norm, data.n_temps, data.zero_g)
                p = A.shape[-1]
                if norm:
                    uh = data.g / np.linalg.norm(data.g, axis=1, keepdims=True)
                    v0 = np.sum(uh**2 * base_v, axis=-1)  # (F, P)
                    w = train / v0
                    th0 = np.broadcast_to(_norm_start(data.g, labels, floor.gamma), (F, p))
                    th, C = _lm_norm(A, b, d, floor.gamma, w, th0)
                    r, J, _ = _norm_resid(A, b, d, floor.gamma, th)
                    pv = np.einsum("fpq,fqr,fpr->fp", J, C, J)
                    r, v0, pv = r[..., None], v0[..., None], pv[..., None]
                    lev = w[..., None] * pv
                else:
                    v0 = base_v + s2[:, None, None] * shape[None]
                    y = (floor.gamma * data.ref)[None] - b  # (F, P, 3)
                    Af = A.reshape(F, P * 3, p)
                    wf = (train[:, :, None] / v0).reshape(F, P * 3)
                    th, C = _wls(Af, y.reshape(F, P * 3), wf)
                    r = y - np.einsum("fpcq,fq->fpc", A, th)
                    pv = np.einsum("fpcq,fqr,fpcr->fpc", A, C, A)
                    lev = (train[:, :, None] / v0) * pv
                cost = np.sum(train[:, :, None] * r**2 / v0, axis=(1, 2))
                outs.append((cost, r, v0, pv, lev, th, labels, p))
            costs = np.stack([o[0] for o in outs])
            best = np.argmin(costs, axis=0)
            pick = lambda k: np.stack([outs[best[f]][k][f] for f in range(F)])  # noqa: E731
            r, v0, pv, lev, th = pick(1), pick(2), pick(3), pick(4), pick(5)
            labels, n_static = outs[best[-1]][6], outs[best[-1]][7]
            if use_drift:
                params["drift_tau_s"] = float(TAU_DRIFT_S[grid[best[-1]]])
            if it < n_iter - 1:
                # maximum likelihood s^2 per fold on leverage-corrected training residuals
                rc2 = r**2 / np.clip(1.0 - lev, 0.05, 1.0)
                vb = base_v[:, None] + _S2_GRID[None, :, None, None] * shape[None, None]  # (F, S, P, 3)
                ll = -0.5 * np.sum(train[:, None, :, None] * (np.log(vb) + rc2[:, None] / vb), axis=(2, 3))
                s2 = _S2_GRID[np.argmax(ll, axis=1)]
        fit_s = r[-1]
        params.update({f"{e}:{det}": float(v) for (e, det), v in zip(labels, th[-1])})
        if "pose_error" in added and not norm:
            params["scatter_deg"] = float(np.degrees(np.sqrt(s2[-1])))
        r_s = _heldout(r, fold)
        fl_s = _heldout(floor0, fold)
        v_s = _heldout(v0 + pv, fold)
        pv_s = _heldout(pv, fold)
        if norm:
            np.add.at(nll, (np.arange(P), np.argmax(np.abs(data.g), axis=1)), _nll(r_s, v_s)[:, 0])
        else:
            nll += _nll(r_s, v_s)
    n_var = {"pose_error": 1}  # noise and quantization are measured within poses, not fitted to residuals
    n_params = n_static + n_time + sum(n_var.get(a, 0) for a in added)
    return Evaluation(tuple(added), n_params, r_s, v_s, fl_s, r_time, v_time, nll, params, fit_s, r_sp, v_sp,
                      fl_time, pv_s)

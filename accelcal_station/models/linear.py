"""AN4399 linear least-squares models: 6, 12 and 15 parameters, and closed forms.

Per output channel c the model is linear in its coefficients:
  6  parameters  G_c = W_cc G_fc + V_c                             (AN4399 Eqns 6-17 generalised)
  12 parameters  G_c = W_cx G_fx + W_cy G_fy + W_cz G_fz + V_c     (AN4399 Eqns 35-48)
  15 parameters  the 12 above + Gamma_cc G_fc^3                    (AN4399 Eqns 67-72)
and is solved per channel by least squares against the pose references,
``beta = (X^T X)^-1 X^T Y`` (AN4399 Eqn 46), for a stack of boards at once.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UnderdeterminedError
from .result import BatchFit

AXES = "xyz"
N_COEF = {"6": 2, "12": 4, "15": 5}
COND_LIMIT = 1e7  # beyond this the poses do not determine the model in float64 at mg level


def param_names(model: str) -> list[str]:
    w = [f"W_{r}{c}" for r in AXES for c in AXES]
    v = [f"V_{a}" for a in AXES]
    if model == "6":
        return [f"W_{a}{a}" for a in AXES] + v
    if model == "12":
        return w + v
    return w + v + [f"Gamma_{a}{a}" for a in AXES]


def regressors(gf: np.ndarray, model: str) -> np.ndarray:
    """Design matrix per channel, shape (D, 3, P, k), from readings in g (D, P, 3)."""
    D, P, _ = gf.shape
    if model == "6":
        return np.stack([gf, np.ones_like(gf)], axis=-1).transpose(0, 2, 1, 3)
    base = np.concatenate([gf, np.ones((D, P, 1))], axis=-1)  # (D, P, 4)
    X = np.broadcast_to(base[:, None], (D, 3, P, 4))
    if model == "12":
        return X
    cubic = (gf**3).transpose(0, 2, 1)[..., None]  # (D, 3, P, 1)
    return np.concatenate([X, cubic], axis=-1)


def coefficients_to_an4399(beta: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map per-channel coefficient vectors (D, 3, k) to W (D,3,3), V (D,3), Gamma (D,3)."""
    D = beta.shape[0]
    W = np.zeros((D, 3, 3))
    G = np.zeros((D, 3))
    if model == "6":
        idx = np.arange(3)
        W[:, idx, idx] = beta[..., 0]
        V = beta[..., 1]
    else:
        W = beta[..., :3].copy()
        V = beta[..., 3].copy()
        if model == "15":
            G = beta[..., 4].copy()
    return W, V, G


def _params(W: np.ndarray, V: np.ndarray, G: np.ndarray, model: str) -> np.ndarray:
    """The parameter vector (D, k) in the order of param_names(model)."""
    D = W.shape[0]
    if model == "6":
        return np.concatenate([np.diagonal(W, axis1=1, axis2=2), V], axis=1)
    if model == "12":
        return np.concatenate([W.reshape(D, 9), V], axis=1)
    return np.concatenate([W.reshape(D, 9), V, G], axis=1)


def diagnose_underdetermined(gf: np.ndarray, model: str) -> str:
    """Say what a single board's pose set is missing for ``model`` (gf: (P, 3) in g)."""
    P = gf.shape[0]
    k = N_COEF[model]
    if k > P:
        return f"model {model} needs at least {k} poses; got {P}"
    spread = gf.max(axis=0) - gf.min(axis=0)
    for c in range(3):
        if spread[c] < 0.05:
            return (f"channel {AXES[c]} has no spread across the {P} poses (all within {spread[c]:.3f} g): "
                    f"add poses that tilt the {AXES[c]} axis toward and away from gravity")
    if model in ("12", "15"):
        centred = gf - gf.mean(axis=0)
        _, s, vt = np.linalg.svd(centred, full_matrices=False)
        if s[-1] < 1e-3 * s[0]:
            n = vt[-1]
            return (f"the {P} poses lie in a plane (normal {n[0]:+.2f}, {n[1]:+.2f}, {n[2]:+.2f}): "
                    f"model {model} needs poses out of that plane")
    if model == "15":
        # opposite pairs (p, -p): the four odd columns g_x, g_y, g_z, g_c^3 take only
        # (number of pairs) independent values, so the cubic is lost among gain and cross-axis
        d = gf / np.linalg.norm(gf, axis=1, keepdims=True)
        paired = _all_paired(d)
        if paired and P // 2 < 4:
            return (f"the {P} poses are {P // 2} opposite pairs: the cubic terms cannot be told from gain and "
                    "cross-axis; model 15 needs at least 4 directions that are not opposite, e.g. an4399-8")
        for c in range(3):
            levels = np.unique(np.round(np.abs(gf[:, c]), 1))
            if len(levels) < 3 or np.all(np.isin(levels, (0.0, 1.0))):
                return (f"the cubic term of channel {AXES[c]} cannot be told from its gain with these poses "
                        f"(channel {AXES[c]} only near 0 and +-1 g): model 15 needs intermediate tilts, e.g. an4399-8")
    return f"the poses do not determine model {model} (the design is numerically singular)"


def _all_paired(d: np.ndarray, block: int = 1 << 21) -> bool:
    """Every unit direction d_p has an opposite: min_q |d_p + d_q| < 0.1.  Rows a block at a time,
    so memory stays linear in the pose count."""
    P = len(d)
    step = max(1, block // max(1, P))
    sq = np.sum(d * d, axis=1)
    for a in range(0, P, step):
        # |d_p + d_q|^2 = |d_p|^2 + |d_q|^2 + 2 d_p . d_q
        near = np.min(sq[a:a + step, None] + sq[None, :] + 2 * d[a:a + step] @ d.T, axis=1)
        if not np.all(near < 0.01):
            return False
    return True


def residual_variance(noise_g: ArrayLike | None, rss: np.ndarray, D: int, P: int, dof: int) -> np.ndarray:
    """Per-board, per-axis residual variance (D, 3), g^2: the measured noise (std/sqrt(n) per pose)
    when known, since a few poses' residuals estimate sigma too poorly; else RSS / (P - k); NaN when neither."""
    if noise_g is not None:
        nz = np.broadcast_to(np.asarray(noise_g, dtype=float), (D, P, 3))
        return np.einsum("dpk,dpk->dk", nz, nz) / P  # the mean of nz**2 over poses, with no (D, P, 3) temporary
    return rss / dof if dof > 0 else np.full((D, 3), np.nan)


def _solve_normal_equations(X: np.ndarray, y: np.ndarray, model: str
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``beta = (X^T X)^-1 X^T Y`` per board and channel (AN4399 Eqn 46).

    X (D, 3, P, k), y (D, 3, P).  Returns the design used Xs (model 12 shares one across
    channels: (D, 1, P, k)), (X^T X)^-1 (D, 1 or 3, k, k), beta (D, 3, k), the condition
    number of X per channel (D, 1 or 3) and ok (D,): the design determines the model."""
    k = N_COEF[model]
    # Normal equations on the (small, well-scaled) design: batched k x k inverses are
    # several times faster than batched SVDs, and cond(X) stays far below 1e8 for any
    # design that determines the model.  Model 12 shares one design across channels.
    Xs = X[:, :1] if model == "12" else X
    XsT = Xs.swapaxes(-1, -2)
    G = XsT @ Xs
    ev = np.linalg.eigvalsh(G)
    cond_c = np.sqrt(ev[..., -1] / np.maximum(ev[..., 0], 1e-300))
    bad = np.any(cond_c > COND_LIMIT, axis=1)
    G = np.where(bad[:, None, None, None], np.eye(k), G)  # keep singular boards from poisoning inv
    Ginv_s = np.linalg.inv(G)
    beta = (Ginv_s @ (XsT @ y[..., None]))[..., 0]  # (D, 3, k)
    return Xs, Ginv_s, beta, cond_c, ~bad


def _leave_one_out(Xs: np.ndarray, Ginv_s: np.ndarray, r: np.ndarray, ok: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-pose-out RMS (D,) and where it holds (D,) from the hat matrix diagonal
    ``h_ii = x_i^T (X^T X)^-1 x_i``: the left-out residual is ``r_i / (1 - h_ii)``."""
    h = np.broadcast_to(np.sum((Xs @ Ginv_s) * Xs, axis=-1), r.shape)
    cv_ok = np.all(h < 1.0 - 1e-9, axis=(1, 2)) & ok
    loo = r / np.where(h < 1.0 - 1e-9, 1.0 - h, 1.0)
    return np.where(cv_ok, np.sqrt(np.mean(loo**2, axis=(1, 2))), np.nan), cv_ok


def _sandwich(Xs: np.ndarray, cov_unit: np.ndarray, noise_g: ArrayLike, D: int, P: int) -> np.ndarray:
    """cov = G X^T diag(v) X G per board and channel (D, 3, k, k), G = (X^T X)^-1, v the poses' own
    squared standard errors: the OLS estimator's covariance with each pose's measured variance (GUM eq. 13);
    equal to mean(v) G when the poses' variances are equal, right when a sequential capture gave the poses
    unequal counts (models/allocation.py)."""
    v = np.broadcast_to(np.asarray(noise_g, dtype=float), (D, P, 3)).transpose(0, 2, 1) ** 2  # (D, 3, P)
    meat = np.einsum("dcpk,dcp,dcpl->dckl", Xs, v, Xs) if Xs.shape[1] == 3 else np.einsum(
        "dpk,dcp,dpl->dckl", Xs[:, 0], v, Xs[:, 0])
    return cov_unit @ meat @ cov_unit


def fit_linear_batch(gf: ArrayLike, ref: ArrayLike, model: str, noise_g: ArrayLike | None = None) -> BatchFit:
    """Least-squares fit of model 6, 12 or 15 for a stack of boards (AN4399 Eqn 46).

    gf: (D, P, 3) uncalibrated readings in g; ref: (D, P, 3) or (P, 3) expected output in g;
    noise_g: optional (D, P, 3) or (P, 3) standard error of each pose's mean in g.
    Boards whose poses cannot determine the model get ``ok=False`` and a message.
    """
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    ref = np.broadcast_to(np.asarray(ref, dtype=float), (D, P, 3))
    k = N_COEF[model]
    X = regressors(gf, model)  # (D, 3, P, k)
    y = ref.transpose(0, 2, 1)  # (D, 3, P)
    if k > P:
        msg = f"model {model} needs at least {k} poses; got {P}"
        raise UnderdeterminedError(msg)
    Xs, Ginv_s, beta, cond_c, ok = _solve_normal_equations(X, y, model)
    fitted = (Xs @ beta[..., None])[..., 0]
    r = y - fitted  # (D, 3, P): reference minus calibrated (AN4399 residual)
    rss = np.sum(r**2, axis=-1)  # (D, 3)
    cv_rms, cv_ok = _leave_one_out(Xs, Ginv_s, r, ok)
    cov_unit = np.broadcast_to(Ginv_s, (D, 3, k, k))  # (X^T X)^-1
    s2 = residual_variance(noise_g, rss, D, P, P - k)
    se_ok = np.all(np.isfinite(s2), axis=1) & ok
    if noise_g is None:
        cov = cov_unit * np.where(np.isfinite(s2), s2, 0.0)[..., None, None]  # (D, 3, k, k)
    else:
        cov = _sandwich(Xs, cov_unit, noise_g, D, P)
    se = np.sqrt(np.clip(np.diagonal(cov, axis1=2, axis2=3), 0.0, None))  # (D, 3, k)
    W, V, G = coefficients_to_an4399(beta, model)
    sW, sV, sG = coefficients_to_an4399(se, model)
    calibrated = ref - r.transpose(0, 2, 1)
    norm_err = np.linalg.norm(calibrated, axis=-1) - np.linalg.norm(ref, axis=-1)
    messages = [""] * D
    for d in np.flatnonzero(~ok):
        messages[d] = diagnose_underdetermined(gf[d], model)
    return BatchFit(
        model=model, W=W, V=V, Gamma=G,
        residuals_g=r.transpose(0, 2, 1), norm_error_g=norm_err, P=rss,
        residual_rms_g=np.sqrt(np.mean(r**2, axis=(1, 2))),
        crossval_rms_g=cv_rms, crossval_ok=cv_ok,
        condition_number=np.max(cond_c, axis=1),
        stderr_W=sW, stderr_V=sV, stderr_Gamma=sG, stderr_ok=se_ok,
        covariance=cov, params=_params(W, V, G, model), param_names=param_names(model),
        ok=ok, messages=messages, readings_g=gf,
    )


# -- AN4399 closed forms ---------------------------------------------------------------

def six_param_two_pose(gf0: ArrayLike, gf1: ArrayLike, ref0: ArrayLike | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Gain and offset from two opposite poses (AN4399 Eqns 6-17).

    gf0, gf1: readings in g (3,) at the two poses; ref0: expected output of pose 0
    (default +1/sqrt(3) on every axis, the note's +-g/sqrt(3) poses; pose 1 is -ref0).
    Returns (W_diag, V).
    """
    gf0 = np.asarray(gf0, dtype=float)
    gf1 = np.asarray(gf1, dtype=float)
    r0 = np.full(3, 1.0 / np.sqrt(3.0)) if ref0 is None else np.asarray(ref0, dtype=float)
    d = gf0 - gf1
    if np.any(np.abs(d) < 1e-6):
        raise UnderdeterminedError("the two poses read the same on some channel; they must be opposite")
    w = 2.0 * r0 / d
    return w, r0 - w * gf0


def six_param_six_face(g_plus: ArrayLike, g_minus: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Gain and offset per axis from the six faces, on-axis channel only (AN4399 Eqns 12-17).

    g_plus[c], g_minus[c]: channel c's reading in g with +1 g and -1 g along c.
    """
    gp = np.asarray(g_plus, dtype=float)
    gm = np.asarray(g_minus, dtype=float)
    d = gp - gm
    if np.any(np.abs(d) < 1e-6):
        raise UnderdeterminedError("a channel reads the same on both faces; faces must be opposite")
    w = 2.0 / d
    return w, -w * (gp + gm) / 2.0

"""The 9-parameter gravity-norm model ``A = M (V - B)``, M symmetric (nine-position paper).

Fitted with no pose references by making every static reading's calibrated norm
equal to 1 g: residual ``r_i = |M (v_i - B)| - 1``, minimised by Levenberg-Marquardt
(Gauss-Newton with adaptive damping) for a whole stack of boards at once.  The
result is reported in AN4399 form as ``W = M``, ``V = -M B``, ``Gamma = 0``.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .result import BatchFit

PARAM_NAMES = ["M_xx", "M_yy", "M_zz", "M_xy", "M_xz", "M_yz", "B_x", "B_y", "B_z"]
_IU = ([0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2])  # where each M parameter sits
COND_LIMIT = 1e8


def nominal_scale(x: np.ndarray) -> np.ndarray:
    """Input units per g, estimated from static readings of any offset and scale (D,).

    The centre is the per-axis mid-range; the scale the median distance from it,
    so 16-bit unsigned counts centred at 32768 or m/s^2 both come out right.
    """
    centre = 0.5 * (x.max(axis=1) + x.min(axis=1))
    r = np.median(np.linalg.norm(x - centre[:, None, :], axis=-1), axis=1)
    return np.where(r > 0, r, 1.0)


def _sphere_start(gf: np.ndarray) -> np.ndarray:
    """Starting parameters from a linear sphere fit |v|^2 = 2 v.c + k (D, 9)."""
    D, P, _ = gf.shape
    A = np.concatenate([2 * gf, np.ones((D, P, 1))], axis=-1)
    b = np.sum(gf**2, axis=-1)
    AtA = np.einsum("dpi,dpj->dij", A, A) + 1e-12 * np.eye(4)
    sol = np.linalg.solve(AtA, np.einsum("dpi,dp->di", A, b)[..., None])[..., 0]
    c = sol[:, :3]
    r2 = sol[:, 3] + np.sum(c**2, axis=1)
    # a poor sphere fit (too few or planar poses) falls back to the mid-range centre
    bad = ~np.isfinite(r2) | (r2 <= 0) | ~np.all(np.isfinite(c), axis=1)
    mid = 0.5 * (gf.max(axis=1) + gf.min(axis=1))
    c = np.where(bad[:, None], mid, c)
    r = np.median(np.linalg.norm(gf - c[:, None], axis=-1), axis=1)
    r = np.where(r > 0, r, 1.0)
    p0 = np.zeros((D, 9))
    p0[:, :3] = 1.0 / r[:, None]
    p0[:, 6:] = c
    return p0


def _unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M (D, 3, 3) symmetric and B (D, 3) from parameters (D, 9) ordered as PARAM_NAMES."""
    D = p.shape[0]
    M = np.zeros((D, 3, 3))
    M[:, _IU[0], _IU[1]] = p[:, :6]
    M[:, _IU[1], _IU[0]] = p[:, :6]
    return M, p[:, 6:]


def _residual_jacobian(p: np.ndarray, gf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r (D, P) and J (D, P, 9) of r_i = |M (v_i - B)| - 1."""
    M, B = _unpack(p)
    u = gf - B[:, None, :]
    a = np.einsum("dij,dpj->dpi", M, u)
    n = np.linalg.norm(a, axis=-1)
    ah = a / np.maximum(n, 1e-300)[..., None]
    J = np.empty(gf.shape[:2] + (9,))
    J[..., 0] = ah[..., 0] * u[..., 0]
    J[..., 1] = ah[..., 1] * u[..., 1]
    J[..., 2] = ah[..., 2] * u[..., 2]
    J[..., 3] = ah[..., 0] * u[..., 1] + ah[..., 1] * u[..., 0]
    J[..., 4] = ah[..., 0] * u[..., 2] + ah[..., 2] * u[..., 0]
    J[..., 5] = ah[..., 1] * u[..., 2] + ah[..., 2] * u[..., 1]
    J[..., 6:] = -np.einsum("dpi,dij->dpj", ah, M)
    return n - 1.0, J


def _held_jacobian(p: np.ndarray, gf: np.ndarray, free: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``_residual_jacobian`` with the held parameters' columns zeroed: a step never moves them
    (models/held.py), and their covariance rows come out zero."""
    r, J = _residual_jacobian(p, gf)
    if free is not None:  # (9,) shared or (D, 9) per board
        J *= free[:, None, :] if free.ndim == 2 else free
    return r, J


def levenberg_marquardt(gf: np.ndarray, p0: np.ndarray, max_iter: int = 200, tol: float = 1e-15,
                        free: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised LM over boards; returns params (D, 9), nfev (D,), converged (D,).

    ``free`` (9,) or (D, 9) bool: parameters not free stay at their value in ``p0`` (held at nominal)."""
    p = p0.copy()
    D = p.shape[0]
    lam = np.full(D, 1e-3)
    r, J = _held_jacobian(p, gf, free)
    cost = np.sum(r**2, axis=1)
    nfev = np.ones(D, dtype=int)
    active = np.ones(D, dtype=bool)
    for _ in range(max_iter):
        if not active.any():
            break
        ia = np.flatnonzero(active)
        Ja, ra = J[ia], r[ia]
        JtJ = np.einsum("dpi,dpj->dij", Ja, Ja)
        g = np.einsum("dpi,dp->di", Ja, ra)
        diag = np.einsum("dii->di", JtJ)
        A = JtJ + (lam[ia, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(9)
        try:
            step = np.linalg.solve(A, -g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.stack([np.linalg.lstsq(Ai, -gi, rcond=None)[0] for Ai, gi in zip(A, g, strict=True)])
        pn = p[ia] + step
        rn, Jn = _held_jacobian(pn, gf[ia], free if free is None or free.ndim == 1 else free[ia])
        cn = np.sum(rn**2, axis=1)
        nfev[ia] += 1
        better = np.isfinite(cn) & (cn <= cost[ia])
        ib = ia[better]
        small = np.abs(cost[ia] - np.where(better, cn, cost[ia])) <= tol * np.maximum(cost[ia], 1e-30)
        tiny = np.linalg.norm(step, axis=1) <= 1e-13 * (1 + np.linalg.norm(p[ia], axis=1))
        p[ib], r[ib], J[ib], cost[ib] = pn[better], rn[better], Jn[better], cn[better]
        lam[ib] = np.maximum(lam[ib] / 10, 1e-12)
        lam[ia[~better]] *= 10
        done = (better & (small | tiny)) | (~better & (lam[ia] > 1e12)) | (cost[ia] < 1e-28)
        active[ia[done]] = False
    return p, nfev, ~active


def _fit_core(gf: np.ndarray, free: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sphere start then LM: params (D, 9) on the positive-definite branch, nfev (D,), converged (D,).
    The sphere start has M diagonal, so held non-orthogonalities stay at 0."""
    p0 = _sphere_start(gf)
    p, nfev, conv = levenberg_marquardt(gf, p0, free=free)
    M, B = _unpack(p)
    # |M u| = |-M u|: keep the physical, positive-definite branch
    flip = np.trace(M, axis1=1, axis2=2) < 0
    p[flip, :6] *= -1
    return p, nfev, conv


def _refusals(gf: np.ndarray, cond: np.ndarray, conv: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """ok (D,) and a message per board the fit cannot stand for: poses that do not determine
    the nine parameters (cond(J) > COND_LIMIT), or LM stopped at its iteration limit."""
    D, P, _ = gf.shape
    ok = np.ones(D, dtype=bool)
    messages = [""] * D
    for d in np.flatnonzero(cond > COND_LIMIT):
        ok[d] = False
        centred = gf[d] - gf[d].mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[-1] < 1e-3 * sv[0]:
            messages[d] = (f"the {P} poses lie in a plane: model 9 needs orientations spread over the sphere "
                           "(e.g. six faces plus three tilts)")
        else:
            messages[d] = f"the {P} poses do not determine model 9 (condition number {cond[d]:.3g})"
    for d in np.flatnonzero(ok & ~conv):
        ok[d] = False
        messages[d] = "model 9 did not converge (Levenberg-Marquardt stopped at its iteration limit)"
    return ok, messages


def _covariance(J: np.ndarray, r: np.ndarray, noise_g: ArrayLike | None, ok: np.ndarray, k: int = 9
                ) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton covariance ``(J^T J)^-1 s^2`` (D, 9, 9) and where it holds (D,): s^2 is the
    measured noise when known (see linear.py), else RSS / (P - k), k free parameters."""
    D, P = r.shape
    dof = P - k  # k: the free parameters
    s2 = np.full(D, np.nan)
    if noise_g is not None:
        s2 = np.mean(np.asarray(noise_g) ** 2, axis=(1, 2))
    elif dof > 0:
        s2 = np.sum(r**2, axis=1) / dof
    JtJ = np.einsum("dpi,dpj->dij", J, J)
    cov = np.linalg.pinv(JtJ) * np.where(np.isfinite(s2), s2, 0.0)[:, None, None]
    if k < 9:  # held parameters (zero Jacobian columns): exactly zero variance, not pinv's round-off
        held = ~np.any(JtJ != 0, axis=(0, 1))
        cov[:, held, :] = 0.0
        cov[:, :, held] = 0.0
    return cov, np.isfinite(s2) & ok


def _stderr_an4399(M: np.ndarray, B: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard errors of W = M (D, 3, 3) and V = -M B (D, 3): the covariance of the nine
    parameters propagated through the Jacobians of those maps (first order, G cov G^T)."""
    D = M.shape[0]
    Gw = np.zeros((D, 9, 9))
    for j, (a, b) in enumerate(zip(*_IU, strict=True)):
        Gw[:, 3 * a + b, j] = 1.0
        Gw[:, 3 * b + a, j] = 1.0
    Gv = np.zeros((D, 3, 9))
    for j, (a, b) in enumerate(zip(*_IU, strict=True)):
        Gv[:, a, j] -= B[:, b]
        if a != b:
            Gv[:, b, j] -= B[:, a]
    Gv[:, :, 6:] = -M
    sW = np.sqrt(np.clip(np.einsum("dij,djk,dik->di", Gw, cov, Gw), 0, None)).reshape(D, 3, 3)
    sV = np.sqrt(np.clip(np.einsum("dij,djk,dik->di", Gv, cov, Gv), 0, None))
    return sW, sV


def _crossval(gf: np.ndarray, ok: np.ndarray, free: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Leave each pose out, refit on the rest, score the left-out pose's norm error
    ``|M (v_i - B)| - 1``: RMS per board (D,) and where it holds (D,)."""
    D, P, _ = gf.shape
    idx = np.array([np.delete(np.arange(P), i) for i in range(P)])  # (P, P-1)
    sub = gf[:, idx, :].reshape(D * P, P - 1, 3)
    ps, _, convs = _fit_core(sub, free)
    Ms, Bs = _unpack(ps)
    left = gf.reshape(D * P, 3)  # board d, left-out pose i sits at row d * P + i
    a = np.einsum("dij,dj->di", Ms, left - Bs)
    e = (np.linalg.norm(a, axis=-1) - 1.0).reshape(D, P)
    cv = np.sqrt(np.mean(e**2, axis=1))
    cv_ok = ok & convs.reshape(D, P).all(axis=1) & np.all(np.isfinite(e), axis=1)
    return np.where(cv_ok, cv, np.nan), cv_ok


def fit_norm_batch(gf: np.ndarray, noise_g: ArrayLike | None = None, crossval: bool = True,
                   free: np.ndarray | None = None) -> BatchFit:
    """Fit model 9 to a stack of boards' static readings gf (D, P, 3) in (nominal) g.

    ``free`` (9,) bool: fit only these parameters, hold the others at nominal (models/held.py);
    the condition number is then that of the free columns and the held ones have zero variance."""
    D, P, _ = gf.shape
    if P < 9:
        from ..errors import UnderdeterminedError
        raise UnderdeterminedError(f"model 9 needs at least 9 poses (it has 9 parameters); got {P}")
    p, nfev, conv = _fit_core(gf, free)
    M, B = _unpack(p)
    r, J = _held_jacobian(p, gf, free)
    s = np.linalg.svd(J if free is None else J[..., free], compute_uv=False)
    cond = s[:, 0] / np.maximum(s[:, -1], 1e-300)
    ok, messages = _refusals(gf, cond, conv)
    W = M  # AN4399 form: W = M, V = -M B, Gamma = 0
    V = -np.einsum("dij,dj->di", M, B)
    cal = np.einsum("dij,dpj->dpi", W, gf) + V[:, None, :]
    nrm = np.linalg.norm(cal, axis=-1)
    resid = cal / np.maximum(nrm, 1e-300)[..., None] - cal  # unit-sphere point minus calibrated
    cov, se_ok = _covariance(J, r, noise_g, ok, 9 if free is None else int(free.sum()))
    sW, sV = _stderr_an4399(M, B, cov)
    cv = np.full(D, np.nan)
    cv_ok = np.zeros(D, dtype=bool)
    if crossval and P >= 10:
        cv, cv_ok = _crossval(gf, ok, free)
    return BatchFit(
        model="9", W=W, V=V, Gamma=np.zeros((D, 3)), residuals_g=resid, norm_error_g=nrm - 1.0,
        P=np.sum(resid**2, axis=1), residual_rms_g=np.sqrt(np.mean(r**2, axis=1)),
        crossval_rms_g=cv, crossval_ok=cv_ok, condition_number=cond,
        stderr_W=sW, stderr_V=sV, stderr_Gamma=np.zeros((D, 3)), stderr_ok=se_ok,
        covariance=cov, params=p, param_names=list(PARAM_NAMES), ok=ok, messages=messages,
        readings_g=gf, nfev=nfev, status=["converged" if c else "max_iter" for c in conv],
    )

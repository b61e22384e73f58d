"""Model 9 (the gravity-norm model of gravity_norm.py) for a stack of boards, boards last.

Every array is laid out with the board axis last: readings g (3, P, N), parameters p (9, N),
residuals (P, N), the Jacobian J (9, P, N) and normal matrices (9, 9, N).  Each numpy call
then works on rows of N boards (a (N, P) layout runs its inner loops over a dozen poses),
and the 9 x 9 algebra is boardwise.py's elementwise routines, not one LAPACK call per board.

1. Start from the algebraic ellipsoid fit (_ellipsoid_start): two Gauss-Newton steps then
   settle a board where a sphere start needed three; boards it does not suit (degenerate
   poses) start from the sphere fit.
2. Plain Gauss-Newton (_gauss_newton), the step by a boardwise Cholesky solve, stopping each
   board once the error left, estimated from the contraction of its steps, is below 1e-10
   relative (boards still moving are evaluated alone).
3. The damped (Levenberg-Marquardt) fit of gravity_norm.py only for the boards Gauss-Newton
   does not settle.
4. _finish9: the condition number from the extreme eigenvalues of J^T J (LAPACK only for
   boards boardwise cannot certify), the covariance (J^T J)^-1 s^2 from the Cholesky factor
   Gauss-Newton already has, standard errors of W and V, and leave-one-out by one
   Gauss-Newton step from the full fit, refitted to convergence where that step is too
   large to trust (_loo9).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UnderdeterminedError
from . import boardwise as bw
from . import gravity_norm as gn
from .result import BatchFit, LazyCovariance


class ScaledCovariance(LazyCovariance):
    """(D, 9, 9) covariance (J^T J)^-1 s2 of model 9, formed per board on indexing."""

    _fields = ("Ainv", "s2")

    def __init__(self, Ainv: np.ndarray, s2: np.ndarray):
        self.Ainv, self.s2 = Ainv, s2

    def __getitem__(self, d: Any) -> np.ndarray:
        return self.Ainv[d] * np.asarray(self.s2[d])[..., None, None]


def _median_rows(x: np.ndarray) -> np.ndarray:
    """np.median(x, axis=1) by one partition (np.median's general path costs more here)."""
    P = x.shape[1]
    if P % 2:
        return np.partition(x, P // 2, axis=1)[:, P // 2]
    part = np.partition(x, (P // 2 - 1, P // 2), axis=1)
    return 0.5 * (part[:, P // 2 - 1] + part[:, P // 2])


def _sphere_start(gf: np.ndarray) -> np.ndarray:
    """gravity_norm._sphere_start (D, 9) in closed form: |v|^2 = 2 v.c + k by the centred 3x3
    solve, for readings gf (D, P, 3)."""
    D, P, _ = gf.shape
    g = gf.transpose(2, 0, 1)
    b = np.einsum("idp,idp->dp", g, g)
    xbar = g.mean(axis=2)
    xc, bc = g - xbar[..., None], b - b.mean(axis=1)[:, None]
    S = tuple(np.einsum("dp,dp->d", xc[i], xc[j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    (i00, i01, i02, i11, i12, i22), det = bw.inv3_sym(*S)
    q = np.einsum("idp,dp->id", xc, bc)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = 0.5 * np.array([i00 * q[0] + i01 * q[1] + i02 * q[2], i01 * q[0] + i11 * q[1] + i12 * q[2],
                            i02 * q[0] + i12 * q[1] + i22 * q[2]]).T / det[:, None]
    bad = ~np.all(np.isfinite(c), axis=1)
    if bad.any():  # degenerate poses: the reference start (regularised solve, mid-range fallback)
        c[bad] = gn._sphere_start(gf[bad])[:, 6:]
    u = gf - c[:, None]
    r = _median_rows(np.sqrt(np.einsum("dpi,dpi->dp", u, u)))
    r = np.where(r > 0, r, 1.0)
    p0 = np.zeros((D, 9))
    p0[:, :3] = 1.0 / r[:, None]
    p0[:, 6:] = c
    return p0


def _ellipsoid_start(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starting parameters (9, N) from the algebraic ellipsoid fit v^T Q' v + l.v = 1 (linear
    least squares in the 9 coefficients, by a boardwise Cholesky), and which boards it suits.

    With c = -Q'^-1 l / 2 the ellipsoid is (v - c)^T Q (v - c) = 1, Q = Q' / (1 + c^T Q' c), so
    M = Q^(1/2) (the symmetric root, by 3 Newton steps X <- (X + X^-1 Q) / 2 from I, which stay
    polynomials in Q and so commute with it) and B = c.  The algebraic residual is nearly twice
    the geometric one for a nearly spherical ellipsoid, so the start is within noise x
    asphericity of the optimum and Gauss-Newton needs about one step fewer than from a sphere.
    Boards whose fit is not a real ellipsoid around its centre (degenerate poses) are flagged
    False and should start from _sphere_start instead."""
    x, y, z = g  # (P, N) each
    Phi = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z])  # (9, P, N)
    ch = bw.cholesky(np.einsum("apn,bpn->abn", Phi, Phi))
    th = bw.solve(ch, Phi.sum(axis=1))  # Phi^T Phi th = Phi^T 1
    Qp = tuple(th[k] for k in (0, 3, 4, 1, 5, 2))  # 00 01 02 11 12 22
    (i00, i01, i02, i11, i12, i22), det = bw.inv3_sym(*Qp)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        l0, l1, l2 = th[6], th[7], th[8]
        c = -0.5 * np.stack([i00 * l0 + i01 * l1 + i02 * l2, i01 * l0 + i11 * l1 + i12 * l2,
                             i02 * l0 + i12 * l1 + i22 * l2]) / det
        k = 1.0 - 0.5 * (c[0] * l0 + c[1] * l1 + c[2] * l2)  # 1 + c^T Q' c, as Q' c = -l / 2
        Q = tuple(q / k for q in Qp)
        X = tuple(0.5 * (q + e) for q, e in zip(Q, (1.0, 0.0, 0.0, 1.0, 0.0, 1.0), strict=True))  # first step from I
        for _ in range(2):
            Xi, dx = bw.inv3_sym(*X)
            X = tuple(0.5 * (a + b / dx) for a, b in zip(X, bw.mul3_sym(Xi, Q), strict=True))
    p = np.stack([X[0], X[3], X[5], X[1], X[2], X[4], c[0], c[1], c[2]])
    ok = ch.ok & (det > 0) & (k > 0) & (Q[0] > 0) & (Q[3] > 0) & (Q[5] > 0) & np.all(np.isfinite(p), axis=0)
    return p, ok


_M_AT = ((0, 3, 4), (3, 1, 5), (4, 5, 2))  # the parameter of M[a][b] (M_xx M_yy M_zz M_xy M_xz M_yz)


def _times_m(p: np.ndarray, u: list[np.ndarray]) -> list[np.ndarray]:
    """M u per axis for the symmetric M of parameters p (9, N) (or (9, P, N))."""
    return [p[0] * u[0] + p[3] * u[1] + p[4] * u[2], p[3] * u[0] + p[1] * u[1] + p[5] * u[2],
            p[4] * u[0] + p[5] * u[1] + p[2] * u[2]]


def _calibrated(p: np.ndarray, g: np.ndarray) -> list[np.ndarray]:
    """a = M (v - B) per axis, each (P, N), for parameters p (9, N) (or (9, P, N)) and g (3, P, N)."""
    return _times_m(p, [g[i] - p[6 + i] for i in range(3)])


def _norm(a: list[np.ndarray]) -> np.ndarray:
    return np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _resid_jac(p: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r (P, N) and J (9, P, N) of r_i = |M (v_i - B)| - 1 (gravity_norm._residual_jacobian)."""
    u = [g[i] - p[6 + i] for i in range(3)]
    a = _times_m(p, u)
    n = _norm(a)
    inv = 1.0 / np.maximum(n, 1e-300)
    ah = [ai * inv for ai in a]
    J = np.empty((9,) + n.shape)
    np.multiply(ah[0], u[0], out=J[0])
    np.multiply(ah[1], u[1], out=J[1])
    np.multiply(ah[2], u[2], out=J[2])
    J[3] = ah[0] * u[1] + ah[1] * u[0]
    J[4] = ah[0] * u[2] + ah[2] * u[0]
    J[5] = ah[1] * u[2] + ah[2] * u[1]
    for j in range(3):
        J[6 + j] = -(ah[0] * p[_M_AT[0][j]] + ah[1] * p[_M_AT[1][j]] + ah[2] * p[_M_AT[2][j]])
    return n - 1.0, J


def _normal(J: np.ndarray) -> np.ndarray:
    """J^T J (9, 9, N) of a (9, P, N) Jacobian."""
    return np.einsum("apn,bpn->abn", J, J)


_DIAG = np.arange(9)


def _held(J: np.ndarray, fm: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """J with the held parameters' columns zeroed and A = J^T J with the held diagonal set to
    the mean free diagonal (``fm`` (9, N): 1 free, 0 held at nominal, models/held.py).

    A is then block diagonal: the free block is the constrained problem's J_f^T J_f, and the
    held block c I gives a zero step (its gradient is zero) and leaves the extreme eigenvalues
    those of the free block (each free diagonal entry lies between them, so their mean does):
    one 9 x 9 boardwise algebra serves held and free fits alike.  None: every parameter free."""
    if fm is None:
        return J, _normal(J)
    J = J * fm[:, None, :]
    A = _normal(J)
    fill = np.einsum("kkn->kn", A).sum(axis=0) / np.maximum(fm.sum(axis=0), 1.0)
    A[_DIAG, _DIAG] += (1.0 - fm) * fill
    return J, A


@dataclass
class _Linearised:
    """Each board's last Gauss-Newton evaluation: J (9, P, N), A = J^T J (9, 9, N) and its
    Cholesky factor (``chol.ok`` False where A is not positive definite)."""

    J: np.ndarray
    A: np.ndarray
    chol: bw.Cholesky

    def put(self, rows: np.ndarray, J: np.ndarray, A: np.ndarray, chol: bw.Cholesky) -> None:
        self.J[:, :, rows], self.A[:, :, rows] = J, A
        self.chol.L[:, :, rows], self.chol.inv_diag[:, rows], self.chol.ok[rows] = chol.L, chol.inv_diag, chol.ok


def _gauss_newton(g: np.ndarray, p: np.ndarray, iters: int, tol: float = 1e-10, fm: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, _Linearised]:
    """Plain batched Gauss-Newton (no line search: the caller sends the boards that do not
    settle to the damped fit) on readings g (3, P, N) from p (9, N).

    A board is settled once the error left after its last step, estimated from the
    contraction of its steps (q = |s_k| / |s_k-1| < 1/2: left <= |s_k| q / (1 - q)), is below
    ``tol`` relative to its parameters, or once a step itself is; it is then no longer
    evaluated.  The linearisation returned is each board's last evaluation, before its last
    step (a 1e-7 relative change of J at most on optimal-12 lots).  ``fm`` (9, N): the free
    parameters (_held); held ones never move from p.
    Returns (params (9, N), settled (N,), _Linearised)."""
    p = p.copy()
    N = p.shape[1]
    settled = np.zeros(N, dtype=bool)
    prev = np.full(N, np.nan)  # no contraction estimate before the second step
    act = np.arange(N)
    lin: _Linearised | None = None
    for _ in range(iters):
        whole = act.size == N
        ra, Ja = _resid_jac(p if whole else p[:, act], g if whole else g[:, :, act])
        Ja, Aa = _held(Ja, None if fm is None else (fm if whole else fm[:, act]))
        chol = bw.cholesky(Aa)
        step = bw.solve(chol, -np.einsum("kpn,pn->kn", Ja, ra))
        pd = chol.ok & np.all(np.isfinite(step), axis=0)
        step = np.where(pd, step, 0.0)
        size = np.sqrt(np.einsum("kn,kn->n", step, step))
        with np.errstate(divide="ignore", invalid="ignore"):
            q = size / prev[act]
            left = np.where(q < 0.5, size * q / (1.0 - q), np.inf)
        pa = p if whole else p[:, act]
        limit = tol * (1 + np.sqrt(np.einsum("kn,kn->n", pa, pa)))
        small = pd & ((left <= limit) | (size <= limit))
        if whole:
            p += step
        else:
            p[:, act] += step
        if whole or lin is None:  # the first iteration evaluates every board
            lin = _Linearised(Ja, Aa, chol)
        else:
            lin.put(act, Ja, Aa, chol)
        settled[act], prev[act] = small, size
        act = act[~(small | ~pd)]
        if not act.size:
            break
    if lin is None:
        raise ValueError(f"Gauss-Newton needs at least one iteration; got {iters}")
    settled &= np.all(np.isfinite(p), axis=0)
    return p, settled, lin


def fit9(gf: ArrayLike, noise_g: ArrayLike | None = None, gn_iters: int = 8,
         free: ArrayLike | None = None) -> BatchFit:
    """Model 9 for a stack of boards (D, P, 3) in nominal g; same results as
    gravity_norm.fit_norm_batch (leave-one-out to the tolerance stated in _loo9).

    ``free`` (D, 9) or (9,) bool: fit only these parameters and hold the others at nominal
    (0: the held non-orthogonalities of models/held.py), with zero variance; None: all free."""
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    if P < 9:
        raise UnderdeterminedError(f"model 9 needs at least 9 poses (it has 9 parameters); got {P}")
    fm = None if free is None else np.ascontiguousarray(np.broadcast_to(np.asarray(free, bool), (D, 9)).T, float)
    if fm is not None and fm.all():
        fm = None
    g = np.ascontiguousarray(gf.transpose(2, 1, 0))  # (3, P, D)
    p0, ell = _ellipsoid_start(g)
    if not ell.all():
        p0[:, ~ell] = _sphere_start(gf[~ell]).T
    if fm is not None:
        p0 *= fm  # held terms at nominal (0); only non-orthogonalities are ever held
    p, conv, lin = _gauss_newton(g, p0, gn_iters, fm=fm)
    lm = np.flatnonzero(~conv)
    if lm.size:  # the damped fit only where Gauss-Newton did not settle, from the sphere start (M diagonal)
        p_lm, _, conv[lm] = gn.levenberg_marquardt(gf[lm], _sphere_start(gf[lm]),
                                                   free=None if fm is None else fm[:, lm].T > 0)
        p[:, lm] = p_lm.T
    flip = np.flatnonzero(p[0] + p[1] + p[2] < 0)
    if flip.size:  # |M u| = |-M u|: keep the positive-definite branch, as gravity_norm does
        _flip_branch(p, lin, flip)
    if lm.size:
        _, J_lm = _resid_jac(p[:, lm], g[:, :, lm])
        J_lm, A_lm = _held(J_lm, None if fm is None else fm[:, lm])
        lin.put(lm, J_lm, A_lm, bw.cholesky(A_lm))
    return _finish9(gf, g, p, conv, noise_g, lin, fm)


def _flip_branch(p: np.ndarray, lin: _Linearised, rows: np.ndarray) -> None:
    """M -> -M for boards ``rows``: r is even in M and the M columns of J change sign, so with
    S = diag(-1 (M), +1 (B)): J^T J -> S J^T J S, and its Cholesky factor L -> S L S."""
    p[:6, rows] *= -1
    lin.J[:6, :, rows] *= -1
    lin.A[:6, 6:, rows] *= -1
    lin.A[6:, :6, rows] *= -1
    lin.chol.L[6:, :6, rows] *= -1


def _condition(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sqrt(lambda_max / lambda_min) of each J^T J (9, 9, N) (the condition number of J), and
    lambda_min; LAPACK recomputes the boards boardwise.extreme_eigenvalues cannot certify."""
    lo, hi, sure = bw.extreme_eigenvalues(A)
    if not sure.all():
        finite = np.all(np.isfinite(A), axis=(0, 1))
        redo = np.flatnonzero(~sure & finite)
        if redo.size:
            ev = np.linalg.eigvalsh(A[:, :, redo].transpose(2, 0, 1))
            lo[redo], hi[redo] = ev[:, 0], ev[:, -1]
        lo[~finite] = hi[~finite] = np.nan
    cond = np.sqrt(np.maximum(hi, 0) / np.maximum(lo, 1e-300))
    return cond, lo


def _judge(gf: np.ndarray, cond: np.ndarray, conv: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Which boards are fitted, and why the others are not (gravity_norm.fit_norm_batch's words)."""
    D, P, _ = gf.shape
    ok = np.ones(D, dtype=bool)
    messages = [""] * D
    bad = np.flatnonzero(cond > gn.COND_LIMIT)
    ok[bad] = False
    for d in bad:
        centred = gf[d] - gf[d].mean(axis=0)
        sv = np.linalg.svd(centred, compute_uv=False)
        messages[d] = ((f"the {P} poses lie in a plane: model 9 needs orientations spread over the sphere "
                        "(e.g. six faces plus three tilts)") if sv[-1] < 1e-3 * sv[0]
                       else f"the {P} poses do not determine model 9 (condition number {cond[d]:.3g})")
    for d in np.flatnonzero(ok & ~conv):
        ok[d] = False
        messages[d] = "model 9 did not converge (Levenberg-Marquardt stopped at its iteration limit)"
    return ok, messages


def _finish9(gf: np.ndarray, g: np.ndarray, p: np.ndarray, conv: np.ndarray, noise_g: ArrayLike | None,
             lin: _Linearised, fm: np.ndarray | None = None) -> BatchFit:
    """Everything gravity_norm.fit_norm_batch reports, from the fitted parameters p (9, N)
    and each board's last linearisation; held parameters (``fm`` 0) get zero variance and
    the residual variance is RSS / (P - free parameters)."""
    D, P, _ = gf.shape
    cond, lam_min = _condition(lin.A)
    ok, messages = _judge(gf, cond, conv)
    a = _calibrated(p, g)  # the calibrated output W v + V = M (v - B), (P, N) per axis
    nrm = _norm(a)
    r = nrm - 1.0
    cal = np.stack(a)
    resid = cal / np.maximum(nrm, 1e-300) - cal  # (3, P, N): unit-sphere point minus calibrated
    s2 = np.full(D, np.nan)
    if noise_g is not None:
        s2 = np.mean(np.asarray(noise_g) ** 2, axis=(1, 2))
    else:
        k = np.full(D, 9.0) if fm is None else fm.sum(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            s2 = np.where(k < P, np.einsum("pn,pn->n", r, r) / (P - k), np.nan)
    good = ok & (lam_min > 0) & lin.chol.ok
    Ainv = np.where(good, bw.inverse(lin.chol), 0.0)  # (9, 9, N)
    if fm is not None:  # the held block of the inverse is 1 / fill (_held): held terms have no variance
        Ainv *= fm[:, None, :] * fm[None, :, :]
    s2z = np.where(np.isfinite(s2), s2, 0.0)
    sW, sV = _propagate9(Ainv, s2z, p)
    cv, cv_ok = np.full(D, np.nan), np.zeros(D, dtype=bool)
    if P >= 10:
        e = _loo9(g, p, r, lin.J, Ainv, fm)
        cv_ok = ok & np.all(np.isfinite(Ainv), axis=(0, 1)) & np.all(np.isfinite(e), axis=0)
        cv = np.where(cv_ok, np.sqrt(np.mean(e**2, axis=0)), np.nan)
    params = p.T
    M, B = gn._unpack(params)
    return BatchFit(
        model="9", W=M, V=-np.einsum("dij,dj->di", M, B), Gamma=np.zeros((D, 3)),
        residuals_g=resid.transpose(2, 1, 0), norm_error_g=r.T, P=np.einsum("ipn,ipn->ni", resid, resid),
        residual_rms_g=np.sqrt(np.mean(r**2, axis=0)), crossval_rms_g=cv, crossval_ok=cv_ok,
        condition_number=cond, stderr_W=sW, stderr_V=sV, stderr_Gamma=np.zeros((D, 3)),
        stderr_ok=np.isfinite(s2) & ok, covariance=ScaledCovariance(Ainv.transpose(2, 0, 1), s2z),
        params=params, param_names=list(gn.PARAM_NAMES), ok=ok, messages=messages, readings_g=gf,
        status=["converged" if c else "max_iter" for c in conv])


LOO_REFIT = 0.1  # a held-out fit is refitted when its one-step change |dp|^2 exceeds this x the residual RMS


def _loo9(g: np.ndarray, p: np.ndarray, r: np.ndarray, J: np.ndarray, Ainv: np.ndarray,
          fm: np.ndarray | None = None) -> np.ndarray:
    """Held-out residuals (P, N) of model 9: pose i's residual under the fit without pose i.

    First one Gauss-Newton step from the full fit p (J (9, P, N) at p), in closed form for
    every (board, pose): the normal matrix without pose i is A - j_i j_i^T, whose inverse is
    A^-1 + u_i u_i^T / (1 - h_i) with u_i = A^-1 j_i, h_i = j_i^T u_i (Sherman-Morrison),
    so the step is -(A^-1 g) - u_i (u_i.g - r_i) / (1 - h_i) with g = J^T r the full gradient
    (~0 at the optimum).  Its error is second order in the step dp, so where |dp|^2 exceeds
    LOO_REFIT times the board's residual RMS (high-leverage poses: designs with few poses
    beyond 9, or much noise) the held-out fit is refitted to convergence from there
    (_refit_held_out).  Against today's exact refits: within 1e-5 g and 0.5 % of the
    cross-validated RMS at 1 mg noise (tests/test_lot.py).  Held parameters (``fm`` 0) have zero
    columns in J and zero rows in Ainv, so no held-out fit moves them."""
    U = np.einsum("kln,lpn->kpn", Ainv, J)  # u_i (9, P, N)
    h = np.einsum("kpn,kpn->pn", U, J)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv1h = np.where(h < 1.0 - 1e-9, 1.0 / (1.0 - h), np.nan)
    grad = np.einsum("kpn,pn->kn", J, r)  # J^T r (~0 at the optimum)
    c = (np.einsum("kpn,kn->pn", U, grad) - r) * inv1h
    step = U * c
    ps = (p - np.einsum("kln,ln->kn", Ainv, grad))[:, None, :] - step  # stepped parameters (9, P, N)
    rms = np.sqrt(np.mean(r * r, axis=0))
    pose, board = np.nonzero(np.einsum("kpn,kpn->pn", step, step) > LOO_REFIT * rms)
    if pose.size:
        ps[:, pose, board] = _refit_held_out(g, ps[:, pose, board], pose, board,
                                             None if fm is None else fm[:, board])
    return _norm(_calibrated(ps, g)) - 1.0


def _refit_held_out(g: np.ndarray, ps: np.ndarray, pose: np.ndarray, board: np.ndarray,
                    fm: np.ndarray | None = None) -> np.ndarray:
    """Parameters (9, K) of K held-out fits (board ``board[k]`` without pose ``pose[k]``), by
    Gauss-Newton from ps (9, K), and the damped fit for those it does not settle (as today's
    fitter refits every held-out pose); NaN where neither converges."""
    P = g.shape[1]
    keep = np.array([np.delete(np.arange(P), i) for i in range(P)])[pose]  # (K, P - 1)
    sub = np.ascontiguousarray(g[:, keep.T, board[None, :]])  # (3, P - 1, K)
    out, settled, _ = _gauss_newton(sub, ps, 8, fm=fm)
    lm = np.flatnonzero(~settled)
    if lm.size:
        p_lm, _, conv = gn.levenberg_marquardt(sub[:, :, lm].transpose(2, 1, 0), ps[:, lm].T,
                                               free=None if fm is None else fm[:, lm].T > 0)
        out[:, lm] = np.where(conv, p_lm.T, np.nan)
    return out


_W_OF_P = [0, 3, 4, 3, 1, 5, 4, 5, 2]  # the parameter of W[a, b] (row-major): M_xx M_xy M_xz ...


def _propagate9(Ainv: np.ndarray, s2: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard errors (first order) of W = M (D, 3, 3) and V = -M B (D, 3) from the
    covariance Ainv s2 of the parameters (Ainv (9, 9, N), p (9, N))."""
    N = p.shape[1]
    Gv = np.zeros((3, 9, N))  # dV / dp
    for j, (a, b) in enumerate(zip(*gn._IU, strict=True)):
        Gv[a, j] -= p[6 + b]
        if a != b:
            Gv[b, j] -= p[6 + a]
    for a in range(3):
        for b in range(3):
            Gv[a, 6 + b] = -p[_M_AT[a][b]]
    var_p = np.einsum("kkn->kn", Ainv)[_W_OF_P] * s2
    sW = np.sqrt(np.clip(var_p, 0, None)).T.reshape(N, 3, 3)
    var_v = np.einsum("akn,akn->an", np.einsum("akn,kln->aln", Gv, Ainv), Gv) * s2
    return sW, np.sqrt(np.clip(var_v, 0, None)).T

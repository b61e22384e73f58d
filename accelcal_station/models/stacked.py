"""Fast stacked fitters for a chunk of boards: the same estimators as linear.py and
gravity_norm.py, written as elementwise numpy over the board axis.

Model 12 (AN4399 Eqn 46) is solved on the centred design: with xc = g - mean(g),
S = xc^T xc (3 x 3), W^T = S^-1 xc^T (ref - mean(ref)) and V = mean(ref) - W mean(g),
which is the normal-equation solution of ``[g 1] beta = ref`` (the intercept column
drops out by the Frisch-Waugh theorem).  S^-1 comes from the adjugate, so no
per-board LAPACK call is made; (X^T X)^-1 of the full design follows by the block
(Schur complement) formula, giving standard errors, and the hat matrix diagonal
h = 1/P + xc^T S^-1 xc gives closed-form leave-one-out residuals r / (1 - h).
The condition number sqrt(lambda_max / lambda_min) of X^T X uses the extreme roots of
its characteristic polynomial (coefficients from principal minors, all computed
through S so they carry no cancellation), found by Laguerre's method, which
converges monotonically from outside the roots of a polynomial with real roots.

The design [g 1] is each board's own readings, so it cannot be factored once per lot;
what boards share is the reference set (the fixture's poses): fit_stacked groups boards
by identical references, and within a group the centred references, their norms and the
cross products xc^T yc (one BLAS matmul over the group) are computed once.

Arrays are laid out (3, P, D), boards last, so sums over poses are additions of P
contiguous rows; the covariance is kept as the 10 distinct entries of (X^T X)^-1 per board.

Models 6 and 15 use linear.fit_linear_batch (already batched normal equations).
Model 9 uses batched Gauss-Newton from the algebraic ellipsoid fit (_ellipsoid_start: two
steps settle a board where a sphere start needed three; the 9 x 9 normal matrices by one batched matmul, solved by LAPACK's batched Cholesky and elementwise
triangular solves), stopping each board once the error left, estimated from the
contraction of its steps, is below 1e-10 relative (boards still moving are evaluated
alone), with the damped (Levenberg-Marquardt) fit of gravity_norm.py only for the boards
Gauss-Newton does not settle.  Leave-one-out is one Gauss-Newton step from the full fit
per (board, held-out pose), in closed form by Sherman-Morrison on the full normal matrix
inverse (also the covariance): the one-step (leverage) approximation, whose tolerance
against exact refits _loo9 states and tests/test_lot.py checks.

fit_stacked fits blocks of boards (BLOCK) in one thread per CPU and copies each into the
lot's arrays as soon as it is done.
"""
from __future__ import annotations

import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import UnderdeterminedError
from . import gravity_norm as gn
from .linear import COND_LIMIT, diagnose_underdetermined, fit_linear_batch, param_names, residual_variance
from .result import BatchFit

CHECK_COND = 1e5  # above this, extreme eigenvalues are recomputed by LAPACK (rare)


def _sym_inv3(a, b, c, d, e, f):
    """Inverse of symmetric [[a b c] [b d e] [c e f]] by the adjugate: 6 entries and det."""
    A00, A01, A02 = d * f - e * e, c * e - b * f, b * e - c * d
    A11, A12, A22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A00 + b * A01 + c * A02
    return (A00, A01, A02, A11, A12, A22), det


def _laguerre_root(coef, x, iters: int = 3):
    """A root of the monic quartic x^4 - e1 x^3 + e2 x^2 - e3 x + e4 from x (vectorised).

    All roots real: started above (below) all roots, Laguerre's iteration goes
    monotonically to the largest (smallest).  Returns the root and the last step.
    """
    e1, e2, e3, e4 = coef
    step = np.zeros_like(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(iters):
            p = (((x - e1) * x + e2) * x - e3) * x + e4
            dp = ((4 * x - 3 * e1) * x + 2 * e2) * x - e3
            d2p = (12 * x - 6 * e1) * x + 2 * e2
            g1 = dp / p
            h = g1 * g1 - d2p / p
            sq = np.sqrt(np.maximum(3.0 * (4.0 * h - g1 * g1), 0.0))
            den = g1 + np.copysign(sq, g1)
            step = np.where((p == 0) | (den == 0), 0.0, 4.0 / den)
            x = x - step
    return x, step


def _smallest_root(coef, top):
    """The smallest root of the quartic once its largest ``top`` is known: deflate to a cubic,
    take its smallest root in trigonometric form (three real roots), polish by 2 Newton steps
    on the quartic (a cluster of small roots makes Laguerre from below slow)."""
    e1, e2, e3, e4 = coef
    a = top - e1  # x^3 + a x^2 + b x + c = quartic / (x - top)
    b = e2 + top * a
    c = -e3 + top * b
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    m = np.sqrt(np.maximum(-p / 3.0, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        arg = np.clip(np.where(m > 0, -q / (2.0 * m**3), 0.0), -1.0, 1.0)
    t = np.arccos(arg) / 3.0
    x = 2.0 * m * np.cos(t + 2.0 * np.pi / 3.0) - a / 3.0  # the smallest of the three
    step = np.zeros_like(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(2):
            f = (((x - e1) * x + e2) * x - e3) * x + e4
            df = ((4 * x - 3 * e1) * x + 2 * e2) * x - e3
            step = np.where(df != 0, f / df, 0.0)
            x = x - step
    return x, step


def _cond12(S, det, xbar, P, G_full):
    """Condition number of X = [g 1] (sqrt of eigenvalue ratio of X^T X), per board."""
    a, b, c, d, e, f = S
    x0, x1, x2 = xbar
    Pn = float(P)
    e1 = a + d + f + Pn * (x0 * x0 + x1 * x1 + x2 * x2) + Pn

    def m2(sii, sjj, sij, xi, xj):  # 2x2 principal minor of A = S + P xbar xbar^T
        return sii * sjj - sij * sij + Pn * (sii * xj * xj + sjj * xi * xi - 2 * sij * xi * xj)

    e2 = m2(a, d, b, x0, x1) + m2(a, f, c, x0, x2) + m2(d, f, e, x1, x2) + Pn * (a + d + f)
    (i00, i01, i02, i11, i12, i22), _ = _sym_inv3(a, b, c, d, e, f)
    q = (i00 * x0 * x0 + i11 * x1 * x1 + i22 * x2 * x2 + 2 * (i01 * x0 * x1 + i02 * x0 * x2 + i12 * x1 * x2))
    e3 = det + Pn * q + Pn * ((a * d - b * b) + (a * f - c * c) + (d * f - e * e))  # q already / det
    e4 = Pn * det
    coef = (e1, e2, e3, e4)
    hi, s_hi = _laguerre_root(coef, e1.copy())
    lo, s_lo = _smallest_root(coef, hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.sqrt(hi / np.maximum(lo, 1e-300))
    unsure = ~np.isfinite(cond) | (cond > CHECK_COND) | (np.abs(s_lo) > 1e-9 * np.abs(lo)) \
        | (np.abs(s_hi) > 1e-9 * np.abs(hi))
    if unsure.any():
        ev = np.linalg.eigvalsh(G_full(unsure))
        cond[unsure] = np.sqrt(ev[:, -1] / np.maximum(ev[:, 0], 1e-300))
    return cond


class _LazyCovariance:
    """A (D, ...) covariance stored as a few arrays and formed per board on indexing; the
    arrays are named in ``_fields`` (the lot assembler copies them)."""

    _fields: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(getattr(self, self._fields[0]))


class _ScaledCovariance(_LazyCovariance):
    """(D, 9, 9) covariance (J^T J)^-1 s2 of model 9, formed per board on indexing."""

    _fields = ("Ainv", "s2")

    def __init__(self, Ainv: np.ndarray, s2: np.ndarray):
        self.Ainv, self.s2 = Ainv, s2

    def __getitem__(self, d):
        return self.Ainv[d] * np.asarray(self.s2[d])[..., None, None]


class _ChannelCovariance(_LazyCovariance):
    """(D, 3, 4, 4) covariance (X^T X)^-1 s2_c of model 12, built per board on indexing from the
    10 distinct entries of the symmetric (X^T X)^-1 (saves D x 38 floats and their copies).

    ``G`` (D, 10): S^-1 upper triangle (00 01 02 11 12 22), u = -S^-1 xbar (3), 1/P + xbar^T S^-1 xbar;
    ``s2`` (D, 3): the residual variance per output channel."""

    _ROWS = np.array([[0, 1, 2, 6], [1, 3, 4, 7], [2, 4, 5, 8], [6, 7, 8, 9]])
    _fields = ("G", "s2")

    def __init__(self, G: np.ndarray, s2: np.ndarray):
        self.G, self.s2 = G, s2

    def __getitem__(self, d):
        Ginv = self.G[d][..., self._ROWS]  # (..., 4, 4)
        return Ginv[..., None, :, :] * self.s2[d][..., None, None]


def fit12(gf: np.ndarray, ref: np.ndarray, noise_g: np.ndarray | None = None) -> BatchFit:
    """Model 12 for a stack of boards (D, P, 3) in g; same results as fit_linear_batch.

    ``ref`` is (D, P, 3), or (P, 3) shared by every board: then its centred form, its norms
    and the cross products xc^T yc (one BLAS matmul) are computed once for the stack."""
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    if P < 4:
        raise UnderdeterminedError(f"model 12 needs at least 4 poses; got {P}")
    ref = np.asarray(ref, dtype=float)
    shared = ref.ndim == 2
    # (3, P, D): boards last, so sums over poses add P contiguous rows (short-row reductions are slow)
    g = np.ascontiguousarray(gf.transpose(2, 1, 0))
    y = ref.T[:, :, None] if shared else np.ascontiguousarray(ref.transpose(2, 1, 0))  # (3, P, 1 or D)
    xbar, ybar = g.sum(axis=1) / P, y.sum(axis=1) / P  # (3, D), (3, 1 or D)
    xc, yc = g - xbar[:, None, :], y - ybar[:, None, :]
    S = tuple((xc[i] * xc[j]).sum(axis=0) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    adj, det = _sym_inv3(*S)
    scale = np.maximum(S[0] + S[3] + S[5], 1e-300)
    ok = det > 1e-12 * scale**3  # a quick screen; the condition number decides below
    det_safe = np.where(ok, det, 1.0)
    i00, i01, i02, i11, i12, i22 = (np.where(ok, v, 0.0) / det_safe for v in adj)
    Si = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])  # (3, 3, D)
    if shared:  # (3, P) @ (3 in, P, D): BLAS
        C = yc[:, :, 0] @ xc  # (3 in, 3 out, D)
    else:
        C = np.einsum("ipd,cpd->icd", xc, yc)
    Wt = np.einsum("jid,icd->jcd", Si, C)  # W[c, j] = Wt[j, c]
    W = Wt.transpose(2, 1, 0)  # (D, 3, 3)
    V = ybar.T - np.einsum("dcj,dj->dc", W, xbar.T)
    r = np.empty_like(xc)  # (3, P, D) reference minus calibrated
    for c in range(3):
        r[c] = yc[c] - Wt[0, c] * xc[0] - Wt[1, c] * xc[1] - Wt[2, c] * xc[2]
    h = (i00 * xc[0] ** 2 + i11 * xc[1] ** 2 + i22 * xc[2] ** 2
         + 2 * (i01 * xc[0] * xc[1] + i02 * xc[0] * xc[2] + i12 * xc[1] * xc[2]))
    h += 1.0 / P  # hat diagonal (P, D)

    def G_full(mask):
        X = np.concatenate([gf[mask], np.ones((int(mask.sum()), P, 1))], axis=-1)
        return X.swapaxes(1, 2) @ X

    cond = _cond12(S, det_safe, xbar, P, G_full)
    ok &= np.isfinite(cond) & (cond <= COND_LIMIT)
    r2 = r * r
    rss = r2.sum(axis=1).T  # (D, 3)
    fit_h = h < 1.0 - 1e-9
    cv_ok = fit_h.all(axis=0) & ok
    w = 1.0 / np.where(fit_h, 1.0 - h, 1.0) ** 2  # leave-one-out residual r / (1 - h), squared
    cv_rms = np.where(cv_ok, np.sqrt(((r2[0] + r2[1] + r2[2]) * w).sum(axis=0) / (3 * P)), np.nan)
    s2 = residual_variance(noise_g, rss, D, P, P - 4)
    se_ok = np.all(np.isfinite(s2), axis=1) & ok
    s2z = np.where(np.isfinite(s2), s2, 0.0)
    # (X^T X)^-1 of X = [g 1] by the block formula: [[S^-1, -S^-1 xbar], [., 1/P + xbar^T S^-1 xbar]]
    u = -np.einsum("ijd,jd->id", Si, xbar)  # (3, D)
    G = np.stack([i00, i01, i02, i11, i12, i22, u[0], u[1], u[2], 1.0 / P - (u * xbar).sum(axis=0)], axis=1)
    sW = np.sqrt(np.clip(s2z[:, :, None] * G[:, None, [0, 3, 5]], 0.0, None))
    sV = np.sqrt(np.clip(s2z * G[:, 9:10], 0.0, None))
    resid = r.transpose(2, 1, 0)  # (D, P, 3) view
    cal = y - r
    norm_err = (np.sqrt(cal[0] * cal[0] + cal[1] * cal[1] + cal[2] * cal[2]) - np.sqrt((y * y).sum(axis=0))).T
    messages = [""] * D
    for d in np.flatnonzero(~ok):
        messages[d] = diagnose_underdetermined(gf[d], "12")
    W = np.where(ok[:, None, None], W, 0.0)
    V = np.where(ok[:, None], V, 0.0)
    return BatchFit(
        model="12", W=W, V=V, Gamma=np.zeros((D, 3)), residuals_g=resid, norm_error_g=norm_err, P=rss,
        residual_rms_g=np.sqrt(rss.sum(axis=1) / (3 * P)), crossval_rms_g=cv_rms, crossval_ok=cv_ok,
        condition_number=cond, stderr_W=sW, stderr_V=sV, stderr_Gamma=np.zeros((D, 3)), stderr_ok=se_ok,
        covariance=_ChannelCovariance(G, s2z),
        params=np.concatenate([W.reshape(D, 9), V], axis=1), param_names=param_names("12"),
        ok=ok, messages=messages, readings_g=gf)


# -- model 9 -------------------------------------------------------------------------------------

def _median_rows(x: np.ndarray) -> np.ndarray:
    """np.median(x, axis=1) by one partition (np.median's general path costs more here)."""
    P = x.shape[1]
    if P % 2:
        return np.partition(x, P // 2, axis=1)[:, P // 2]
    part = np.partition(x, (P // 2 - 1, P // 2), axis=1)
    return 0.5 * (part[:, P // 2 - 1] + part[:, P // 2])


def _sphere_start(gf: np.ndarray) -> np.ndarray:
    """gravity_norm._sphere_start in closed form: |v|^2 = 2 v.c + k by the centred 3x3 solve."""
    D, P, _ = gf.shape
    g = gf.transpose(2, 0, 1)
    b = np.einsum("idp,idp->dp", g, g)
    xbar = g.mean(axis=2)
    xc, bc = g - xbar[..., None], b - b.mean(axis=1)[:, None]
    S = tuple(np.einsum("dp,dp->d", xc[i], xc[j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    (i00, i01, i02, i11, i12, i22), det = _sym_inv3(*S)
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


def _sym_mul(X, Y):
    """X Y for symmetric 3 x 3 matrices that commute (so the product is symmetric), each given
    as its 6 entries (00 01 02 11 12 22) of (N,) arrays."""
    x00, x01, x02, x11, x12, x22 = X
    y00, y01, y02, y11, y12, y22 = Y
    return (x00 * y00 + x01 * y01 + x02 * y02, x00 * y01 + x01 * y11 + x02 * y12,
            x00 * y02 + x01 * y12 + x02 * y22, x01 * y01 + x11 * y11 + x12 * y12,
            x01 * y02 + x11 * y12 + x12 * y22, x02 * y02 + x12 * y12 + x22 * y22)


def _ellipsoid_start(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starting parameters (N, 9) from the algebraic ellipsoid fit v^T Q' v + l.v = 1 (linear
    least squares in the 9 coefficients, one batched 9 x 9 Cholesky), and which boards it suits.

    With c = -Q'^-1 l / 2 the ellipsoid is (v - c)^T Q (v - c) = 1, Q = Q' / (1 + c^T Q' c), so
    M = Q^(1/2) (the symmetric root, by 3 Newton steps X <- (X + X^-1 Q) / 2 from I, which stay
    polynomials in Q and so commute with it) and B = c.  The algebraic residual is nearly twice
    the geometric one for a nearly spherical ellipsoid, so the start is within noise x
    asphericity of the optimum and Gauss-Newton needs about one step fewer than from a sphere.
    Boards whose fit is not a real ellipsoid around its centre (degenerate poses) are flagged
    False and start from _sphere_start instead."""
    x, y, z = g  # (N, P) each
    Phi = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z])  # (9, N, P)
    A, rhs = _normal(Phi, -np.ones_like(x))  # Phi^T Phi, Phi^T 1
    th, ok = _spd_solve(A, rhs)
    Qp = tuple(th[:, k] for k in (0, 3, 4, 1, 5, 2))  # 00 01 02 11 12 22
    (i00, i01, i02, i11, i12, i22), det = _sym_inv3(*Qp)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        l0, l1, l2 = th[:, 6], th[:, 7], th[:, 8]
        c = -0.5 * np.stack([i00 * l0 + i01 * l1 + i02 * l2, i01 * l0 + i11 * l1 + i12 * l2,
                             i02 * l0 + i12 * l1 + i22 * l2], axis=1) / det[:, None]
        k = 1.0 - 0.5 * (c[:, 0] * l0 + c[:, 1] * l1 + c[:, 2] * l2)  # 1 + c^T Q' c, as Q' c = -l / 2
        Q = tuple(q / k for q in Qp)
        X = tuple(0.5 * (q + e) for q, e in zip(Q, (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)))  # first step from I
        for _ in range(2):
            Xi, dx = _sym_inv3(*X)
            X = tuple(0.5 * (a + b / dx) for a, b in zip(X, _sym_mul(Xi, Q)))
    p = np.stack([X[0], X[3], X[5], X[1], X[2], X[4], c[:, 0], c[:, 1], c[:, 2]], axis=1)
    ok &= (det > 0) & (k > 0) & (Q[0] > 0) & (Q[3] > 0) & (Q[5] > 0) & np.all(np.isfinite(p), axis=1)
    return p, ok


def _resid_jac(p: np.ndarray, g: np.ndarray):
    """r (N, P) and J (9, N, P) of r_i = |M (v_i - B)| - 1 (gravity_norm._residual_jacobian),
    with g (3, N, P): each component a contiguous array."""
    m = [p[:, k, None] for k in range(9)]
    M = ((m[0], m[3], m[4]), (m[3], m[1], m[5]), (m[4], m[5], m[2]))
    u = [g[i] - m[6 + i] for i in range(3)]
    a = [M[i][0] * u[0] + M[i][1] * u[1] + M[i][2] * u[2] for i in range(3)]
    n = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    inv = 1.0 / np.maximum(n, 1e-300)
    ah = [ai * inv for ai in a]
    J = np.empty((9,) + n.shape)
    J[0], J[1], J[2] = ah[0] * u[0], ah[1] * u[1], ah[2] * u[2]
    J[3] = ah[0] * u[1] + ah[1] * u[0]
    J[4] = ah[0] * u[2] + ah[2] * u[0]
    J[5] = ah[1] * u[2] + ah[2] * u[1]
    for j in range(3):
        J[6 + j] = -(ah[0] * M[0][j] + ah[1] * M[1][j] + ah[2] * M[2][j])
    return n - 1.0, J


def _masked_grad(p: np.ndarray, g: np.ndarray, w: np.ndarray) -> np.ndarray:
    """J^T (w r) (N, 9) of r_i = |M (v_i - B)| - 1 without forming J (the sums of _resid_jac's
    columns weighted by w r, grouped as sum_q (a_k r / |a|) u_l and sum_q a_k r / |a|)."""
    m = [p[:, k, None] for k in range(9)]
    M = ((m[0], m[3], m[4]), (m[3], m[1], m[5]), (m[4], m[5], m[2]))
    u = [g[i] - m[6 + i] for i in range(3)]
    a = [M[i][0] * u[0] + M[i][1] * u[1] + M[i][2] * u[2] for i in range(3)]
    n = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    f = (n - 1.0) * w / np.maximum(n, 1e-300)
    c = [ai * f for ai in a]  # ah_k * r * w
    S = [[np.einsum("np,np->n", c[k], u[l]) for l in range(3)] for k in range(3)]
    s = [ck.sum(axis=1) for ck in c]
    out = np.empty((len(p), 9))
    out[:, 0], out[:, 1], out[:, 2] = S[0][0], S[1][1], S[2][2]
    out[:, 3], out[:, 4], out[:, 5] = S[0][1] + S[1][0], S[0][2] + S[2][0], S[1][2] + S[2][1]
    for j in range(3):
        out[:, 6 + j] = -(s[0] * M[0][j][:, 0] + s[1] * M[1][j][:, 0] + s[2] * M[2][j][:, 0])
    return out


def _chol_solve(A: list, b: list):
    """Solve A x = b for N symmetric 9 x 9 systems at once by Cholesky, elementwise over N.

    A[i][j] (i >= j) and b[i] are (N,) arrays.  Returns x (N, 9) and whether A was positive definite.
    """
    n = len(b)
    L = [[None] * n for _ in range(n)]
    ok = np.ones(b[0].shape, dtype=bool)
    for j in range(n):
        s = A[j][j] - sum((L[j][k] * L[j][k] for k in range(j)), np.zeros_like(b[0]))
        ok &= s > 1e-300
        L[j][j] = np.sqrt(np.where(s > 1e-300, s, 1.0))
        for i in range(j + 1, n):
            L[i][j] = (A[i][j] - sum((L[i][k] * L[j][k] for k in range(j)), np.zeros_like(b[0]))) / L[j][j]
    y = [None] * n
    for i in range(n):
        y[i] = (b[i] - sum((L[i][k] * y[k] for k in range(i)), np.zeros_like(b[0]))) / L[i][i]
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - sum((L[k][i] * x[k] for k in range(i + 1, n)), np.zeros_like(b[0]))) / L[i][i]
    return np.stack(x, axis=1), ok


def _normal(J: np.ndarray, r: np.ndarray):
    """J^T J (N, 9, 9) and -J^T r (N, 9) of a (9, N, P) Jacobian, by one batched matmul
    (45 einsum calls cost more in dispatch than in arithmetic)."""
    Jn = J.transpose(1, 0, 2)  # (N, 9, P)
    return Jn @ Jn.transpose(0, 2, 1), -np.einsum("knp,np->nk", J, r)


def _spd_solve(A: np.ndarray, b: np.ndarray):
    """x (N, 9) of A x = b for N symmetric positive definite A (N, 9, 9), and whether each A
    was positive definite: LAPACK's batched Cholesky, then the two triangular solves
    elementwise over N; a stack with a matrix that is not positive definite (rare: degenerate
    poses) goes to _chol_solve, which flags each board."""
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        At = A.transpose(1, 2, 0)
        return _chol_solve([[At[i, j] for j in range(i + 1)] for i in range(9)], list(b.T))
    Lt = np.ascontiguousarray(L.transpose(1, 2, 0))  # (9, 9, N)
    bt = b.T
    y = [None] * 9
    for i in range(9):
        acc = bt[i].copy()
        for k in range(i):
            acc -= Lt[i, k] * y[k]
        y[i] = acc / Lt[i, i]
    x = [None] * 9
    for i in reversed(range(9)):
        acc = y[i].copy()
        for k in range(i + 1, 9):
            acc -= Lt[k, i] * x[k]
        x[i] = acc / Lt[i, i]
    return np.stack(x, axis=1), np.ones(len(A), dtype=bool)


def _gauss_newton(g: np.ndarray, p: np.ndarray, iters: int, tol: float = 1e-10):
    """Plain batched Gauss-Newton (no line search: the caller sends the boards that do not
    settle to the damped fit) on readings g (3, N, P).

    A board is settled once the error left after its last step, estimated from the
    contraction of its steps (q = |s_k| / |s_k-1| < 1/2: left <= |s_k| q / (1 - q)), is below
    ``tol`` relative to its parameters (the issue's "within 1e-9"), or once a step itself is;
    it is then no longer evaluated (the few slow boards do not cost the block an iteration).
    The Jacobian J (9, N, P) and J^T J (N, 9, 9) returned are from each board's last
    evaluation, before its last step (1e-7 relative at most on optimal-12 lots, a 1e-7
    relative change of J); the residuals r are re-evaluated at the parameters returned.
    From the second evaluation on (when a board usually settles) the step is (J^T J)^-1 g by
    LAPACK's batched inverse, which _finish9 needs anyway for the covariance, instead of the
    Cholesky solve; a board whose step is not a descent direction (J^T J not positive
    definite) is treated as the Cholesky path treats it.
    Returns (params, settled, r, J, J^T J, (J^T J)^-1 (NaN where not computed)).
    """
    p = p.copy()
    N = len(p)
    settled = np.zeros(N, dtype=bool)
    prev = np.full(N, np.nan)  # no contraction estimate before the second step
    act = np.arange(N)
    J = A = None
    Ainv = np.full((N, 9, 9), np.nan)
    for it in range(iters):
        whole = act.size == N
        pa = p if whole else p[act]
        ra, Ja = _resid_jac(pa, g if whole else g[:, act])
        Aa, grad = _normal(Ja, ra)
        Ai = None
        if it > 0:
            try:
                Ai = np.linalg.inv(Aa)
            except np.linalg.LinAlgError:  # an exactly singular J^T J: the Cholesky path flags it
                Ai = None
        if Ai is None:
            step, pd = _spd_solve(Aa, grad)
        else:
            step = (Ai @ grad[..., None])[..., 0]
            pd = np.all(np.isfinite(step), axis=1) & (np.einsum("nk,nk->n", step, grad) > 0)
        size = np.linalg.norm(step, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = size / prev[act]
            left = np.where(q < 0.5, size * q / (1.0 - q), np.inf)
        limit = tol * (1 + np.linalg.norm(pa, axis=1))
        small = pd & ((left <= limit) | (size <= limit))
        if whole:
            p += np.where(pd[:, None], step, 0.0)
        else:
            p[act] += np.where(pd[:, None], step, 0.0)
        if whole:
            J, A = Ja, Aa
        else:
            J[:, act], A[act] = Ja, Aa
        if whole and Ai is not None:
            Ainv = Ai  # no copy of the block's inverses
        else:
            Ainv[act] = np.nan if Ai is None else Ai
        settled[act], prev[act] = small, size
        act = act[~(small | ~pd)]
        if not act.size:
            break
    r = _norm_resid(p[:, None, :], g.transpose(1, 2, 0))
    settled &= np.all(np.isfinite(p), axis=1) & np.isfinite(r).all(axis=1)
    return p, settled, r, J, A, Ainv


def fit9(gf: np.ndarray, noise_g: np.ndarray | None = None, gn_iters: int = 8, loo_iters: int = 1) -> BatchFit:
    """Model 9 for a stack of boards (D, P, 3) in nominal g; same results as fit_norm_batch
    (leave-one-out to the approximation stated in _loo9)."""
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    if P < 9:
        raise UnderdeterminedError(f"model 9 needs at least 9 poses (it has 9 parameters); got {P}")
    g = np.ascontiguousarray(gf.transpose(2, 0, 1))
    p0, ell = _ellipsoid_start(g)
    if not ell.all():
        p0[~ell] = _sphere_start(gf[~ell])
    p, settled, r, J, A, Ainv = _gauss_newton(g, p0, gn_iters)
    conv = settled.copy()
    lm = np.flatnonzero(~settled)
    if lm.size:  # the damped fit only where Gauss-Newton did not settle, from the sphere start
        p[lm], _, conv[lm] = gn.levenberg_marquardt(gf[lm], _sphere_start(gf[lm]))
    M, _ = gn._unpack(p)
    flip = np.trace(M, axis1=1, axis2=2) < 0
    p[flip, :6] *= -1
    # r is even in M; the M columns of J change sign, so J^T J changes sign off the M/B diagonal blocks
    J[:6, flip] *= -1
    for X in (A, Ainv):  # D X D with D = diag(-1 (M), +1 (B)): (D A D)^-1 = D A^-1 D
        X[np.ix_(flip, range(6), range(6, 9))] *= -1
        X[np.ix_(flip, range(6, 9), range(6))] *= -1
    if lm.size:
        r[lm], J[:, lm] = _resid_jac(p[lm], g[:, lm])
        A[lm] = _normal(J[:, lm], r[lm])[0]
        Ainv[lm] = np.nan
    return _finish9(gf, p, conv, noise_g, loo_iters, r, J, A, Ainv)


def _finish9(gf, p, conv, noise_g, loo_iters, r, J, JtJ, Ainv=None) -> BatchFit:
    """Everything gravity_norm.fit_norm_batch reports, from fitted parameters p and the
    residuals r (D, P), Jacobian J (9, D, P) and J^T J (D, 9, 9) at p, and (J^T J)^-1 where
    already computed (rows with NaN, or ``Ainv`` None, are inverted here)."""
    D, P, _ = gf.shape
    M, B = gn._unpack(p)
    ev = np.linalg.eigvalsh(JtJ)
    cond = np.sqrt(np.maximum(ev[:, -1], 0) / np.maximum(ev[:, 0], 1e-300))
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
    W, V = M, -np.einsum("dij,dj->di", M, B)
    cal = gf @ W.transpose(0, 2, 1) + V[:, None, :]
    nrm = np.sqrt(np.einsum("dpi,dpi->dp", cal, cal))
    resid = cal / np.maximum(nrm, 1e-300)[..., None] - cal
    s2 = np.full(D, np.nan)
    if noise_g is not None:
        s2 = np.mean(np.asarray(noise_g) ** 2, axis=(1, 2))
    elif P > 9:
        s2 = np.einsum("dp,dp->d", r, r) / (P - 9)
    good = ok & (ev[:, 0] > 0)
    Ainv = np.full((D, 9, 9), np.nan) if Ainv is None else Ainv
    need = good & np.isnan(Ainv[:, 0, 0])
    if need.any():
        Ainv[need] = np.linalg.inv(JtJ[need])
    if not good.all():
        Ainv[~good] = 0.0
    s2z = np.where(np.isfinite(s2), s2, 0.0)
    sW, sV = _propagate9(Ainv, s2z, M, B)
    cv, cv_ok = np.full(D, np.nan), np.zeros(D, dtype=bool)
    if P >= 10:
        cv_ok = ok & np.all(np.isfinite(Ainv), axis=(1, 2))
        e = _loo9(gf, p, r, J, Ainv, loo_iters)
        cv_ok &= np.all(np.isfinite(e), axis=1)
        cv = np.where(cv_ok, np.sqrt(np.mean(e**2, axis=1)), np.nan)
    return BatchFit(
        model="9", W=W, V=V, Gamma=np.zeros((D, 3)), residuals_g=resid, norm_error_g=nrm - 1.0,
        P=np.sum(resid**2, axis=1), residual_rms_g=np.sqrt(np.mean(r**2, axis=1)),
        crossval_rms_g=cv, crossval_ok=cv_ok, condition_number=cond,
        stderr_W=sW, stderr_V=sV, stderr_Gamma=np.zeros((D, 3)), stderr_ok=np.isfinite(s2) & ok,
        covariance=_ScaledCovariance(Ainv, s2z), params=p, param_names=list(gn.PARAM_NAMES), ok=ok,
        messages=messages,
        readings_g=gf, status=["converged" if c else "max_iter" for c in conv])


def _norm_resid(ps: np.ndarray, gf: np.ndarray) -> np.ndarray:
    """r = |M (v - B)| - 1 elementwise for parameters ps (..., 9) and readings gf (..., 3)."""
    m = [ps[..., k] for k in range(9)]
    u = [gf[..., i] - m[6 + i] for i in range(3)]
    a0 = m[0] * u[0] + m[3] * u[1] + m[4] * u[2]
    a1 = m[3] * u[0] + m[1] * u[1] + m[5] * u[2]
    a2 = m[4] * u[0] + m[5] * u[1] + m[2] * u[2]
    return np.sqrt(a0 * a0 + a1 * a1 + a2 * a2) - 1.0


def _loo9(gf, p, r, J, Ainv, steps: int = 1) -> np.ndarray:
    """Held-out residuals (D, P) of model 9: pose i's residual under the fit without pose i,
    by ``steps`` Gauss-Newton steps from the full fit p (J is (9, D, P), at p).

    Step 1 is the one-step (leverage) approximation, in closed form for every (board, pose):
    the normal matrix without pose i is A - j_i j_i^T, whose inverse is
    A^-1 + u_i u_i^T / (1 - h_i) with u_i = A^-1 j_i, h_i = j_i^T u_i (Sherman-Morrison),
    so the step is -(A^-1 g) - u_i (u_i.g - r_i) / (1 - h_i) with g = J^T r the full gradient
    (~0 at the optimum); pose i's residual is then evaluated exactly (not linearised) at the
    stepped parameters.  Its error is second order in the step: against exact refits (damped,
    to convergence) it is within 1e-5 g and 0.5 % of the cross-validated RMS at 1 mg noise
    (tests/test_lot.py).  Each further step (``steps`` > 1) re-evaluates the gradient of the
    P - 1 poses at the new point and applies the same inverse (a chord step: P^2 residuals
    per board, about 3 times the cost of everything else; the error contracts by the
    size of the step each time)."""
    D, P, _ = gf.shape
    if steps == 1:
        return _loo9_one_step(gf, p, r, J, Ainv)
    Jd = np.ascontiguousarray(J.transpose(1, 2, 0))  # (D, P, 9)
    U = Jd @ Ainv  # u_i = A^-1 j_i (D, P, 9); A^-1 symmetric
    h = np.einsum("dpk,dpk->dp", U, Jd)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv1h = np.where(h < 1.0 - 1e-9, 1.0 / (1.0 - h), np.nan)
    grad = np.einsum("dpk,dp->dk", Jd, r)  # J^T r (~0 at the optimum)
    Ag = np.einsum("dkl,dl->dk", Ainv, grad)
    ug = np.einsum("dpk,dk->dp", U, grad)
    ps = p[:, None, :] - Ag[:, None, :] - U * ((ug - r) * inv1h)[..., None]  # (D, P, 9)
    if steps > 1:
        g = np.ascontiguousarray(np.broadcast_to(gf.transpose(2, 0, 1)[:, :, None, :], (3, D, P, P)))
        keep_n = np.tile(1.0 - np.eye(P), (D, 1))  # row (d, i): pose i held out
    for _ in range(steps - 1):
        Gi = _masked_grad(ps.reshape(D * P, 9), g.reshape(3, D * P, P), keep_n).reshape(D, P, 9)
        AG = Gi @ Ainv
        ps -= AG + U * (np.einsum("dpk,dpk->dp", U, Gi) * inv1h)[..., None]
    return _norm_resid(ps, gf)


_W_OF_P = [0, 3, 4, 3, 1, 5, 4, 5, 2]  # the parameter of W[a, b] (row-major): M_xx M_xy M_xz ...


def _loo9_one_step(gf, p, r, J, Ainv) -> np.ndarray:
    """_loo9 with one step, on (D, 9, P) and (D, P) arrays: u_i as the columns of A^-1 J^T,
    each parameter of the stepped fits a (D, P) array (no (D, P, 9) broadcast)."""
    Jn = J.transpose(1, 0, 2)  # (D, 9, P)
    Ut = Ainv @ Jn  # column i: u_i = A^-1 j_i
    h = np.einsum("dkp,dkp->dp", Ut, Jn)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv1h = np.where(h < 1.0 - 1e-9, 1.0 / (1.0 - h), np.nan)
    grad = np.einsum("kdp,dp->dk", J, r)  # J^T r (~0 at the optimum)
    Ag = (Ainv @ grad[..., None])[..., 0]
    c = (np.einsum("dkp,dk->dp", Ut, grad) - r) * inv1h
    m = [(p[:, k] - Ag[:, k])[:, None] - Ut[:, k] * c for k in range(9)]  # stepped parameters (D, P)
    u = [gf[..., i] - m[6 + i] for i in range(3)]
    a0 = m[0] * u[0] + m[3] * u[1] + m[4] * u[2]
    a1 = m[3] * u[0] + m[1] * u[1] + m[5] * u[2]
    a2 = m[4] * u[0] + m[5] * u[1] + m[2] * u[2]
    return np.sqrt(a0 * a0 + a1 * a1 + a2 * a2) - 1.0


def _propagate9(Ainv, s2, M, B):
    """Standard errors of W = M and V = -M B from the covariance Ainv s2 of (M, B) (first order)."""
    D = len(Ainv)
    Gv = np.zeros((D, 3, 9))
    for j, (a, b) in enumerate(zip(*gn._IU)):
        Gv[:, a, j] -= B[:, b]
        if a != b:
            Gv[:, b, j] -= B[:, a]
    Gv[:, :, 6:] = -M
    var_p = np.diagonal(Ainv, axis1=1, axis2=2)[:, _W_OF_P] * s2[:, None]
    sW = np.sqrt(np.clip(var_p, 0, None)).reshape(D, 3, 3)  # W = M
    sV = np.sqrt(np.clip(((Gv @ Ainv) * Gv).sum(axis=-1) * s2[:, None], 0, None))  # diag(G C G^T)
    return sW, sV


BLOCK = {"12": 8192, "9": 2048, "6": 1 << 40, "15": 1 << 40}  # boards per call: the working set stays in cache


class _Assembler:
    """One BatchFit of D boards from fits of board subsets (rows given by a slice or indices):
    each part is copied into arrays allocated at the first part as soon as it is fitted, while
    it is still in cache (and no list of parts is kept to concatenate afterwards)."""

    _SHARED = ("model", "param_names", "input_units")

    def __init__(self, D: int, gf: np.ndarray):
        self.D, self.gf, self.kw, self.whole = D, gf, None, None

    def add(self, rows: np.ndarray | slice, b: BatchFit) -> None:
        if isinstance(rows, slice) and rows == slice(0, self.D):
            self.whole = b
            return
        if self.kw is None:
            self.kw = {name: self._alloc(name, getattr(b, name)) for name in b.__dataclass_fields__}
            self.copied = [name for name, out in self.kw.items() if name not in self._SHARED
                           and (isinstance(out, (list, _LazyCovariance))
                                or (isinstance(out, np.ndarray) and out is not self.gf))]
        for name in self.copied:
            out, v = self.kw[name], getattr(b, name)
            if isinstance(out, _LazyCovariance):
                for f in out._fields:
                    getattr(out, f)[rows] = getattr(v, f)
            elif isinstance(out, np.ndarray):
                out[rows] = v
            elif isinstance(rows, slice):
                out[rows] = v
            else:
                for k, i in enumerate(rows):
                    out[i] = v[k]

    def _alloc(self, name: str, v0):
        D = self.D
        if name in self._SHARED:
            return v0
        if name == "readings_g":
            return self.gf
        if name in ("messages", "status"):
            return None if v0 is None else [""] * D
        if isinstance(v0, _LazyCovariance):
            return type(v0)(*(np.empty((D,) + getattr(v0, f).shape[1:]) for f in v0._fields))
        if v0 is None or np.ndim(v0) == 0:
            return v0
        return np.empty_like(v0, shape=(D,) + np.shape(v0)[1:])  # the part's memory layout: contiguous copies

    def result(self) -> BatchFit:
        if self.whole is not None:
            return self.whole
        if self.kw is None:
            raise UnderdeterminedError("no boards to fit")
        return BatchFit(**self.kw)


def _reference_groups(ref: np.ndarray) -> list[tuple[np.ndarray | slice, np.ndarray]]:
    """Boards grouped by identical reference sets: [(rows, shared (P, 3) references)].
    A lot usually has one set (the fixture's poses); a broadcast array is recognised free."""
    D = len(ref)
    if D == 0 or ref.strides[0] == 0 or np.array_equal(ref, np.broadcast_to(ref[0], ref.shape)):
        return [(slice(0, D), np.ascontiguousarray(ref[0]) if D else ref.reshape(-1, 3))]
    uniq, inv = np.unique(ref.reshape(D, -1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    return [(np.flatnonzero(inv == k), uniq[k].reshape(-1, 3)) for k in range(len(uniq))]


def _workers() -> int:
    """Threads for fit_stacked: the CPUs this process may run on (numpy releases the GIL in
    its loops and LAPACK calls, so blocks fit in parallel), at most 8."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 8))


def fit_stacked(gf: np.ndarray, ref: np.ndarray | None, model: str, noise_g: np.ndarray | None = None,
                workers: int | None = None) -> BatchFit:
    """The fast fitter of ``model`` on (D, P, 3) readings in g (references in g for 6/12/15),
    in blocks of BLOCK[model] boards, fitted by ``workers`` threads (default: one per CPU);
    model 12 per group of boards sharing their references.  Blocks are independent, so the
    result does not depend on the number of threads."""
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    ref = None if ref is None else np.broadcast_to(np.asarray(ref, dtype=float), (D, P, 3))
    nz = None if noise_g is None else np.broadcast_to(np.asarray(noise_g, dtype=float), (D, P, 3))
    groups = _reference_groups(ref) if model == "12" else [(slice(0, D), ref)]
    jobs = []
    for rows, gref in groups:
        idx = np.arange(D)[rows] if isinstance(rows, slice) else rows
        for a in range(0, len(idx), BLOCK[model]):
            sel = slice(idx[0] + a, min(idx[0] + a + BLOCK[model], idx[-1] + 1)) \
                if isinstance(rows, slice) else idx[a:a + BLOCK[model]]
            jobs.append((sel, gref))

    def run(job):
        sel, gref = job
        n = None if nz is None else nz[sel]
        if model == "9":
            return sel, fit9(gf[sel], n)
        if model == "12":
            return sel, fit12(gf[sel], gref, n)
        return sel, fit_linear_batch(gf[sel], ref[sel], model, n)

    out = _Assembler(D, gf)
    workers = _workers() if workers is None else max(1, int(workers))
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            out.add(*run(job))
        return out.result()
    with ThreadPoolExecutor(max_workers=workers) as ex:
        pending: deque = deque()
        for job in jobs:  # at most 2 blocks per thread in flight: memory stays bounded
            pending.append(ex.submit(run, job))
            if len(pending) >= 2 * workers:
                out.add(*pending.popleft().result())
        while pending:
            out.add(*pending.popleft().result())
    return out.result()

"""Small symmetric matrices stacked along a trailing board axis: ``A`` is (n, n, N), one
n x n matrix per board, and every routine is elementwise numpy over the N boards.

For the 9 x 9 normal matrices of model 9 this costs a few hundred numpy calls on (N,)
rows instead of N LAPACK calls: LAPACK's batched routines copy and dispatch each 9 x 9
matrix alone, so at 2048 boards a Cholesky here takes half the time of
``np.linalg.cholesky``, an inverse a third of ``np.linalg.inv``'s, and the extreme
eigenvalues half of ``np.linalg.eigvalsh`` (benchmarks/bench_lot.py measures the whole fit).

- ``inv3_sym``, ``mul3_sym``: 3 x 3 symmetric inverse (adjugate) and product, entry by entry;
- ``cholesky``: A = L L^T (Golub & Van Loan, Alg. 4.2.1, by columns), flagging boards
  whose A is not positive definite instead of raising;
- ``solve`` and ``inverse`` from the factor (forward and back substitution; A^-1 = L^-T L^-1);
- ``extreme_eigenvalues``: Householder tridiagonalisation (Golub & Van Loan, Alg. 8.3.1),
  then Laguerre's iteration on the characteristic polynomial from Gershgorin bounds,
  which converges monotonically to the largest (from above) and the smallest (from
  below) root of a polynomial whose roots are all real; a Sturm count certifies each
  board's pair, and the caller recomputes the few it cannot certify by LAPACK.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Sym3 = tuple[np.ndarray, ...]  # the 6 distinct entries of symmetric 3 x 3 matrices: 00 01 02 11 12 22


def boards_last(a: np.ndarray) -> np.ndarray:
    """(D, P, 3) boards' arrays as a contiguous (3, P, D), boards last: every (k, p) row of D
    boards is contiguous, so per-board sums over poses add long rows.  (A (P, 3, D) copy made
    by a 2-D transpose is 35 % faster to make, but a sum over poses then adds in another order:
    the fits would differ in their last bits from every earlier result.)"""
    return np.ascontiguousarray(a.transpose(2, 1, 0))


def inv3_sym(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray, f: np.ndarray
             ) -> tuple[Sym3, np.ndarray]:
    """Adjugate and determinant of symmetric [[a b c] [b d e] [c e f]] (entries elementwise):
    the inverse is adj / det, with adj's 6 distinct entries returned in the same order."""
    A00, A01, A02 = d * f - e * e, c * e - b * f, b * e - c * d
    A11, A12, A22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A00 + b * A01 + c * A02
    return (A00, A01, A02, A11, A12, A22), det


def mul3_sym(X: Sym3, Y: Sym3) -> Sym3:
    """X Y for symmetric 3 x 3 matrices that commute (so the product is symmetric), each given
    as its 6 entries (00 01 02 11 12 22)."""
    x00, x01, x02, x11, x12, x22 = X
    y00, y01, y02, y11, y12, y22 = Y
    return (x00 * y00 + x01 * y01 + x02 * y02, x00 * y01 + x01 * y11 + x02 * y12,
            x00 * y02 + x01 * y12 + x02 * y22, x01 * y01 + x11 * y11 + x12 * y12,
            x01 * y02 + x11 * y12 + x12 * y22, x02 * y02 + x12 * y12 + x22 * y22)


@dataclass(frozen=True)
class Cholesky:
    """A = L L^T per board: ``L`` (n, n, N) lower triangular, ``inv_diag`` (n, N) = 1 / diag(L),
    ``ok`` (N,) False where A is not positive definite (that board's factor is meaningless)."""

    L: np.ndarray
    inv_diag: np.ndarray
    ok: np.ndarray


def cholesky(A: np.ndarray) -> Cholesky:
    """Cholesky factor of each board's symmetric A (n, n, N), column by column."""
    n = A.shape[0]
    L = np.zeros_like(A)
    inv = np.empty(A.shape[1:])
    ok = np.ones(A.shape[2:], dtype=bool)
    for j in range(n):
        Lj = L[j, :j]
        s = A[j, j] - np.einsum("kn,kn->n", Lj, Lj) if j else A[0, 0].copy()
        good = s > 0
        ok &= good
        r = 1.0 / np.sqrt(np.where(good, s, 1.0))
        inv[j] = r
        L[j, j] = np.where(good, s, 1.0) * r
        if j + 1 < n:
            col = A[j + 1:, j] - np.einsum("ikn,kn->in", L[j + 1:, :j], Lj) if j else A[1:, 0]
            L[j + 1:, j] = col * r
    return Cholesky(L, inv, ok)


def solve(ch: Cholesky, b: np.ndarray) -> np.ndarray:
    """x (n, N) of A x = b (n, N) per board, by forward then back substitution."""
    L, inv = ch.L, ch.inv_diag
    n = len(b)
    y = np.empty_like(b)
    y[0] = b[0] * inv[0]
    for i in range(1, n):
        y[i] = (b[i] - np.einsum("kn,kn->n", L[i, :i], y[:i])) * inv[i]
    x = np.empty_like(b)
    x[n - 1] = y[n - 1] * inv[n - 1]
    for i in range(n - 2, -1, -1):
        x[i] = (y[i] - np.einsum("kn,kn->n", L[i + 1:, i], x[i + 1:])) * inv[i]
    return x


def inverse(ch: Cholesky) -> np.ndarray:
    """A^-1 (n, n, N) = L^-T L^-1, with L^-1 by forward substitution row by row."""
    L, inv = ch.L, ch.inv_diag
    n = L.shape[0]
    X = np.zeros_like(L)
    for i in range(n):
        X[i, i] = inv[i]
        if i:
            X[i, :i] = -np.einsum("kn,kjn->jn", L[i, :i], X[:i, :i]) * inv[i]
    return np.einsum("kin,kjn->ijn", X, X)


def tridiagonal(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Householder reduction of symmetric A (n, n, N) to a similar tridiagonal matrix:
    its diagonal d (n, N) and squared off-diagonal e2 (n - 1, N) (Golub & Van Loan Alg. 8.3.1)."""
    S = A.copy()
    n = S.shape[0]
    d, e2 = np.empty(S.shape[1:]), np.empty((n - 1,) + S.shape[2:])
    for k in range(n - 2):
        x = S[k + 1:, k]
        s = np.einsum("in,in->n", x, x)
        d[k], e2[k] = S[k, k], s
        alpha = -np.copysign(np.sqrt(s), x[0])
        v = x.copy()
        v[0] -= alpha
        vv = 2.0 * (s - alpha * x[0])  # |v|^2, as alpha^2 = s
        with np.errstate(divide="ignore", invalid="ignore"):
            beta = np.where(vv > 0, 2.0 / vv, 0.0)  # a zero column needs no reflection
        T = S[k + 1:, k + 1:]
        p = np.einsum("ijn,jn->in", T, v) * beta
        w = p - (0.5 * beta * np.einsum("in,in->n", p, v)) * v
        vw = v[:, None] * w[None, :]
        T -= vw  # T <- H T H = T - v w^T - w v^T
        T -= vw.swapaxes(0, 1)
    d[n - 2], d[n - 1] = S[n - 2, n - 2], S[n - 1, n - 1]
    e2[n - 2] = S[n - 1, n - 2] ** 2
    return d, e2


def _laguerre_step(d: np.ndarray, e2: np.ndarray, x: np.ndarray) -> np.ndarray:
    """One Laguerre step for det(x I - T) of the tridiagonal (d, e2) at x (..., N): p, p' and
    p'' by the three-term recurrence p_k = (x - d_k) p_k-1 - e2_k-1 p_k-2 and its derivatives."""
    n = d.shape[0]
    p0, p1 = np.ones_like(x), x - d[0]
    q0, q1 = np.zeros_like(x), np.ones_like(x)
    r0, r1 = np.zeros_like(x), np.zeros_like(x)
    for k in range(1, n):
        t = x - d[k]
        p0, p1 = p1, t * p1 - e2[k - 1] * p0
        q0, q1 = q1, p0 + t * q1 - e2[k - 1] * q0
        r0, r1 = r1, 2.0 * q0 + t * r1 - e2[k - 1] * r0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        G = q1 / p1
        H = G * G - r1 / p1
        den = G + np.copysign(np.sqrt(np.maximum((n - 1) * (n * H - G * G), 0.0)), G)
        return np.where((p1 == 0) | (den == 0) | ~np.isfinite(den), 0.0, n / den)


def _count_below(d: np.ndarray, e2: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Eigenvalues of the tridiagonal (d, e2) below x: the negative pivots of T - x I (Sturm)."""
    q = d[0] - x
    count = (q < 0).astype(int)
    tiny = 1e-300
    for k in range(1, d.shape[0]):
        q = d[k] - x - e2[k - 1] / np.where(np.abs(q) < tiny, -tiny, q)
        count += q < 0
    return count


def extreme_eigenvalues(A: np.ndarray, iters: int = 12, rtol: float = 1e-12
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The smallest and largest eigenvalues (N,) of symmetric A (n, n, N), and ``sure`` (N,):
    both converged (last step within 1e-9 relative) and certified by a Sturm count (no
    eigenvalue below lo or above hi by more than that).  Where ``sure`` is False the caller should use LAPACK."""
    n = A.shape[0]
    scale = np.abs(np.einsum("iin->n", A))
    scale = np.where(scale > 0, scale, 1.0)
    d, e2 = tridiagonal(A / scale)  # eigenvalues within [-1, 1] for a positive semi-definite A
    e = np.sqrt(e2)
    radius = np.zeros_like(d)
    radius[:-1] += e
    radius[1:] += e
    # bounds: Gershgorin's, and for a positive semi-definite A the Frobenius norm above, 0 below
    # (where A is not, the smallest root may lie below 0: the Sturm count then sends it to LAPACK)
    frob = np.sqrt((d * d).sum(axis=0) + 2.0 * e2.sum(axis=0))
    x = np.stack([np.minimum((d + radius).max(axis=0), frob), np.maximum((d - radius).min(axis=0), 0.0)])
    step = np.full_like(x, np.inf)
    for _ in range(iters):
        step = _laguerre_step(d, e2, x)
        x = x - step
        if np.all(np.abs(step) <= rtol * np.abs(x)):
            break
    hi, lo = x
    margin = 1e-9 * np.abs(x) + 1e-13  # rounding of the Sturm pivots is ~1e-16 of the trace
    sure = (np.all(np.abs(step) <= margin, axis=0) & np.isfinite(x).all(axis=0)
            & (_count_below(d, e2, lo - margin[1]) == 0) & (_count_below(d, e2, hi + margin[0]) == n))
    return lo * scale, hi * scale, sure

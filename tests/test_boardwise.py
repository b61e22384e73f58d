"""models/boardwise.py (small symmetric matrices along a trailing board axis) against LAPACK,
and the model 9 condition number built on it."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from accelcal_station.models import boardwise as bw
from accelcal_station.models.heap import keep_block_memory
from accelcal_station.models.stacked_norm import _condition


def _spd(rng, N, n, log10_range=(-3, 1)):
    Q = np.linalg.qr(rng.normal(size=(N, n, n)))[0]
    lam = 10 ** rng.uniform(*log10_range, (N, n))
    return (Q * lam[:, None, :]) @ Q.transpose(0, 2, 1)


def _last(A):  # (N, n, n) -> (n, n, N)
    return np.ascontiguousarray(A.transpose(1, 2, 0))


@pytest.mark.parametrize("n", [3, 4, 9])
def test_cholesky_solve_and_inverse_match_lapack(n):
    rng = np.random.default_rng(1)
    A = _spd(rng, 500, n)
    b = rng.normal(size=(500, n))
    ch = bw.cholesky(_last(A))
    assert ch.ok.all()
    np.testing.assert_allclose(ch.L.transpose(2, 0, 1), np.linalg.cholesky(A), rtol=1e-10, atol=1e-12)
    x = bw.solve(ch, np.ascontiguousarray(b.T)).T
    np.testing.assert_allclose(x, np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(bw.inverse(ch).transpose(2, 0, 1), np.linalg.inv(A), rtol=1e-8, atol=1e-10)


def test_cholesky_flags_boards_that_are_not_positive_definite_without_raising():
    rng = np.random.default_rng(2)
    A = _spd(rng, 6, 9)
    A[1] -= 2 * np.linalg.eigvalsh(A[1])[0] * np.eye(9)  # one negative eigenvalue
    A[3] = np.zeros((9, 9))
    A[4, 0, 0] = np.nan
    ch = bw.cholesky(_last(A))
    assert ch.ok.tolist() == [True, False, True, False, False, True]


def test_tridiagonal_keeps_the_eigenvalues():
    rng = np.random.default_rng(3)
    S = rng.normal(size=(200, 9, 9))
    A = S + S.transpose(0, 2, 1)  # symmetric, indefinite
    d, e2 = bw.tridiagonal(_last(A))
    T = np.zeros_like(A)
    i = np.arange(9)
    T[:, i, i] = d.T
    T[:, i[:-1], i[1:]] = T[:, i[1:], i[:-1]] = np.sqrt(e2.T)
    np.testing.assert_allclose(np.linalg.eigvalsh(T), np.linalg.eigvalsh(A), atol=1e-12 * np.abs(A).max())


def _hard_stack(rng):
    """Well and badly conditioned, clustered, repeated, diagonal, identity, singular, indefinite."""
    N = 400
    A = _spd(rng, N, 9, (-2, 2))
    A[:50] = _spd(rng, 50, 9, (-7, 2))  # condition numbers up to 1e9
    Q = np.linalg.qr(rng.normal(size=(100, 9, 9)))[0]
    lam = np.ones((100, 9))
    lam[:, :3] = 0.3 * (1 + rng.normal(0, 1e-9, (100, 3)))  # clusters at both ends
    lam[:, 6:] = 2.0 * (1 + rng.normal(0, 1e-9, (100, 3)))
    A[50:150] = (Q * lam[:, None, :]) @ Q.transpose(0, 2, 1)
    A[150:160] = np.eye(9) * rng.uniform(0.1, 10, (10, 1, 1))
    A[160:170] = np.array([np.diag(rng.uniform(0.1, 10, 9)) for _ in range(10)])
    S = rng.normal(size=(20, 9, 9))
    A[170:190] = S + S.transpose(0, 2, 1)  # indefinite
    A[190:200] = np.einsum("dip,djp->dij", *(2 * [rng.normal(size=(10, 9, 5))]))  # rank 5
    return A


def test_extreme_eigenvalues_are_never_certified_wrong():
    rng = np.random.default_rng(4)
    A = _hard_stack(rng)
    ev = np.linalg.eigvalsh(A)
    lo, hi, sure = bw.extreme_eigenvalues(_last(A))
    scale = np.abs(ev).max(axis=1)
    assert sure[200:].mean() > 0.95  # ordinary matrices are certified, LAPACK is the exception
    assert sure[150:170].all()  # the identity and diagonal matrices too
    np.testing.assert_allclose(hi[sure], ev[sure, -1], rtol=1e-9, atol=0)
    err_lo = np.abs(lo - ev[:, 0])[sure]  # eigvalsh's own error is ~1e-16 of the largest
    assert np.all(err_lo <= 1e-12 * scale[sure] + 1e-9 * np.abs(ev[sure, 0]))


def test_model9_condition_number_matches_lapack_on_every_board():
    # the certified boards by boardwise, the others by LAPACK: one answer either way
    rng = np.random.default_rng(5)
    A = _hard_stack(rng)[:170]  # positive definite ones
    ev = np.linalg.eigvalsh(A)
    cond, lam_min = _condition(_last(A))
    np.testing.assert_allclose(cond, np.sqrt(ev[:, -1] / ev[:, 0]), rtol=1e-6)
    np.testing.assert_allclose(lam_min, ev[:, 0], rtol=1e-6)
    A[3, 0, 0] = np.nan
    cond, _ = _condition(_last(A))
    assert np.isnan(cond[3]) and np.isfinite(np.delete(cond, 3)).all()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mallopt is glibc's (Linux)")
def test_heap_thresholds_are_set_once_on_glibc():
    import ctypes
    try:
        _ = ctypes.CDLL("libc.so.6").mallopt  # glibc has it; musl and others raise
    except (OSError, AttributeError):
        pytest.skip("not glibc: the allocator keeps its own policy")
    assert keep_block_memory() and keep_block_memory()

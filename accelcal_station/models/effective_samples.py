"""The effective sample count of correlated samples: n_eff = n / tau_int.

A chip's low-pass filter (MPU6050 DLPF) makes neighbouring samples correlated, and the
variance of the mean of n samples with autocorrelation rho_k is

    var(mean) = sigma^2 / n * (1 + 2 sum_{k=1}^{n-1} (1 - k/n) rho_k) = sigma^2 / n_eff

(e.g. Priestley, Spectral Analysis and Time Series, eq. 5.3.5).  ``tau_int`` is estimated
from the samples' own autocorrelation with Sokal's automatic window (A. Sokal, "Monte Carlo
methods in statistical mechanics", 1996, section 3): the sum runs to the smallest lag M
with M >= c * tau_int(M), c = 5, which keeps the window's bias small (terms beyond
~5 tau decay as exp(-5)) without summing the noise of the far lags.  tau_int is floored
at 1: an estimate below 1 on white noise is chance, and flooring never lowers a
reported error.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

SOKAL_C = 5.0  # Sokal's window constant


def autocorrelation(x: ArrayLike, max_lag: int | None = None) -> np.ndarray:
    """Sample autocorrelation rho_k, k = 0..max_lag, per column of x (n, m) -> (max_lag + 1, m).

    The biased estimator (sum over n - k products divided by n c_0), by FFT; a column
    with no variance gets rho = [1, 0, 0, ...]."""
    a = np.asarray(x, dtype=float)
    a = a.reshape(len(a), -1)
    n = len(a)
    lag = n - 1 if max_lag is None else min(int(max_lag), n - 1)
    d = a - a.mean(axis=0)
    size = 1 << int(np.ceil(np.log2(max(2 * n - 1, 1))))
    f = np.fft.rfft(d, size, axis=0)
    acov = np.fft.irfft(f * np.conj(f), size, axis=0)[:lag + 1]
    c0 = acov[0]
    flat = c0 <= 1e-12 * max(1.0, float(np.max(np.abs(d))) ** 2)
    rho = acov / np.where(flat, 1.0, c0)
    rho[:, flat] = 0.0
    rho[0] = 1.0
    return rho


def tau_int(x: ArrayLike, c: float = SOKAL_C) -> np.ndarray:
    """Integrated autocorrelation time per column: 1 + 2 sum_{k=1}^{M} (1 - k/n) rho_k with
    Sokal's window M = min{M : M >= c tau_int(M)}; at least 1."""
    a = np.asarray(x, dtype=float)
    a = a.reshape(len(a), -1)
    n = len(a)
    if n < 4:
        return np.ones(a.shape[1])
    rho = autocorrelation(a, min(n - 1, max(8, n // 2)))
    k = np.arange(len(rho))[:, None]
    partial = 1.0 + 2.0 * np.cumsum(np.where(k >= 1, (1.0 - k / n) * rho, 0.0), axis=0)
    ok = k >= c * partial  # the window condition per lag and column
    m = np.where(ok.any(axis=0), ok.argmax(axis=0), len(rho) - 1)
    tau = partial[m, np.arange(a.shape[1])]
    return np.maximum(tau, 1.0)


def effective_n(x: ArrayLike, c: float = SOKAL_C) -> np.ndarray:
    """n_eff = n / tau_int per column of x (n, m): var(mean) = var / n_eff."""
    a = np.asarray(x, dtype=float)
    a = a.reshape(len(a), -1)
    return len(a) / tau_int(a, c)

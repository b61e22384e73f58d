"""The noise floor of the diagnosis: what the simulator (or the data's own spread) says a pose mean varies by.

The variance of a pose mean of n samples with white noise sigma and quantization step q is
``B + (sigma^2 + q^2/12 - B) / n`` per axis, where
``B = sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2 / q^2)`` is the part of the
quantization error that averaging cannot remove (the Fourier series of the rounding error
smoothed by the noise; B = q^2/12 without noise, 0 when the noise dithers).  Pose scatter s
(rad, per rotation axis) adds ``s^2 (1 - ref_c^2)`` (static_view).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass
class Floor:
    """What the simulator says the noise is: per-sample sigma (3,) g, quantization step q g, pose scatter s rad."""

    sigma_g: np.ndarray
    q_g: float
    scatter_rad: float
    gamma: float  # configured local gravity in standard g
    sim_sigma_g: np.ndarray | None = None  # the simulator's own sigma, when sigma_g was measured from the data
    source: str = "simulator noise and quantization"
    sim_q_g: float | None = None  # the simulator's own LSB, when q_g was measured from the data

    @property
    def simulator_sigma_g(self) -> np.ndarray:
        """The simulator's own per-sample sigma: sim_sigma_g, or sigma_g when that was not measured."""
        return self.sim_sigma_g if self.sim_sigma_g is not None else self.sigma_g


def bias_var(sigma: ArrayLike, q: ArrayLike) -> np.ndarray:
    """B: variance (over poses) of the quantization error a mean of n samples keeps (module doc)."""
    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    k = np.arange(1, 201)  # enough terms for B -> q^2/12 as sigma -> 0
    qs = np.where(q > 0, q, 1.0)[..., None]
    terms = qs**2 / (2 * np.pi**2 * k**2) * np.exp(-4 * np.pi**2 * k**2 * sigma[..., None]**2 / qs**2)
    return np.where(q > 0, terms.sum(-1), 0.0)


def random_var(sigma: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Per-sample variance around a pose's mean: sigma^2 + q^2/12 - B."""
    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    return sigma**2 + q**2 / 12.0 - bias_var(sigma, q)


def within_spread(sigma: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Variance, over a pose's position on the quantization grid, of its within-pose variance.

    w(x) = Var[Q(x + noise)] for x uniform in one step (numerically, on 64 positions);
    0 without quantization.  Heavy quantization (sigma << q) makes w swing from 0 (x mid-step)
    to about q^2/4 (x on a step edge), which a sampling variance alone would not predict.
    """
    from scipy.special import ndtr

    sigma, q = np.broadcast_arrays(np.asarray(sigma, float), np.asarray(q, float))
    out = np.zeros(sigma.shape)
    for idx in np.ndindex(sigma.shape):
        s, h = float(sigma[idx]), float(q[idx])
        if h <= 0:
            continue
        x = (np.arange(64) + 0.5) / 64 * h
        K = int(np.ceil(6 * s / h)) + 1
        k = np.arange(-K, K + 1)[:, None] * h
        pk = ndtr((k + h / 2 - x) / s) - ndtr((k - h / 2 - x) / s) if s > 0 else (np.abs(k - x) < h / 2).astype(float)
        m = np.sum(pk * k, axis=0)
        w = np.sum(pk * k**2, axis=0) - m**2
        out[idx] = np.var(w)
    return out


def mean_var(sigma: ArrayLike, q: ArrayLike, n: ArrayLike) -> np.ndarray:
    """Variance of a mean of n samples: B + (sigma^2 + q^2/12 - B) / n (module doc)."""
    return bias_var(sigma, q) + random_var(sigma, q) / n


def sigma_from_within(w2: ArrayLike, q: ArrayLike) -> np.ndarray:
    """White-noise sigma whose within-pose variance (with quantization q) is w2: solves random_var = w2."""
    w2 = np.asarray(w2, float)
    s2 = np.maximum(w2 - np.asarray(q) ** 2 / 12.0, 0.0)
    for _ in range(30):
        s2 = np.maximum(w2 - np.asarray(q) ** 2 / 12.0 + bias_var(np.sqrt(s2), q), 0.0)
    return np.sqrt(s2)

"""The chip's output noise in time: white, or a one-pole low-pass (AR(1)) process carried from read to read.

A one-pole low-pass of bandwidth f_c sampled every 1/ODR is AR(1) with lag-1 correlation
a = exp(-2 pi f_c / ODR) (sensor_model.py stage 7, the MPU6050's DLPF): y_k = a y_(k-1) +
sqrt(1 - a^2) sigma e_k keeps the stationary sigma; over a gap of m ODR steps the state decays
by a^m (the exact AR(1) transition).  a = 0 gives the white draws unchanged.
"""
from __future__ import annotations

import numpy as np


def ar1(u: np.ndarray, a: float) -> np.ndarray:
    """y_k = a y_(k-1) + u_k along axis 0 (y_0 = u_0), vectorised: within a block of L samples
    y_(s+i) = a^i (a y_(s-1) + sum_(j<=i) a^-j u_(s+j)).  No scipy: it runs in emulator threads that
    must answer within a bus timeout, and scipy.signal's first import takes longer than that."""
    y = np.empty_like(u)
    # a^-L up to 1e260: the early terms a scaled-up cumsum rounds away are below eps of the late ones
    L = max(1, min(len(u), int(-600.0 / np.log(a)))) if a > 0 else 1
    prev = np.zeros(u.shape[1:])
    for s in range(0, len(u), L):
        blk = u[s:s + L]
        p = a ** np.arange(len(blk), dtype=float)[:, None]
        y[s:s + L] = p * (a * prev + np.cumsum(blk / p, axis=0))
        prev = y[s + len(blk) - 1]
    return y


class FilteredNoise:
    """The noise state of one board: the last sample's noise (g) and its time."""

    def __init__(self) -> None:
        self.state = np.zeros(3)
        self.t_last: float | None = None

    def draw(self, e: np.ndarray, t: np.ndarray, a: float, odr_hz: float) -> np.ndarray:
        """Noise (g) at sample times t from standard draws ``e`` already scaled to sigma (n, 3)."""
        if a <= 0.0:
            return e
        m = np.inf if self.t_last is None else max((float(t[0]) - self.t_last) * odr_hz, 1.0)
        am = a**m
        u = e.copy()
        u[0] = am * self.state + np.sqrt(1.0 - am * am) * e[0]
        u[1:] *= np.sqrt(1.0 - a * a)
        y = ar1(u, a)
        self.state, self.t_last = y[-1].copy(), float(t[-1])
        return y

"""Hand-placed faces: six faces referenced only as "this axis up", placed by hand a few degrees off.

The classical opposite-face estimate (AN4399 Eqns 12-17) uses each axis' own channel on
its two faces: offset = mean of the two, scale = half their difference.  A face tilted by
theta reads g cos(theta) on its axis, so hand placement biases the scale low by about
theta^2 / 2, and the off-axis channels, which carry the tilt, are thrown away.

Here the same six parameters (gain and offset per axis, W diagonal) are fitted to the
whole reading of every pose by the gravity norm instead, |diag(w) (x - o)| = 1 g
(Gauss-Newton from the classical estimate), so the reference direction is not needed
and each face's misplacement is what the calibrated reading says it is: the angle
between the calibrated reading and the face's axis.  Six distinct orientations
determine the six parameters exactly; revisits placed differently add the spare
orientations.  Cross-axis coupling moves readings across gravity like a misplacement
does: with faces alone the two cannot be told apart, and the result says so.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UnderdeterminedError
from ..identifiability import first_of_orientation

GN_ITER = 20
AXES = "xyz"


@dataclass(frozen=True)
class FaceFit:
    """A diagonal calibration ``g = w * (x - o)`` (per axis; x in g) and how it was found."""

    method: str  # "opposite-face" or "norm"
    gain: np.ndarray  # (3,) w
    offset_g: np.ndarray  # (3,) o, in input g
    misplacement_deg: np.ndarray | None  # (P,) angle of each pose's calibrated reading from its face axis
    distinct: int  # distinct orientations used
    note: str

    def apply(self, x_g: ArrayLike) -> np.ndarray:
        return self.gain * (np.asarray(x_g, dtype=float) - self.offset_g)

    def norm_error_g(self, x_g: ArrayLike) -> np.ndarray:
        """|calibrated| - 1 g of static readings (P, 3)."""
        return np.linalg.norm(self.apply(x_g), axis=-1) - 1.0

    def as_an4399(self) -> tuple[np.ndarray, np.ndarray]:
        """(W, V) of G = W G_f + V."""
        return np.diag(self.gain), -self.gain * self.offset_g


def _faces(ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Face axis (P,) and sign (P,) of "axis up" references; every pose must be one face."""
    ax = np.argmax(np.abs(ref), axis=1)
    sign = np.sign(ref[np.arange(len(ref)), ax])
    off = np.abs(ref).sum(axis=1) - np.abs(ref[np.arange(len(ref)), ax])
    if np.any(off > 1e-9):
        raise UnderdeterminedError("hand-placed faces need references along one axis each (e.g. 1,0,0)")
    for a in range(3):
        for s in (1, -1):
            if not np.any((ax == a) & (sign == s)):
                raise UnderdeterminedError(f"no face with {AXES[a]} {'up' if s > 0 else 'down'}: the six faces "
                                           "each need at least one pose")
    return ax, sign


def opposite_face(x_g: ArrayLike, ref: ArrayLike) -> FaceFit:
    """Classical estimate: per axis, offset = mean of its two faces' on-axis means, scale = half the difference."""
    x, ref = np.asarray(x_g, dtype=float), np.asarray(ref, dtype=float)
    ax, sign = _faces(ref)
    up = np.array([x[(ax == a) & (sign > 0), a].mean() for a in range(3)])
    down = np.array([x[(ax == a) & (sign < 0), a].mean() for a in range(3)])
    scale = (up - down) / 2
    return FaceFit("opposite-face", 1 / scale, (up + down) / 2, None, int(first_of_orientation(x[None])[0].sum()),
                   "on-axis channel only")


def norm_faces(x_g: ArrayLike, ref: ArrayLike) -> FaceFit:
    """Gain and offset per axis by the gravity norm over every pose, with each pose's misplacement."""
    x, ref = np.asarray(x_g, dtype=float), np.asarray(ref, dtype=float)
    ax, _ = _faces(ref)
    start = opposite_face(x, ref)
    distinct = int(first_of_orientation(x[None])[0].sum())
    if distinct < 6:
        raise UnderdeterminedError(f"{distinct} distinct orientations; gain and offset of three axes need 6")
    w, o = start.gain.copy(), start.offset_g.copy()
    for _ in range(GN_ITER):  # Gauss-Newton on r_p = |w (x_p - o)| - 1
        d = x - o
        c = w * d
        n = np.linalg.norm(c, axis=1)
        J = np.concatenate([c * d / n[:, None], -c * w / n[:, None]], axis=1)  # d r / d (w, o)
        step, *_ = np.linalg.lstsq(J, -(n - 1.0), rcond=None)
        w, o = w + step[:3], o + step[3:]
        if np.max(np.abs(step)) < 1e-13:
            break
    cal = w * (x - o)
    u = cal / np.linalg.norm(cal, axis=1, keepdims=True)
    mis = np.degrees(np.arccos(np.clip(np.abs(u[np.arange(len(u)), ax]), -1.0, 1.0)))
    note = ("misplacement per pose is the calibrated reading's angle from its face axis; cross-axis coupling "
            "moves readings the same way, so faces alone cannot tell it from misplacement")
    if distinct == 6:
        note += "; six distinct orientations fit the six parameters exactly (no spare orientation to check them)"
    return FaceFit("norm", w, o, mis, distinct, note)


__all__ = ["FaceFit", "norm_faces", "opposite_face"]

"""Hand-placed faces: six faces referenced only as "this axis up", placed by hand a few degrees off.

The classical opposite-face estimate (AN4399 Eqns 12-17) uses each axis' own channel on
its two faces: offset = mean of the two, scale = half their difference.  A face tilted by
theta reads g cos(theta) on its axis, so hand placement biases the scale low by about
theta^2 / 2, and the off-axis channels, which carry the tilt, are thrown away.

Here the same six parameters (gain and offset per axis, W diagonal) are fitted to the
whole reading of every pose by the gravity norm instead, |diag(w) (x - o)| = k, k the site's
gravity in standard g (the length of the references, scaled to the site by the loader; 1 at
standard gravity), so the calibration maps the input to standard g (Gauss-Newton from the
classical estimate), so the reference direction is not needed and each face's misplacement is
what the calibrated reading says it is: the angle between the calibrated reading and the face's
axis.  Six distinct orientations determine the six parameters exactly; revisits placed differently add the spare
orientations.  Cross-axis coupling moves readings across gravity like a misplacement
does: with faces alone the two cannot be told apart, and the result says so.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..calibration import Calibration
from ..errors import UnderdeterminedError
from ..identifiability import first_of_orientation
from .linear import param_names
from .result import FitResult

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
    norm_g: float = 1.0  # the site's gravity in standard g: the calibrated readings' length

    def apply(self, x_g: ArrayLike) -> np.ndarray:
        return self.gain * (np.asarray(x_g, dtype=float) - self.offset_g)

    def norm_error_g(self, x_g: ArrayLike) -> np.ndarray:
        """|calibrated| - the site's gravity (standard g) of static readings (P, 3)."""
        return np.linalg.norm(self.apply(x_g), axis=-1) - self.norm_g

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


def site_norm_g(ref: np.ndarray) -> float:
    """The site's gravity in standard g the references were scaled to (their length; 1 unscaled)."""
    return float(np.median(np.linalg.norm(ref, axis=1)))


def opposite_face(x_g: ArrayLike, ref: ArrayLike) -> FaceFit:
    """Classical estimate: per axis, offset = mean of its two faces' on-axis means, gain = k over half the
    difference (a face reads o +- k / w, k the site's gravity in standard g)."""
    x, ref = np.asarray(x_g, dtype=float), np.asarray(ref, dtype=float)
    ax, sign = _faces(ref)
    k = site_norm_g(ref)
    up = np.array([x[(ax == a) & (sign > 0), a].mean() for a in range(3)])
    down = np.array([x[(ax == a) & (sign < 0), a].mean() for a in range(3)])
    scale = (up - down) / 2
    return FaceFit("opposite-face", k / scale, (up + down) / 2, None, int(first_of_orientation(x[None])[0].sum()),
                   "on-axis channel only", k)


def norm_faces(x_g: ArrayLike, ref: ArrayLike) -> FaceFit:
    """Gain and offset per axis by the gravity norm over every pose, with each pose's misplacement."""
    x, ref = np.asarray(x_g, dtype=float), np.asarray(ref, dtype=float)
    ax, _ = _faces(ref)
    start = opposite_face(x, ref)
    distinct = int(first_of_orientation(x[None])[0].sum())
    if distinct < 6:
        raise UnderdeterminedError(f"{distinct} distinct orientations; gain and offset of three axes need 6")
    w, o, k = start.gain.copy(), start.offset_g.copy(), start.norm_g
    for _ in range(GN_ITER):  # Gauss-Newton on r_p = |w (x_p - o)| - k
        d = x - o
        c = w * d
        n = np.linalg.norm(c, axis=1)
        J = np.concatenate([c * d / n[:, None], -c * w / n[:, None]], axis=1)  # d r / d (w, o)
        step, *_ = np.linalg.lstsq(J, -(n - k), rcond=None)
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
    return FaceFit("norm", w, o, mis, distinct, note, k)


def _held_out_rms(x: np.ndarray, ref: np.ndarray) -> float | None:
    """Leave-one-pose-out RMS norm error of the norm fit, or None when some face has one pose (leaving
    it out leaves that face's gain and offset undetermined)."""
    ax, sign = _faces(ref)
    if any(np.sum((ax == a) & (sign == s)) < 2 for a in range(3) for s in (1, -1)):
        return None
    e = [norm_faces(np.delete(x, i, 0), np.delete(ref, i, 0)).norm_error_g(x[i:i + 1])[0] for i in range(len(x))]
    return float(np.sqrt(np.mean(np.square(e))))


def norm_fit_result(x_g: ArrayLike, ref: ArrayLike, base: FitResult, noise_g: ArrayLike | None = None
                    ) -> FitResult:
    """The hand-placed faces' norm fit as the FitResult `accelcal fit` prints and saves (one object
    from fit to file): W = diag(w), V = -w o; residuals as model 9's (the calibrated reading's
    distance to the unit sphere), norm errors, leave-one-pose-out norm error, and standard errors
    (J^T J)^-1 s^2 of r_p = |w (x_p - o)| - k (k the site's gravity in standard g; s^2 the mean squared
    per-pose noise when given, else RSS / (P - 6)).  ``base``: the model-6 fit of the same poses (units,
    scale, metadata)."""
    x, r_ = np.asarray(x_g, dtype=float), np.asarray(ref, dtype=float)
    nf = norm_faces(x, r_)
    W, V = nf.as_an4399()
    cal = Calibration("6", W, V, np.zeros(3), base.calibration.input_units, base.calibration.input_per_g,
                      metadata={**base.calibration.metadata, "method": "hand-placed norm fit"})
    out = nf.apply(x)
    n = np.linalg.norm(out, axis=1)
    k = nf.norm_g
    resid = out / n[:, None] * k - out  # the calibrated reading's distance to the site's sphere
    d = x - nf.offset_g
    J = np.concatenate([out * d / n[:, None], -out * nf.gain / n[:, None]], axis=1)
    P = len(x)
    s2 = float(np.mean(np.square(noise_g))) if noise_g is not None else \
        (float(np.sum((n - k) ** 2)) / (P - 6) if P > 6 else None)
    sv = np.linalg.svd(J, compute_uv=False)
    cov = np.linalg.pinv(J.T @ J) * s2 if s2 is not None else None
    stderr = None
    if cov is not None:  # dV/d(w, o): V = -w o
        se_w = np.sqrt(np.clip(np.diag(cov)[:3], 0, None))
        G = np.concatenate([np.diag(-nf.offset_g), np.diag(-nf.gain)], axis=1)
        se_v = np.sqrt(np.clip(np.diag(G @ cov @ G.T), 0, None))
        stderr = {"W": np.diag(se_w), "V": se_v, "Gamma": np.zeros(3)}
    return FitResult(model="6", calibration=cal, pose_count=P, readings_g=x, residuals_g=resid,
                     norm_error_g=n - k, P=np.sum(resid**2, axis=0),
                     residual_rms_g=float(np.sqrt(np.mean((n - k) ** 2))),
                     residual_max_g=float(np.max(np.abs(resid))), stderr=stderr, covariance=cov,
                     condition_number=float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf"),
                     crossval_rms_g=_held_out_rms(x, r_), crossval_residuals_g=None,
                     params=np.concatenate([nf.gain, V]), param_names=param_names("6"),
                     message="hand-placed norm fit: gain and offset per axis by the gravity norm",
                     # leaving every pose of a face out leaves its gain and offset undetermined
                     crossval_by_orientation_rms_g=_held_out_rms(x, r_) if nf.distinct == P else None,
                     distinct_orientations=nf.distinct)


__all__ = ["FaceFit", "norm_faces", "norm_fit_result", "opposite_face", "site_norm_g"]

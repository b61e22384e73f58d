"""Units and pose conventions, made explicit.

Units of a reading:
  ``counts`` raw sensor output (needs ``counts_per_g``),
  ``g``      multiples of the local 1 g that the calibration targets,
  ``mps2``   metres per second squared (needs the local gravity in m/s^2).

Pose convention (AN4399 section 5): z down, output positive along gravity.  A pose
(pitch theta, roll phi) expects the output ``(-sin theta, cos theta sin phi,
cos theta cos phi)`` g, i.e. the flat board (0, 0) reads +1 g on z.  The other common
convention, "the axis pointing up reads +1 g", is given as explicit expected outputs
(``ref_x, ref_y, ref_z``), never by flipping signs behind the user's back.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .errors import UnitsError

STANDARD_GRAVITY_MPS2 = 9.80665
UNITS = ("counts", "g", "mps2")


def an4399_reference(pitch_deg: ArrayLike, roll_deg: ArrayLike) -> np.ndarray:
    """Expected output in g for AN4399 pitch/roll (AN4399 Eqn 22, z down).

    Vectorised: returns shape ``broadcast(pitch, roll).shape + (3,)``.
    """
    theta = np.deg2rad(np.asarray(pitch_deg, dtype=float))
    phi = np.deg2rad(np.asarray(roll_deg, dtype=float))
    theta, phi = np.broadcast_arrays(theta, phi)
    return np.stack([-np.sin(theta), np.cos(theta) * np.sin(phi), np.cos(theta) * np.cos(phi)], axis=-1)


def reference_to_angles(ref_g: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll in degrees (AN4399 Eqns 25-26) of a unit expected output."""
    ref = np.asarray(ref_g, dtype=float)
    ref = ref / np.linalg.norm(ref, axis=-1, keepdims=True)
    pitch = np.rad2deg(np.arcsin(np.clip(-ref[..., 0], -1.0, 1.0)))
    roll = np.rad2deg(np.arctan2(ref[..., 1], ref[..., 2]))
    return pitch, roll


def check_units(units: str) -> str:
    if units not in UNITS:
        raise UnitsError(f"unknown units {units!r}; allowed: counts, g, mps2")
    return units


def units_per_g(units: str, counts_per_g: float | None = None, gravity_mps2: float | None = None) -> float:
    """How many input units make 1 g (the scale that turns input into g)."""
    check_units(units)
    if units == "g":
        return 1.0
    if units == "mps2":
        g = STANDARD_GRAVITY_MPS2 if gravity_mps2 is None else float(gravity_mps2)
        if not np.isfinite(g) or not (9.7 <= g <= 9.9):
            raise UnitsError(f"gravity {gravity_mps2} m/s^2 is implausible; allowed 9.7 to 9.9 m/s^2")
        return g
    if counts_per_g is None:
        raise UnitsError("counts need --counts-per-g (e.g. 4096 for an MMA8451 at 2 g); none was given")
    c = float(counts_per_g)
    if not np.isfinite(c) or c <= 0:
        raise UnitsError(f"counts_per_g {counts_per_g} must be a positive number")
    return c


FACES = {  # expected output (positive along gravity) -> operator words
    (0, 0, 1): "z+ down: board flat, component side up",
    (0, 0, -1): "z- down: board upside down, component side down",
    (1, 0, 0): "x+ down: standing on its +x edge",
    (-1, 0, 0): "x- down: standing on its -x edge",
    (0, 1, 0): "y+ down: standing on its +y edge",
    (0, -1, 0): "y- down: standing on its -y edge",
}


def nearest_face(direction: ArrayLike) -> str:
    """The face (of six) closest to a measured output direction, in operator words."""
    d = np.asarray(direction, dtype=float)
    keys = np.array(list(FACES))
    return FACES[tuple(keys[int(np.argmax(keys @ d))])]


def angle_deg(a: ArrayLike, b: ArrayLike) -> float:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))

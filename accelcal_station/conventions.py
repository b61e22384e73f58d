"""Units and pose conventions, made explicit.

Units of a reading:
  ``counts`` raw sensor output (needs ``counts_per_g``),
  ``g``      multiples of the local 1 g that the calibration targets,
  ``mps2``   metres per second squared (needs the local gravity in m/s^2).

Pose convention of the mathematics and the files (AN4399 section 5): a pose (pitch
theta, roll phi) expects the output ``r = (-sin theta, cos theta sin phi, cos theta
cos phi)`` g (AN4399 Eqn 22), so the pose (0, 0) expects +1 g on z.  Explicit expected
outputs (``ref_x, ref_y, ref_z``) are the same ``r``, never sign-flipped behind the user's back.

Physics (docs/conventions.md): a chip at rest reads the specific force, +1 g on the axis
pointing *away from the Earth* (MMA8451Q data sheet, "Product orientation": top side up
gives Zout = +1 g; MPU-6050 product specification: face up gives +1 g on Z).  So the
placement that makes a real chip read ``r`` is the one with ``r`` pointing up: the
board-frame unit vector pointing up is ``up = r / |r|`` (:func:`up_direction`), and every
word (:func:`placement_words`), picture, jig angle and emulator derives from ``up``.
The world frame here has z pointing up (``WORLD_UP``); an attitude ``R`` maps board
axes to world axes, and the chip reads ``R.T @ WORLD_UP`` g (:func:`specific_force_g`).
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


WORLD_UP = np.array([0.0, 0.0, 1.0])  # world frame: z points away from the Earth

FACES = {  # board axis pointing up (it reads +1 g) -> how to place the board, in words
    (0, 0, 1): "z+ up: lay it flat, component side up",
    (0, 0, -1): "z- up: lay it flat upside down, component side down",
    (1, 0, 0): "x+ up: stand it on its -x edge, +x pointing up",
    (-1, 0, 0): "x- up: stand it on its +x edge, -x pointing up",
    (0, 1, 0): "y+ up: stand it on its -y edge, +y pointing up",
    (0, -1, 0): "y- up: stand it on its +y edge, -y pointing up",
}
_FACE_KEYS = np.array(list(FACES), dtype=float)


def up_direction(ref_g: ArrayLike) -> np.ndarray:
    """The board-frame unit vector pointing away from the Earth when the chip reads ``ref_g``.

    A chip at rest reads +1 g along up (the data sheets' orientation figures), so
    ``up = r / |r|``; vectorised over leading axes.
    """
    r = np.asarray(ref_g, dtype=float)
    return r / np.linalg.norm(r, axis=-1, keepdims=True)


def specific_force_g(attitude: ArrayLike) -> np.ndarray:
    """What an ideal chip at rest reads, in g, with board-to-world rotation ``attitude``: ``R.T @ up``."""
    return np.swapaxes(np.asarray(attitude, dtype=float), -1, -2) @ WORLD_UP


def pose_attitude(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Board-to-world rotation placing AN4399 pose (pitch, roll) physically: ``R_y(theta) R_x(phi)``.

    ``R.T @ WORLD_UP`` is Eqn 22's ``r``: a board at (0, 0) lies flat, component side up.
    """
    t, p = np.deg2rad(float(pitch_deg)), np.deg2rad(float(roll_deg))
    ry = np.array([[np.cos(t), 0.0, np.sin(t)], [0.0, 1.0, 0.0], [-np.sin(t), 0.0, np.cos(t)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), -np.sin(p)], [0.0, np.sin(p), np.cos(p)]])
    return ry @ rx


def attitude_for_up(up: ArrayLike) -> np.ndarray:
    """The smallest board-to-world rotation R with ``R @ up = WORLD_UP`` (Rodrigues)."""
    a = up_direction(up)
    k = np.cross(a, WORLD_UP)
    s, c = float(np.linalg.norm(k)), float(a @ WORLD_UP)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # flat, or a half turn about x
    k = k / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + K * s + K @ K * (1 - c)


def _signed_axes(v: np.ndarray) -> str:
    """'+x+y': the board axes a direction leans along (components over a fifth of its length)."""
    v = v / np.linalg.norm(v)
    return "".join(f"{'+' if v[i] > 0 else '-'}{'xyz'[i]}" for i in range(3) if abs(v[i]) > 0.2)


def nearest_face(direction: ArrayLike) -> str:
    """The face (of six) closest to a measured output direction (= up), in operator words."""
    d = np.asarray(direction, dtype=float)
    return FACES[tuple(int(v) for v in _FACE_KEYS[int(np.argmax(_FACE_KEYS @ d))])]


def placement_words(ref_g: ArrayLike) -> str:
    """How to place the board so a real chip reads ``ref_g``: the face whose axis points up,
    then the tilt that raises the side ``up`` leans towards (a real chip reads + on a raised axis)."""
    up = up_direction(ref_g)
    key = _FACE_KEYS[int(np.argmax(_FACE_KEYS @ up))]
    face = FACES[tuple(int(v) for v in key)]
    tilt = angle_deg(up, key)
    if tilt < 3:
        return face
    lean = up - (up @ key) * key
    side = _signed_axes(lean)
    what = "corner" if len(side) > 2 else "side"
    return f"{face}, then tilt it {tilt:.0f} deg raising its {side} {what}"


def angle_deg(a: ArrayLike, b: ArrayLike) -> float:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))

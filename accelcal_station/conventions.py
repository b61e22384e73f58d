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

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .errors import UnitsError

STANDARD_GRAVITY_MPS2 = 9.80665
UNITS = ("counts", "g", "mps2")


def an4399_reference(pitch_deg: ArrayLike, roll_deg: ArrayLike) -> np.ndarray:
    """Expected output in g for AN4399 pitch/roll (AN4399 Eqn 22); placed physically, it points up.

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

def N_(text: str) -> str:
    """Marks operator words for the gettext catalog (i18n/); this layer cannot import i18n."""
    return text


def _same(text: str) -> str:
    return text


FACES = {  # board axis pointing up (it reads +1 g) -> how to place the board, in words (English msgids)
    (0, 0, 1): N_("z+ up: lay it flat, component side up"),
    (0, 0, -1): N_("z- up: lay it flat upside down, component side down"),
    (1, 0, 0): N_("x+ up: stand it on its -x edge, +x pointing up"),
    (-1, 0, 0): N_("x- up: stand it on its +x edge, -x pointing up"),
    (0, 1, 0): N_("y+ up: stand it on its -y edge, +y pointing up"),
    (0, -1, 0): N_("y- up: stand it on its +y edge, -y pointing up"),
}
TILT_WORDS = {  # how far and which way to tilt from the face, by what the raised part is
    "corner": N_("{face}, then tilt it {tilt} deg raising its {side} corner"),
    "side": N_("{face}, then tilt it {tilt} deg raising its {side} side"),
}
_FACE_KEYS = np.array(list(FACES), dtype=float)


def _face(key: np.ndarray) -> str:
    x, y, z = (int(v) for v in key)
    return FACES[(x, y, z)]


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
    return _face(_FACE_KEYS[int(np.argmax(_FACE_KEYS @ d))])


def placement_words(ref_g: ArrayLike, tr: Callable[[str], str] = _same) -> str:
    """How to place the board so a real chip reads ``ref_g``: the face whose axis points up,
    then the tilt that raises the side ``up`` leans towards (a real chip reads + on a raised axis).

    ``tr``: the operator's language (i18n.translator); the English text is the default."""
    up = up_direction(ref_g)
    key = _FACE_KEYS[int(np.argmax(_FACE_KEYS @ up))]
    face = tr(_face(key))
    tilt = angle_deg(up, key)
    if tilt < 3:
        return face
    lean = up - (up @ key) * key
    side = _signed_axes(lean)
    what = "corner" if len(side) > 2 else "side"
    return tr(TILT_WORDS[what]).format(face=face, tilt=f"{tilt:.0f}", side=side)


def angle_deg(a: ArrayLike, b: ArrayLike) -> float:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.rad2deg(np.arccos(np.clip(c, -1.0, 1.0))))


# -- mountings: how the chip sits on the board (or the board in the jig) ---------------------
# ``device.mount: [a, b, c]`` names the chip axis (signed) lying along the board's x, y and z:
# a board-frame specific force f reads P @ f in chip axes, P's columns being those chip axes.
# Only the 24 proper rotations (signed permutations with determinant +1) are mountings.
IDENTITY_MOUNT = ("x", "y", "z")


def mount_matrix(mount: Sequence[str]) -> np.ndarray:
    """P (chip = P @ board) of a mounting such as ``["y", "-x", "z"]``; ValueError if not one of the 24."""
    if len(mount) != 3:
        raise ValueError(f"{list(mount)!r}: needs three chip axes, one along each board axis x, y, z")
    cols = []
    for a in mount:
        s = str(a).strip().lower()
        sign = -1.0 if s.startswith("-") else 1.0
        axis = s.lstrip("+-")
        if axis not in ("x", "y", "z") or len(s) - len(axis) > 1:
            raise ValueError(f"{a!r}: allowed x, y, z, each with an optional sign (+x, -y)")
        cols.append(sign * np.eye(3)[" xyz".index(axis) - 1])
    P = np.column_stack(cols)
    if round(float(np.linalg.det(P))) != 1:
        raise ValueError(f"{list(mount)!r} is not a proper rotation (each axis once, determinant +1): "
                         "a mirror-image mounting cannot be made by turning a board")
    return P


def mount_label(P: ArrayLike) -> list[str]:
    """The ``device.mount`` list of a signed permutation P (inverse of :func:`mount_matrix`)."""
    m = np.asarray(P, dtype=float)
    out = []
    for j in range(3):
        i = int(np.argmax(np.abs(m[:, j])))
        out.append(("-" if m[i, j] < 0 else "") + "xyz"[i])
    return out


def all_mounts() -> np.ndarray:
    """The 24 proper rotations among signed permutations, (24, 3, 3), the identity first."""
    from itertools import permutations, product

    out = []
    for perm in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            P[list(perm), [0, 1, 2]] = signs
            if np.linalg.det(P) > 0:
                out.append(P)
    return np.stack(out)


def mount_turn_words(P: ArrayLike) -> str:
    """'turned 90 deg about z' (P's own axis and angle), or 'not turned'."""
    m = np.asarray(P, dtype=float)
    ang = float(np.degrees(np.arccos(np.clip((np.trace(m) - 1.0) / 2.0, -1.0, 1.0))))
    if ang < 1:
        return "not turned"
    if ang > 179:
        w, v = np.linalg.eigh((m + m.T) / 2)  # a half turn: the axis is the eigenvector of +1
        axis = v[:, int(np.argmax(w))]
    else:
        axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    axis = axis / np.linalg.norm(axis)
    if axis[int(np.argmax(np.abs(axis)))] < 0:
        axis = -axis
        ang = ang if ang > 179 else -ang
    return f"turned {ang:.0f} deg about {_signed_axes(axis).lstrip('+')}"


def fit_mount(expected_board: ArrayLike, measured: ArrayLike) -> tuple[np.ndarray, float, bool]:
    """The mounting that best explains readings: (P, worst angle in deg, unique).

    ``expected_board`` (n, 3): the poses' expected outputs in board axes; ``measured`` (n, 3):
    what the chip read.  Each of the 24 mountings is scored by its worst angle between
    ``P @ expected`` and the reading; ties (one pose cannot tell a turn about its own axis)
    go to the smallest turn among those within 30 deg, and ``unique`` says no other fits within 30 deg.
    """
    r = np.asarray(expected_board, dtype=float).reshape(-1, 3)
    m = np.asarray(measured, dtype=float).reshape(-1, 3)
    mounts = all_mounts()
    pred = np.einsum("kij,nj->kni", mounts, r)
    cosang = np.sum(pred * m[None], axis=-1) / (np.linalg.norm(pred, axis=-1) * np.linalg.norm(m, axis=-1)[None])
    worst = np.degrees(np.arccos(np.clip(cosang.min(axis=1), -1.0, 1.0)))
    turn = np.arccos(np.clip((np.trace(mounts, axis1=1, axis2=2) - 1) / 2, -1, 1))
    fits = worst <= 30.0
    if fits.sum() > 1:  # the readings cannot tell these apart: the smallest turn among them
        best = int(np.flatnonzero(fits)[np.lexsort((worst[fits], np.round(turn[fits], 6)))[0]])
    else:
        best = int(np.argmin(worst))
    return mounts[best], float(worst[best]), bool(fits.sum() == 1)


def _axis_name(v: ArrayLike) -> str:
    """'+x', '-y', ...: the axis a direction lies along (within 15 deg), else its unit vector."""
    d = np.asarray(v, dtype=float)
    d = d / np.linalg.norm(d)
    i = int(np.argmax(np.abs(d)))
    if abs(d[i]) >= np.cos(np.radians(15.0)):
        return f"{'+' if d[i] > 0 else '-'}{'xyz'[i]}"
    return "(" + " ".join(f"{a} {c:+.2f}" for a, c in zip("xyz", d + 0.0, strict=True)) + ")"


def mount_hint(expected_board: ArrayLike, measured: ArrayLike, mount: ArrayLike | None = None,
               tolerance_deg: float = 15.0, key: str = "device.mount") -> str | None:
    """Name the mounting that fits the readings when it is not ``mount`` (None when ``mount`` fits
    or none of the 24 does): "reads +y where the pose expects +x: the board looks turned 90 deg
    about z; set device.mount: [y, -x, z]" (``key``: the config key that sets it, e.g. a panel
    board's ``device.boards[2].mount``)."""
    P0 = np.eye(3) if mount is None else np.asarray(mount, dtype=float)
    r = np.asarray(expected_board, dtype=float).reshape(-1, 3)
    m = np.asarray(measured, dtype=float).reshape(-1, 3)
    P, worst, unique = fit_mount(r, m)
    if worst > tolerance_deg or np.allclose(P, P0):
        return None
    wrong = [i for i in range(len(r)) if angle_deg(P0 @ r[i], m[i]) > tolerance_deg] or list(range(len(r)))
    reads = ", ".join(_axis_name(m[i]) for i in wrong)
    wants = ", ".join(_axis_name(P0 @ r[i]) for i in wrong)
    turn = mount_turn_words(P @ P0.T)
    looks = f"the board looks {turn}" if unique else f"the board looks {turn} (the smallest turn that fits)"
    return (f"reads {reads} where the pose{'s' if len(wrong) > 1 else ''} expect{'' if len(wrong) > 1 else 's'} "
            f"{wants}: {looks}; set {key}: [{', '.join(mount_label(P))}]")

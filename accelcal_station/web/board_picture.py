"""The board drawn in a pose: a box in the board's axes, placed as a real chip must be to read
the pose's expected output, seen from the front, above and to the right.

A chip at rest reads +1 g on the axis pointing away from the Earth (docs/conventions.md), so
the pose's expected output direction ``r`` points *up* the screen: the turn is the smallest
rotation taking ``r`` onto world up (conventions.attitude_for_up, Rodrigues' formula
R = I + [k]x sin t + [k]x^2 (1 - cos t)).  Faces are drawn back to front (painter's
algorithm on a convex box); the axis arrows show where x, y, z point; the gravity arrow
points down.
"""
from __future__ import annotations

from typing import TypedDict

import numpy as np

from ..conventions import WORLD_UP, attitude_for_up

HALF_MM = np.array([34.0, 22.0, 3.0])  # board half-sizes along x, y, z
VIEW_AZ_DEG, VIEW_EL_DEG = 35.0, 22.0
SCALE = 2.6
FACES = [("x+", 0, 1), ("x-", 0, -1), ("y+", 1, 1), ("y-", 1, -1), ("z+", 2, 1), ("z-", 2, -1)]


def rotation_to_up(ref_g: np.ndarray) -> np.ndarray:
    """The board's attitude for expected output ``ref_g``: the smallest R with R @ (ref/|ref|) = world up."""
    return attitude_for_up(ref_g)


def _camera() -> np.ndarray:
    """Rows: screen right, screen up, towards the viewer (world coordinates)."""
    az, el = np.radians(VIEW_AZ_DEG), np.radians(VIEW_EL_DEG)
    toward = np.array([np.cos(el) * np.sin(az), -np.cos(el) * np.cos(az), np.sin(el)])
    right = np.cross(np.array([0.0, 0.0, 1.0]), toward)
    right /= np.linalg.norm(right)
    up = np.cross(toward, right)
    return np.vstack([right, up, toward])


def _xy(cam: np.ndarray, p: np.ndarray, cx: float, cy: float) -> tuple[float, float]:
    v = cam @ p
    return cx + SCALE * float(v[0]), cy - SCALE * float(v[1])


class Face(TypedDict):
    """A visible face: its name (x+ ...), depth towards the viewer, shade and SVG polygon points."""

    face: str
    depth: float
    shade: float
    points: str


class Line(TypedDict):
    """An arrow from (x1, y1) to (x2, y2) in the viewBox."""

    x1: float
    y1: float
    x2: float
    y2: float


class Arrow(Line):
    """An axis arrow; ``front``: its tip is on the viewer's side."""

    axis: str
    front: bool


class Picture(TypedDict):
    """The board in a pose as the page draws it (SVG in a ``size`` square viewBox)."""

    size: float
    faces: list[Face]
    arrows: list[Arrow]
    gravity: Line
    ground_y: float


def picture(ref_g: np.ndarray, size: float = 320.0) -> Picture:
    """Polygons (faces, back to front) and arrows (axes, gravity) in a ``size`` square viewBox."""
    R, cam = rotation_to_up(ref_g), _camera()
    cx = cy = size / 2
    faces: list[Face] = []
    lowest = cy
    for face, axis, sign in FACES:
        normal = np.zeros(3)
        normal[axis] = sign
        n_world = R @ normal
        depth = float(cam[2] @ n_world)
        if depth <= 1e-6:
            continue  # facing away
        others = [i for i in range(3) if i != axis]
        corners = []
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = normal * HALF_MM
            p[others[0]] = su * HALF_MM[others[0]]
            p[others[1]] = sv * HALF_MM[others[1]]
            corners.append(_xy(cam, R @ p, cx, cy))
            lowest = max(lowest, corners[-1][1])
        faces.append({"face": face, "depth": depth, "shade": round(0.55 + 0.45 * depth, 3),
                      "points": " ".join(f"{x:.1f},{y:.1f}" for x, y in corners)})
    faces.sort(key=lambda f: f["depth"])
    arrows: list[Arrow] = []
    for i, name in enumerate("xyz"):
        tip = R @ (np.eye(3)[i] * (HALF_MM[i] + 26.0))
        x1, y1 = _xy(cam, np.zeros(3), cx, cy)
        x2, y2 = _xy(cam, tip, cx, cy)
        arrows.append({"axis": name, "x1": x1, "y1": y1, "x2": x2, "y2": y2,
                       "front": bool(cam[2] @ tip >= -1e-9)})
    gx, gy1 = size - 26.0, 40.0
    return {"size": size, "faces": faces, "arrows": arrows,
            "gravity": {"x1": gx, "y1": gy1, "x2": gx, "y2": gy1 + 70.0},
            "ground_y": lowest + 6}


def level_xy(reading_g: np.ndarray, ref_g: np.ndarray, full_scale_deg: float = 30.0) -> tuple[float, float]:
    """Where the bubble sits, seen from above as the picture is: a bubble floats to the high side.

    The reading is the board's true up (a chip reads +1 g on the axis pointing up), so its part
    ``d`` across the pose's ``r`` is the side raised too high; turned into the world with the
    picture's attitude it points, on the level, towards that side as the picture shows it
    (x: screen right, y: away from the viewer), scaled so ``full_scale_deg`` reaches the rim.
    """
    r = np.asarray(ref_g, dtype=float) / np.linalg.norm(ref_g)
    g = np.asarray(reading_g, dtype=float)
    g = g / max(float(np.linalg.norm(g)), 1e-12)
    d = g - (g @ r) * r  # the part of the reading across the pose's direction
    if np.linalg.norm(d) < 1e-12:
        return 0.0, 0.0
    ang = float(np.degrees(np.arctan2(np.linalg.norm(d), g @ r)))
    right = _camera()[0]  # horizontal (camera right is perpendicular to world up)
    away = np.cross(WORLD_UP, right)
    w = rotation_to_up(r) @ d
    frac = min(ang / full_scale_deg, 1.0) / float(np.linalg.norm(d))
    return float(w @ right) * frac, float(w @ away) * frac

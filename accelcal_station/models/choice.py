"""The default model, chosen from the data: the richest model the poses determine, and why.

  references present   15 when its cubic is determined (at every calibration temperature), else 12
  no references        the hand-placed faces' norm fit when every pose is an axis-up face
                       (within FACE_TOL_DEG) and all six faces are present: faces alone determine
                       no non-orthogonality (each would rest on placement errors), so model 9
                       would have to hold all three at 0, which is that fit (models/handplaced.py);
                       else 9 when determined, holding weak non-orthogonalities (models/held.py);
                       else a refusal naming the poses to add

FACE_TOL_DEG is 15 degrees: a board laid by hand on a bench face is a few degrees off
(imucal's session: under 2 degrees); a tilt meant to determine cross terms is 30 degrees
or more away from every axis (45 in the nine-position designs), so the two cannot mix.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TypedDict

import numpy as np

from ..errors import UnderdeterminedError
from ..identifiability import assess
from ..session import Session
from .gravity_norm import nominal_scale
from .held import Held, hold_plan

FACE_TOL_DEG = 15.0
AXES = "xyz"


class ModelChoiceJson(TypedDict):
    """The model fit chose as JSON: how, why, and the terms it holds at nominal."""

    model: str
    method: str
    reason: str
    held: list[str]


@dataclass(frozen=True)
class Faces:
    """Every pose taken as the axis-up face it lies nearest: references (P, 3) (the face's axis,
    signed as the reading), face names ("+x", ...) and each pose's angle from its face (deg)."""

    references_g: np.ndarray
    names: list[str]
    angle_deg: np.ndarray

    @property
    def text(self) -> str:
        return (f"six faces placed by hand (every static interval within {FACE_TOL_DEG:g} deg of an axis-up "
                f"face, largest {float(np.max(self.angle_deg)):.1f} deg)")


@dataclass(frozen=True)
class ModelChoice:
    """The model chosen and why; ``faces`` when it is the hand-placed norm fit on model 6's layout."""

    model: str
    reason: str
    faces: Faces | None = None
    held: list[Held] = field(default_factory=list)

    @property
    def method(self) -> str:
        return "hand-placed norm fit" if self.faces is not None else f"model {self.model}"

    def to_json(self) -> ModelChoiceJson:
        return {"model": self.model, "method": self.method, "reason": self.reason,
                "held": [h.term for h in self.held]}


def _scale(session: Session) -> float:
    """Input units per g: the session's, or the readings' own radius when it has none."""
    x = session.readings
    if session.units == "counts" and session.counts_per_g is None:
        return float(nominal_scale(x[None])[0])
    return float(session.input_per_g)


def _unit_readings(session: Session) -> np.ndarray:
    """Readings in about g (the session's scale, or the readings' own radius when it has none)."""
    return session.readings / _scale(session)


def axis_faces(session: Session, tol_deg: float = FACE_TOL_DEG) -> Faces | None:
    """The faces of a session whose every pose is within ``tol_deg`` of an axis and which has all six."""
    g = _unit_readings(session)
    if len(g) < 6:
        return None
    u = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    ax = np.argmax(np.abs(u), axis=1)
    on = np.abs(u[np.arange(len(u)), ax])
    angle = np.degrees(np.arccos(np.clip(on, -1.0, 1.0)))
    sign = np.sign(u[np.arange(len(u)), ax])
    if np.any(angle > tol_deg) or len({(int(a), float(s)) for a, s in zip(ax, sign, strict=True)}) < 6:
        return None
    ref = np.zeros_like(g)
    ref[np.arange(len(g)), ax] = sign
    names = [f"{'+' if s > 0 else '-'}{AXES[a]}" for a, s in zip(ax, sign, strict=True)]
    return Faces(ref, names, angle)


def with_face_references(session: Session, faces: Faces) -> Session:
    """The session with each pose's face as its reference (the hand-placed norm fit's input)."""
    k = session.site_gravity_g  # the faces are unit vectors: scaled to the site's gravity as every reference
    poses = [replace(p, reference_g=r * k) for p, r in zip(session.poses, faces.references_g, strict=True)]
    return Session(poses, session.units, session.counts_per_g, session.gravity_mps2, session.device,
                   dict(session.metadata))


def _with_references(session: Session) -> ModelChoice:
    groups = session.by_temperature() if all(p.temp_c is not None for p in session.poses) else [(None, session)]
    fifteen = all(assess(sub.readings_g(), "15").determined for _, sub in groups)
    if fifteen:
        return ModelChoice("15", "references present and the poses determine the cubic: model 15 "
                                 "(full W, offset, cubic)")
    return ModelChoice("12", "references present; model 15's cubic is not determined by these poses "
                             f"({assess(groups[0][1].readings_g(), '15').reason}): model 12 (full W, offset)")


def choose_model(session: Session) -> ModelChoice:
    """The richest model the poses determine (module doc); raises UnderdeterminedError naming poses to add."""
    if session.has_references:
        return _with_references(session)
    faces = axis_faces(session)
    if faces is not None:
        return ModelChoice("6", "no references and every pose an axis-up face: gain and offset per axis by the "
                                "gravity norm", faces)
    scale = _scale(session)
    noise = session.noise()
    try:
        held = hold_plan(session.readings / scale, "9", None if noise is None else noise / scale)
    except UnderdeterminedError as e:
        raise UnderdeterminedError(
            f"no model is determined: model 9 (no references): {e}; or place the board on all six faces "
            f"(each axis up and down, within {FACE_TOL_DEG:g} deg) for the hand-placed norm fit") from None
    why = "no references; the poses determine the 9-parameter norm model"
    if held:
        why += " with " + ", ".join(h.term for h in held) + " held at 0"
    return ModelChoice("9", why, None, held)


__all__ = ["FACE_TOL_DEG", "Faces", "ModelChoice", "axis_faces", "choose_model", "with_face_references"]

"""The default model, chosen from the data: the richest model the poses determine, and why.

  references present   15 when the references determine its cubic (at every calibration
                       temperature) and its leave-one-orientation-out residual is not far worse than
                       model 12's: not beyond the held-out figures' own scatter (crossval.compare_held_out)
                       nor above FAR_RATIO times it; else 12
  no references        the hand-placed faces' norm fit when every pose is an axis-up face
                       (within FACE_TOL_DEG) and all six faces are present: faces alone determine
                       no non-orthogonality (each would rest on placement errors), so model 9
                       would have to hold all three at 0, which is that fit (models/handplaced.py);
                       else 9 when determined, holding weak non-orthogonalities (models/held.py);
                       else a refusal naming the poses to add

What a design determines is judged from the references, never from the readings: an offset
moves the readings off +-1 g and 0 (six faces of a board whose z reads +0.77 / -1.27 g), which
makes 1, g_z and g_z^3 formally independent although the poses are the same six faces, whose
references cannot tell a cubic from the gain (the fit's cubic would rest on the offset alone and
its held-out error is then hundreds of mg).  Without references the faces are judged on the
readings less the mid-range of each axis (the offset's estimate when both faces of every axis are
present), so an offset does not move a face out of FACE_TOL_DEG.

FACE_TOL_DEG is 15 degrees: a board laid by hand on a bench face is a few degrees off
(imucal's session: under 2 degrees); a tilt meant to determine cross terms is 30 degrees
or more away from every axis (45 in the nine-position designs), so the two cannot mix.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NotRequired, TypedDict

import numpy as np

from ..errors import AccelcalError, UnderdeterminedError
from ..identifiability import assess, first_of_orientation
from ..session import Session
from .crossval import MAX_FOLDS, MAX_POSES, HeldOutComparison, compare_held_out, held_out_by_orientation
from .fitting import _failed, fit_batch
from .gravity_norm import nominal_scale
from .held import Held, hold_plan
from .result import BatchFit

FACE_TOL_DEG = 15.0
AXES = "xyz"


class ComparedJson(TypedDict):
    """The held-out comparison behind a choice between a simpler and a richer model (crossval.py)."""

    simpler: str
    richer: str
    simpler_rms_g: float | None
    richer_rms_g: float | None
    mean_excess_g2: float | None
    excess_se_g2: float | None
    orientations: int
    richer_worse: bool


class ModelChoiceJson(TypedDict):
    """The model fit chose as JSON: how, why, and the terms it holds at nominal; ``judged_on`` what
    the design was judged from ("references", "readings less the estimated offset", ...)."""

    model: str
    method: str
    reason: str
    held: list[str]
    judged_on: NotRequired[str]
    compared: NotRequired[ComparedJson]


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
    judged_on: str = ""
    compared: HeldOutComparison | None = None  # model 15 against 12 (``simpler``/``richer`` below)
    simpler: str = "12"
    richer: str = "15"

    @property
    def method(self) -> str:
        return "hand-placed norm fit" if self.faces is not None else f"model {self.model}"

    def to_json(self) -> ModelChoiceJson:
        out: ModelChoiceJson = {"model": self.model, "method": self.method, "reason": self.reason,
                                "held": [h.term for h in self.held]}
        if self.judged_on:
            out["judged_on"] = self.judged_on
        c = self.compared
        if c is not None:
            def num(v: float) -> float | None:
                return v if np.isfinite(v) else None

            out["compared"] = {"simpler": self.simpler, "richer": self.richer, "simpler_rms_g": num(c.rms_a_g),
                               "richer_rms_g": num(c.rms_b_g), "mean_excess_g2": num(c.diff_g2),
                               "excess_se_g2": num(c.se_g2), "orientations": c.orientations,
                               "richer_worse": c.b_worse}
        return out


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
    g = g - 0.5 * (g.max(axis=0) + g.min(axis=0))  # less the offset's estimate (module doc)
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


REFERENCES = "references"
# a richer model more than this many times a simpler one's held-out RMS is far worse: the terms it adds,
# if real, lower it; if absent, leave-one-out inflates it by 1/sqrt(1 - h), h the left-out pose's
# leverage, about 1.15 times more for model 15 than for 12 on eight orientations (5/8 against 4/8)
FAR_RATIO = 2.0
ESTIMATED = "readings less the offset's estimate (each axis's mid-range)"


def _fold_fits(session: Session, model: str) -> np.ndarray:
    """(K,) squared held-out residual of each distinct orientation of ``session`` left out of
    ``model``'s fit (crossval.held_out_by_orientation; NaN where a fold is not determined)."""
    x = session.readings[None]
    ref = np.asarray(session.references_g, dtype=float)[None]
    nz = session.noise()
    noise = None if nz is None else nz[None]
    gf = x / _scale(session)

    def fold(rows: np.ndarray, keep: np.ndarray) -> BatchFit:
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                return fit_batch(x[:, keep], ref[:, keep], model, units=session.units,
                                 counts_per_g=session.counts_per_g, gravity_mps2=session.gravity_mps2,
                                 noise=None if noise is None else noise[:, keep], workers=1)
        except (AccelcalError, np.linalg.LinAlgError):
            return _failed(len(rows))

    return held_out_by_orientation(gf, ref, fold)[0][0]


def compare_models(session: Session, simpler: str, richer: str) -> HeldOutComparison:
    """``richer`` against ``simpler`` on the same held-out orientations of a session with references
    (pooled over its calibration temperatures)."""
    groups = session.by_temperature() if all(p.temp_c is not None for p in session.poses) else [(None, session)]
    sq_a = np.concatenate([_fold_fits(sub, simpler) for _, sub in groups])
    sq_b = np.concatenate([_fold_fits(sub, richer) for _, sub in groups])
    return compare_held_out(sq_a, sq_b, 3 * len(session))


def _with_references(session: Session) -> ModelChoice:
    groups = session.by_temperature() if all(p.temp_c is not None for p in session.poses) else [(None, session)]
    refs = [np.asarray(sub.references_g, dtype=float) for _, sub in groups]
    judged = [assess(r, "15") for r in refs]
    if not all(j.determined for j in judged):
        why = next(j.reason for j in judged if not j.determined).replace("every reading", "every reference")
        return ModelChoice("12", "references present; the references do not determine model 15's cubic "
                                 f"({why}): model 12 (full W, offset)", judged_on=REFERENCES)
    distinct = int(first_of_orientation(session.readings_g()[None])[0].sum())
    if len(session) > MAX_POSES or distinct > MAX_FOLDS:  # one fit per orientation, the pairs' cosines held at once
        return ModelChoice("15", "references present and they determine the cubic: model 15 (full W, offset, cubic; "
                                 f"{len(session)} poses in {distinct} orientations: not compared with model 12 "
                                 "held out, "
                                 f"which takes at most {MAX_POSES} poses and {MAX_FOLDS} orientations)",
                           judged_on=REFERENCES)
    c = compare_models(session, "12", "15")
    if c.b_far_worse(FAR_RATIO):
        how = "beyond the orientations' scatter" if c.b_worse else f"more than {FAR_RATIO:g} times"
        return ModelChoice("12", "references present and they determine the cubic, but model 15 is worse held out "
                                 f"than model 12 {how} ({c.text}, against model 12's): "
                                 "model 12 (full W, offset)", judged_on=REFERENCES, compared=c)
    return ModelChoice("15", "references present and they determine the cubic: model 15 (full W, offset, cubic; "
                             f"held out {c.text.split(' against ')[0]}, model 12 "
                             f"{c.rms_a_g * 1e3:.3f} mg)", judged_on=REFERENCES, compared=c)


def choose_model(session: Session) -> ModelChoice:
    """The richest model the poses determine (module doc); raises UnderdeterminedError naming poses to add."""
    if session.has_references:
        return _with_references(session)
    faces = axis_faces(session)
    if faces is not None:
        return ModelChoice("6", "no references and every pose an axis-up face: gain and offset per axis by the "
                                "gravity norm", faces, judged_on=ESTIMATED)
    scale = _scale(session)
    noise = session.noise()
    try:
        held = hold_plan(session.readings / scale, "9", None if noise is None else noise / scale, confirm=True)
    except UnderdeterminedError as e:
        raise UnderdeterminedError(
            f"no model is determined: model 9 (no references): {e}; or place the board on all six faces "
            f"(each axis up and down, within {FACE_TOL_DEG:g} deg) for the hand-placed norm fit") from None
    why = "no references; the poses determine the 9-parameter norm model"
    if held:
        why += " with " + ", ".join(h.term for h in held) + " held at 0"
    return ModelChoice("9", why, None, held, judged_on="readings (the norm model's directions)")


__all__ = ["FACE_TOL_DEG", "ComparedJson", "Faces", "ModelChoice", "ModelChoiceJson", "axis_faces", "choose_model",
           "compare_models", "with_face_references"]

"""Fit what the poses determine, hold the rest at nominal, and say so.

Model 9's design (identifiability.py: the norm model linearised at M = I, B = 0, one column
per parameter over the distinct orientations; the columns are functions of unit directions,
all of order 1, and are compared unnormalised here, since normalising would blow a column
that is zero but for placement noise up to full size) can leave one direction
weak while the others are well determined: six faces plus tilts only in the x-z and y-z
planes give ``2 u_x u_y = 0`` at every pose, so the x-y non-orthogonality M_xy is not seen
by any reading.  Fitting it freely invents a value from noise; refusing the log throws
away well-determined gains and offsets.  So the weak direction is held at its nominal
value (M_xy = 0, a constrained solve), named in words, and given zero variance.

Rule (``hold_plan``): while the smallest relative singular value of the free columns is
below ``identifiability.REL_SV_MIN`` (0.05: that direction's standard error is more than
20 times the best-determined one's, so noise is amplified 20-fold into it), take its
singular vector; when the largest component is a non-orthogonality term, hold that term
and look again.  When the weak direction is led by a gain (M_xx..M_zz) or an offset
(B_x..B_z) the model is refused: those have no nominal value a calibration could keep.
Holding all three non-orthogonalities leaves a diagonal M: that is the hand-placed faces'
norm fit (models/handplaced.py), which the caller uses instead.

Model 15 whose cubic the poses cannot tell from the gain (every reading about +-1 g or 0)
while model 12 is determined: the three cubic terms are held at 0 (the fit is model 12's,
stated as model 15 with Gamma = 0 and zero variance).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UnderdeterminedError
from ..identifiability import REL_SV_MIN, _design, assess, first_of_orientation
from .gravity_norm import PARAM_NAMES
from .linear import param_names
from .result import BatchFit

AXES = "xyz"
# parameter index -> (axes in words, the pose that determines it)
HOLDABLE_9 = {3: ("x", "y"), 4: ("x", "z"), 5: ("y", "z")}


@dataclass(frozen=True)
class Held:
    """A term fitted at its nominal value because the poses do not determine it."""

    term: str  # parameter name, e.g. "M_xy"
    value: float  # the nominal value it is held at
    reason: str
    hint: str

    @property
    def text(self) -> str:
        return f"{self.reason}; {self.hint}"

    def to_json(self) -> dict[str, object]:
        return {"term": self.term, "value": self.value, "reason": self.reason, "hint": self.hint}


def _held_9(k: int) -> Held:
    a, b = HOLDABLE_9[k]
    return Held(PARAM_NAMES[k], 0.0, f"{a}-{b} non-orthogonality held at 0: no pose tilts {a} and {b} together",
                f"add a pose between +{a} and +{b} to determine it")


FACES_ONLY = ("every pose is an axis-up face, so no pose determines any non-orthogonality of model 9: "
              "fit with no --model for the hand-placed faces' norm fit, or add tilted poses")


def _held_cubic(axis: str, why: str) -> Held:
    return Held(f"Gamma_{axis}{axis}", 0.0, f"{axis} cubic held at 0: {why.split(';')[0]}",
                "add intermediate tilts (e.g. the an4399-8 design) to determine it")


def cubic_held(res: BatchFit, held: list[Held]) -> BatchFit:
    """A model-12 fit stated as model 15 with every cubic held at 0 (zero value, zero variance)."""
    D = len(res)
    res.model = "15"
    res.params = np.concatenate([res.params, np.zeros((D, 3))], axis=1)
    res.param_names = param_names("15")
    if isinstance(res.covariance, np.ndarray) and res.covariance.ndim == 4:  # (D, 3, 4, 4) per channel
        cov = np.zeros(res.covariance.shape[:2] + (5, 5))
        cov[..., :4, :4] = res.covariance
        res.covariance = cov
    res.held = list(held)
    return res


def _weakest(Xn: np.ndarray, free: np.ndarray) -> tuple[float, np.ndarray]:
    """Smallest relative singular value of the free columns and its singular vector (over all 9)."""
    _, s, vt = np.linalg.svd(Xn[:, free], full_matrices=False)
    v = np.zeros(Xn.shape[1])
    v[free] = vt[-1]
    return float(s[-1] / max(s[0], 1e-300)), v


def hold_plan(gf: np.ndarray, model: str) -> list[Held]:
    """The terms of ``model`` to hold at nominal for readings ``gf`` (P, 3) in about g (module doc).

    Empty when the model is determined as it is; raises UnderdeterminedError (the
    identifiability reason) when a gain or offset is weak or holding cannot help.
    """
    ident = assess(gf, model)
    if model == "15" and not ident.determined and assess(gf, "12").determined:
        return [_held_cubic(a, ident.reason) for a in AXES]
    if model != "9":
        if ident.determined:
            return []
        raise UnderdeterminedError(ident.reason)
    first = first_of_orientation(gf[None])[0]
    X = _design(gf[None], "9")[0, 0][first]  # unit directions: every column on one scale, left unnormalised
    free = np.ones(9, dtype=bool)
    held: list[Held] = []
    while True:
        if len(X) < free.sum():  # fewer distinct orientations than free parameters
            raise UnderdeterminedError(ident.reason)
        rel, v = _weakest(X, free)
        if rel >= REL_SV_MIN:
            break
        k = int(np.argmax(np.abs(v)))
        if k not in HOLDABLE_9:
            raise UnderdeterminedError(ident.reason)
        if len(held) == 2:
            raise UnderdeterminedError(FACES_ONLY)
        free[k] = False
        held.append(_held_9(k))
    if not held and not ident.determined:
        raise UnderdeterminedError(ident.reason)
    return held


def free_mask(held: list[Held], names: list[str]) -> np.ndarray:
    """(k,) bool: the parameters fitted (not held)."""
    terms = {h.term for h in held}
    return np.array([n not in terms for n in names])


__all__ = ["HOLDABLE_9", "Held", "cubic_held", "free_mask", "hold_plan"]

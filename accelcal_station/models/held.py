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

Rule (``hold_plans``, vectorised over boards; ``hold_plan`` one board): while the smallest
relative singular value of the free columns is below ``identifiability.REL_SV_MIN`` (0.05:
that direction's standard error is more than 20 times the best-determined one's, so noise is
amplified 20-fold into it), take its singular vector; when the largest component is a non-
orthogonality term, hold that term and look again. When the weak direction is led by a gain
(M_xx..M_zz) or an offset (B_x..B_z) the model is refused: those have no nominal value a
calibration could keep. Holding all three non-orthogonalities leaves a diagonal M: that is
the hand-placed faces' norm fit (models/handplaced.py), which the caller uses instead.

Model 15 whose cubic the poses cannot tell from the gain (every reading about +-1 g or 0)
while model 12 is determined: the three cubic terms are held at 0 (the fit is model 12's,
stated as model 15 with Gamma = 0 and zero variance).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from ..errors import UnderdeterminedError
from ..identifiability import REL_SV_MIN, _design, assess, assess_batch, first_of_orientation
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


@cache  # frozen: one instance per term serves every board of a lot
def _held_9(k: int) -> Held:
    a, b = HOLDABLE_9[k]
    return Held(PARAM_NAMES[k], 0.0, f"{a}-{b} non-orthogonality held at 0: no pose tilts {a} and {b} together",
                f"add a pose between +{a} and +{b} to determine it")


FACES_ONLY = ("every pose is an axis-up face, so no pose determines any non-orthogonality of model 9: "
              "fit with no --model for the hand-placed faces' norm fit, or add tilted poses")


def _held_cubic(axis: str, why: str) -> Held:
    return Held(f"Gamma_{axis}{axis}", 0.0, f"{axis} cubic held at 0: {why.split(';')[0]}",
                "add intermediate tilts (e.g. the an4399-8 design) to determine it")


def cubic_held(res: BatchFit, held: list[list[Held]]) -> BatchFit:
    """A model-12 fit of D boards stated as model 15 with every cubic held at 0 (zero value,
    zero variance); ``held`` the terms of each board."""
    D = len(res)
    res.model = "15"
    res.params = np.concatenate([res.params, np.zeros((D, 3))], axis=1)
    res.param_names = param_names("15")
    c12 = np.asarray(res.covariance[np.arange(D)])  # (D, 3, 4, 4) per channel (formed if lazy)
    cov = np.zeros(c12.shape[:2] + (5, 5))
    cov[..., :4, :4] = c12
    res.covariance = cov
    res.held = [list(h) for h in held]
    return res


@dataclass
class HoldPlan:
    """The decision for D boards (``hold_plans``): the terms each holds, or why it is refused."""

    held: list[list[Held]]  # (D,) terms held at nominal ([] when the model is determined as it is)
    refused: list[str]  # (D,) "" or the reason the board cannot be fitted with this model

    def free(self, names: list[str]) -> np.ndarray:
        """(D, k) bool: the parameters fitted (not held) of each board."""
        masks: dict[tuple[str, ...], np.ndarray] = {}  # a lot has one or a few distinct held sets
        for h in self.held:
            key = tuple(t.term for t in h)
            if key not in masks:
                masks[key] = free_mask(h, names)
        return np.array([masks[tuple(t.term for t in h)] for h in self.held]).reshape(len(self.held), len(names))


def _plan9(gf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The held columns of model 9, in the order chosen ((D, 2) int, -1 none), and a refusal
    code (D,) int (0 fitted, 1 the identifiability reason, 2 FACES_ONLY): the module doc's
    rule for D boards at once.

    Each board's Gram matrix G = X^T X of the unnormalised design over its distinct orientations
    is formed once; a held term's row and column are zeroed and its diagonal set to the mean free
    diagonal (as stacked_norm._held does), which lies between the free block's extreme
    eigenvalues and so leaves them, the free block's singular values squared, unchanged:
    one 9 x 9 symmetric eigenproblem per board and round (np.linalg.eigh, far cheaper than an
    SVD of the design) gives the weakest free direction and the largest singular value."""
    D = len(gf)
    first = first_of_orientation(gf)
    X = _design(gf, "9")[:, 0] * first[..., None]  # repeats zeroed: distinct orientations only
    G = np.einsum("dpi,dpj->dij", X, X)
    distinct = first.sum(axis=1)
    free = np.ones((D, 9))
    order = np.full((D, 2), -1)
    code = (distinct < 9).astype(int)  # fewer distinct orientations than parameters: refused
    active = np.flatnonzero(code == 0)
    for nh in range(3):  # every active board has nh terms held
        if not active.size:
            break
        f = free[active]
        Ga = G[active] * f[:, :, None] * f[:, None, :]
        fill = np.einsum("dkk->d", Ga) / f.sum(axis=1)
        Ga[:, np.arange(9), np.arange(9)] += (1.0 - f) * fill[:, None]
        w, V = np.linalg.eigh(Ga)  # ascending
        rel = np.sqrt(np.maximum(w[:, 0], 0.0) / np.maximum(w[:, -1], 1e-300))
        k = np.argmax(np.abs(V[:, :, 0]), axis=1)
        weak = rel < REL_SV_MIN
        holdable = np.isin(k, list(HOLDABLE_9))
        code[active[weak & ~holdable]] = 1
        if nh == 2:
            code[active[weak & holdable]] = 2
            break
        step = weak & holdable
        order[active[step], nh] = k[step]
        free[active[step], k[step]] = 0.0
        active = active[step]
    return order, code


def hold_plans(gf: np.ndarray, model: str) -> HoldPlan:
    """The terms of ``model`` to hold at nominal for each of D boards' readings ``gf`` (D, P, 3)
    in about g (module doc), vectorised over boards: the one decision of the one-board fit,
    `accelcal batch` and lot files.  A board whose gain or offset is weak, or that holding
    cannot help, is refused with the identifiability reason."""
    gf = np.asarray(gf, dtype=float)
    D = len(gf)
    determined, _ = assess_batch(gf, model)
    held: list[list[Held]] = [[]] * D  # shared empty list: a board's terms replace it, never appended
    refused = [""] * D
    und = np.flatnonzero(~determined)
    if not und.size:
        return HoldPlan(held, refused)
    if model == "15":
        twelve, _ = assess_batch(gf[und], "12")
        for d, ok12 in zip(und, twelve, strict=True):
            why = assess(gf[d], model).reason
            if ok12:
                held[d] = [_held_cubic(a, why) for a in AXES]
            else:
                refused[d] = why
        return HoldPlan(held, refused)
    if model != "9":
        for d in und:
            refused[d] = assess(gf[d], model).reason
        return HoldPlan(held, refused)
    order, code = _plan9(gf[und])
    for i, d in enumerate(und):
        if code[i] == 1 or order[i, 0] < 0:  # a weak gain or offset, or nothing holding could help
            refused[d] = assess(gf[d], model).reason
        elif code[i] == 2:
            refused[d] = FACES_ONLY
        else:
            held[d] = [_held_9(int(k)) for k in order[i] if k >= 0]
    return HoldPlan(held, refused)


def hold_plan(gf: np.ndarray, model: str) -> list[Held]:
    """One board's ``hold_plans``: the terms to hold for readings ``gf`` (P, 3); raises
    UnderdeterminedError with the reason when the board is refused."""
    plan = hold_plans(np.asarray(gf, dtype=float)[None], model)
    if plan.refused[0]:
        raise UnderdeterminedError(plan.refused[0])
    return list(plan.held[0])  # its own list (the plan shares one empty list among boards)


def free_mask(held: list[Held], names: list[str]) -> np.ndarray:
    """(k,) bool: the parameters fitted (not held)."""
    terms = {h.term for h in held}
    return np.array([n not in terms for n in names])


__all__ = ["HOLDABLE_9", "Held", "HoldPlan", "cubic_held", "free_mask", "hold_plan", "hold_plans"]

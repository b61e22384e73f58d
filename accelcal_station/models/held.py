"""Fit what the data determine, hold the rest at nominal, and say so.

Model 9's design (identifiability.py: the norm model linearised at M = I, B = 0, one column
per parameter; the columns are functions of unit directions, all of order 1) can leave one
direction weak while the others are well determined: six faces plus tilts only in the x-z and
y-z planes give ``2 u_x u_y ~ 0`` at every pose, so the x-y non-orthogonality M_xy is seen only
through the few degrees the tilts happen to lean out of their planes.  Whether that is enough
depends on the noise, not on the geometry alone: at 0.1 mg per pose mean a 0.02 relative
singular value still pins M_xy to a few 1e-3, at 20 times that noise it does not.

Rule (``hold_plans``, vectorised over boards; ``hold_plan`` one board), per board and per
non-orthogonality term k (M_xy, M_xz, M_yz):

  se_k = sqrt([(J^T S^-1 J)^-1]_kk)      the term's predicted standard error at the data's noise
                                          (J the linearised design over every pose, S = diag
                                          sigma_p^2, sigma_p the noise of pose p's norm: the
                                          per-pose std / sqrt(n) given in the data projected on
                                          the pose's direction, else the residual scatter of the
                                          geometric plan's fit, RSS / (P - free terms))
  held at 0  when se_k >= PRIOR_SD_NONORTHO (0.02)

0.02 is the data-sheet spread of the term: cross-axis sensitivity is +-1 % (MMA8451Q) to
+-2 % (MPU-6050 product specification, "Cross-Axis Sensitivity +-2 %"), taken as one sigma of
the prior.  A term the data cannot pin down better than the prior would be fitted to noise and
move the calibration more than setting it to its nominal 0 does, so it is held; one they can,
is fitted freely (the posterior of a Gaussian prior with se_k << 0.02 is the free fit).  The
worst term (largest se_k / prior) is held first and the others judged again without it, as
holding one changes the others' standard errors.

The noise rule is a proposal, checked by held-out data (``confirm_holds``): for a term held by it
with se_k below CONFIRM_SE_MAX (twice the prior), the fits with the term held and free are each
left out one distinct orientation at a time (crossval.held_out_by_orientation); where holding is
worse beyond the orientations' own scatter (crossval.compare_held_out: the mean excess squared
residual above 2.5 standard errors, every free fold computable) the term is fitted freely and
reported in ``freed`` with the figures (docs/fit-decisions.md).

Refusals stay geometric: fewer than nine distinct orientations, or a weak direction
(relative singular value below ``identifiability.REL_SV_MIN`` of the distinct orientations'
design, unnormalised: normalising would blow a column that is zero but for placement noise up
to full size) led by a gain (M_xx..M_zz) or an offset (B_x..B_z), which have no nominal value
a calibration could keep; every pose an axis-up face gives FACES_ONLY (the hand-placed norm
fit, models/handplaced.py, is that fit).  A pose table with neither std/n nor spare poses gives
no noise to judge by: the geometric plan (hold while the weak direction is a
non-orthogonality) is used and said so.

Model 15 whose cubic the poses cannot tell from the gain (every reading about +-1 g or 0)
while model 12 is determined: the three cubic terms are held at 0 (the fit is model 12's,
stated as model 15 with Gamma = 0 and zero variance).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np

from ..errors import UnderdeterminedError
from ..identifiability import REL_SV_MIN, _centre, _design, assess, assess_batch, distinct_count, first_of_orientation
from .crossval import (
    MAX_FOLDS,
    MAX_POSES,
    FoldFit,
    HeldOutComparison,
    compare_held_out,
    held_out_by_orientation,
    orientation_labels,
)
from .gravity_norm import PARAM_NAMES
from .linear import param_names
from .result import BatchFit, Held  # Held: a fit result's record, re-exported here
from .stacked import fit_stacked

AXES = "xyz"
# parameter index -> (axes in words, the pose that determines it)
HOLDABLE_9 = {3: ("x", "y"), 4: ("x", "z"), 5: ("y", "z")}


PRIOR_SD_NONORTHO = 0.02  # one sigma of a non-orthogonality before the data: data-sheet cross-axis spread
TOGETHER_MIN = 0.1  # |2 u_a u_b| below this at every pose (about 3 deg): "no pose tilts a and b together"


@cache  # frozen: one instance per term serves every board of a lot (the geometric plan)
def _held_9(k: int) -> Held:
    a, b = HOLDABLE_9[k]
    return Held(PARAM_NAMES[k], 0.0, f"{a}-{b} non-orthogonality held at 0: no pose tilts {a} and {b} together",
                f"add a pose between +{a} and +{b} to determine it")


def _held_noise(k: int, se: float, together: float) -> Held:
    """Term k held by the noise rule (module doc): its predicted standard error ``se`` is not below
    the prior; ``together`` the largest |2 u_a u_b| over the poses."""
    a, b = HOLDABLE_9[k]
    why = f"no pose tilts {a} and {b} together" if together < TOGETHER_MIN else \
        f"the poses tilt {a} and {b} together too little for their noise"
    sd = "not determined at all" if not np.isfinite(se) else f"+-{se:.2g}"
    return Held(PARAM_NAMES[k], 0.0, f"{a}-{b} non-orthogonality held at 0: {why} (standard error at the data's "
                                     f"noise {sd}, not below its prior +-{PRIOR_SD_NONORTHO:g})",
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
    """The decision for D boards (``hold_plans``): the terms each holds, or why it is refused;
    ``se``: each board's noise-rule standard error of every term it holds by that rule; ``freed``:
    terms the noise rule proposed to hold that the held-out data overruled (``confirm_holds``)."""

    held: list[list[Held]]  # (D,) terms held at nominal ([] when the model is determined as it is)
    refused: list[str]  # (D,) "" or the reason the board cannot be fitted with this model
    se: list[dict[str, float]] = field(default_factory=list)  # (D,) or [] (no noise-rule hold)
    freed: list[list[Held]] = field(default_factory=list)  # (D,) or []

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
    distinct = distinct_count(first)
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


def norm_sigma_g(gf: np.ndarray, noise_g: np.ndarray) -> np.ndarray:
    """(D, P) standard error of each pose's norm in g: the per-axis standard errors of the mean
    ``noise_g`` (D, P, 3) projected on the pose's unit direction u, sqrt(sum_c u_c^2 se_c^2)."""
    x = gf - _centre(gf)[:, None, :]
    u2 = x**2 / np.maximum(np.einsum("dpi,dpi->dp", x, x), 1e-300)[..., None]
    return np.sqrt(np.einsum("dpi,dpi->dp", u2, np.asarray(noise_g, dtype=float) ** 2))


def _stderr9(Gw: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(D, 9) standard errors sqrt(diag (J_f^T S^-1 J_f)^-1) of the free parameters (held: 0),
    from the weighted Gram matrices Gw (D, 9, 9); eigenvalues below 1e-13 of the largest are
    clipped there, so a direction the data do not see gets a huge, finite, ordered error."""
    f = free.astype(float)
    A = Gw * f[:, :, None] * f[:, None, :]
    fill = np.einsum("dkk->d", A) / np.maximum(f.sum(axis=1), 1.0)
    A[:, np.arange(9), np.arange(9)] += (1.0 - f) * fill[:, None]
    w, V = np.linalg.eigh(A)
    w = np.maximum(w, np.maximum(w[:, -1:], 1e-300) * 1e-13)
    return np.sqrt(np.einsum("dkj,dj->dk", V**2, 1.0 / w)) * f


def _noise_plan9(gf: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The module doc's noise rule for D boards: the held non-orthogonalities in the order held
    ((D, 3) int, -1 none) and each one's standard error when it was held ((D, 3)); ``sigma``
    (D, P) the standard error of each pose's norm in g."""
    D = len(gf)
    X = _design(gf, "9")[:, 0]  # every pose, revisits included: they average the noise down
    Gw = np.einsum("dpi,dp,dpj->dij", X, 1.0 / sigma**2, X)
    free = np.ones((D, 9), dtype=bool)
    order, se_at = np.full((D, 3), -1), np.full((D, 3), np.nan)
    hold = np.array(sorted(HOLDABLE_9))
    rows = np.arange(D)
    for nh in range(3):
        se = _stderr9(Gw[rows], free[rows])
        ratio = np.where(free[rows][:, hold], se[:, hold] / PRIOR_SD_NONORTHO, -1.0)
        j = np.argmax(ratio, axis=1)
        step = ratio[np.arange(len(rows)), j] >= 1.0
        rows, j, se = rows[step], j[step], se[step]
        if not rows.size:
            break
        order[rows, nh] = hold[j]
        se_at[rows, nh] = se[np.arange(len(rows)), hold[j]]
        free[rows, hold[j]] = False
    return order, se_at


def _scatter_sigma(gf: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(D, P) the residual scatter of the geometric plan's fit (``order`` its held terms),
    sqrt(RSS / (P - free terms)) at every pose; NaN where no degree of freedom is left."""
    from .stacked_norm import fit9  # the fitter: imported only when a table gives no noise

    free = np.ones((len(gf), 9), dtype=bool)
    for c in range(order.shape[1]):
        rows = np.flatnonzero(order[:, c] >= 0)
        free[rows, order[rows, c]] = False
    res = fit9(gf, None, free=free)
    P = gf.shape[1]
    dof = P - free.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(dof > 0, np.sqrt(np.einsum("dp,dp->d", res.norm_error_g, res.norm_error_g) / dof), np.nan)
    return np.repeat(s[:, None], P, axis=1)


def _plan_model9(gf: np.ndarray, noise_g: np.ndarray | None, determined: np.ndarray) -> HoldPlan:
    """Model 9's plan for D boards: geometric refusals, then the noise rule (module doc)."""
    D = len(gf)
    held: list[list[Held]] = [[]] * D  # shared empty list: a board's terms replace it, never appended
    refused = [""] * D
    ses: list[dict[str, float]] = []
    geo, code = np.full((D, 2), -1), np.zeros(D, dtype=int)
    und = np.flatnonzero(~determined)
    if und.size:
        geo[und], code[und] = _plan9(gf[und])
        code[und[(code[und] == 0) & (geo[und, 0] < 0)]] = 1  # nothing holding could help
    for d in np.flatnonzero(code == 1):
        refused[d] = assess(gf[d], "9").reason
    for d in np.flatnonzero(code == 2):
        refused[d] = FACES_ONLY
    if noise_g is not None:
        sigma = norm_sigma_g(gf, noise_g)
    else:  # the residual scatter, where the geometry leaves a decision to make
        sigma = np.full(gf.shape[:2], np.nan)
        rows = und[code[und] == 0]
        if rows.size:
            sigma[rows] = _scatter_sigma(gf[rows], geo[rows])
    usable = (code == 0) & np.all(np.isfinite(sigma) & (sigma > 0), axis=1)
    rows = np.flatnonzero(usable)
    if rows.size:
        order, se_at = _noise_plan9(gf[rows], sigma[rows])
        x = gf[rows] - _centre(gf[rows])[:, None, :]
        u = x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
        together = {k: np.max(np.abs(2 * u[..., "xyz".index(a)] * u[..., "xyz".index(b)]), axis=1)
                    for k, (a, b) in HOLDABLE_9.items()}
        ses = [{} for _ in range(D)]
        for i, d in enumerate(rows):
            held[d] = [_held_noise(int(k), float(se), float(together[int(k)][i]))
                       for k, se in zip(order[i], se_at[i], strict=True) if k >= 0]
            ses[d] = {PARAM_NAMES[int(k)]: float(se) for k, se in zip(order[i], se_at[i], strict=True) if k >= 0}
    # no noise to judge by: the geometric plan (a board it holds nothing for keeps its empty list)
    for d in np.flatnonzero((code == 0) & ~usable & (geo[:, 0] >= 0)):
        held[d] = [_held_9(int(k)) for k in geo[d] if k >= 0]
    return HoldPlan(held, refused, ses)


CONFIRM_SE_MAX = 2 * PRIOR_SD_NONORTHO  # terms pinned worse than this are not worth a held-out check (module doc)


def _freed(h: Held, se: float, c: HeldOutComparison) -> Held:
    """A noise-rule hold the held-out data overrule: the term fitted freely, and why."""
    what = h.reason.split(" held at 0")[0]
    return Held(h.term, 0.0, f"{what} fitted freely: the noise rule would hold it (standard error +-{se:.2g}, not "
                             f"below its prior +-{PRIOR_SD_NONORTHO:g}), but held out by orientation the held fit "
                             f"is {c.rms_b_g * 1e3:.3f} mg against {c.rms_a_g * 1e3:.3f} mg free, worse beyond the "
                             f"{c.orientations} orientations' scatter", h.hint)


def confirm_holds(gf: np.ndarray, noise_g: np.ndarray | None, plan: HoldPlan, workers: int | None = 1) -> HoldPlan:
    """Model 9's noise-rule holds checked by held-out data (module doc): for each board holding a
    term by the noise rule with a standard error below CONFIRM_SE_MAX, the fits with those terms
    held and free are each left out one distinct orientation at a time (crossval.py); where the
    held fit is worse beyond the orientations' own scatter (compare_held_out), the terms are
    fitted freely and recorded in ``freed``.  Boards sharing a grouping of poses are refitted
    together; a board of more than crossval.MAX_POSES poses or MAX_FOLDS orientations keeps its plan."""
    D, P = gf.shape[:2]
    if not plan.se or P > MAX_POSES:
        return plan

    def weak(d: int) -> list[Held]:
        return [h for h in plan.held[d] if plan.se[d].get(h.term, np.inf) < CONFIRM_SE_MAX]

    rows = np.array([d for d in range(D) if not plan.refused[d] and plan.se[d] and weak(d)], dtype=int)
    if not rows.size:
        return plan
    held, freed = list(plan.held), list(plan.freed) if plan.freed else [[] for _ in range(D)]
    labels = orientation_labels(gf[rows])
    patterns, inverse = np.unique(labels, axis=0, return_inverse=True)
    for k, pattern in enumerate(patterns):
        rk = rows[np.asarray(inverse).reshape(-1) == k]
        if not 3 <= len(np.unique(pattern)) <= MAX_FOLDS:
            continue
        m_held = HoldPlan([plan.held[d] for d in rk], [""] * len(rk)).free(PARAM_NAMES)
        m_free = HoldPlan([[h for h in plan.held[d] if h not in weak(d)] for d in rk],
                          [""] * len(rk)).free(PARAM_NAMES)
        g, nz = gf[rk], None if noise_g is None else np.broadcast_to(noise_g, gf.shape)[rk]
        sq_held = held_out_by_orientation(g, None, _fold9(g, nz, m_held, workers))[0]
        sq_free = held_out_by_orientation(g, None, _fold9(g, nz, m_free, workers))[0]
        for i, d in enumerate(rk):
            c = compare_held_out(sq_free[i], sq_held[i], P)
            if c.b_worse and np.isfinite(c.rms_a_g):
                terms = weak(int(d))
                held[d] = [h for h in plan.held[d] if h not in terms]
                freed[d] = [_freed(h, plan.se[d][h.term], c) for h in terms]
    return HoldPlan(held, plan.refused, plan.se, freed)


def _fold9(gf: np.ndarray, nz: np.ndarray | None, free: np.ndarray, workers: int | None) -> FoldFit:
    """The fold fitter of model 9 with each board's free mask (the one stacked estimator)."""
    def fold(rows: np.ndarray, keep: np.ndarray) -> BatchFit:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            try:
                return fit_stacked(gf[rows][:, keep], None, "9", None if nz is None else nz[rows][:, keep], workers,
                                   free=free[rows])
            except (UnderdeterminedError, np.linalg.LinAlgError):
                return _unfitted(len(rows))
    return fold


def _unfitted(n: int) -> BatchFit:
    """A fold no fit determines: every board not ok."""
    z = np.zeros((n, 3))
    return BatchFit("9", np.zeros((n, 3, 3)), z, z, np.zeros((n, 0, 3)), np.zeros((n, 0)), z, np.zeros(n),
                    np.zeros(n), np.zeros(n, bool), np.zeros(n), np.zeros((n, 3, 3)), z, z, np.zeros(n, bool),
                    np.zeros((n, 0, 0)), np.zeros((n, 0)), [], np.zeros(n, bool), [""] * n, np.zeros((n, 0, 3)))


def hold_plans(gf: np.ndarray, model: str, noise_g: np.ndarray | None = None,
               first: np.ndarray | None = None, sure: np.ndarray | None = None) -> HoldPlan:
    """The terms of ``model`` to hold at nominal for each of D boards' readings ``gf`` (D, P, 3)
    in about g (module doc), vectorised over boards: the one decision of the one-board fit,
    `accelcal batch` and lot files.  ``noise_g`` (D, P, 3): the standard error of each pose
    mean in g (None: the residual scatter).  A board whose gain or offset is weak, or that
    holding cannot help, is refused with the identifiability reason.  ``first``: the boards'
    first_of_orientation when the caller has it (the fit's front computes it once); ``sure``: boards
    already certified determined (models.screening.screen)."""
    gf = np.asarray(gf, dtype=float)
    D = len(gf)
    determined, _ = assess_batch(gf, model, first, sure)
    if model == "9":
        nz = None if noise_g is None else np.broadcast_to(np.asarray(noise_g, dtype=float), gf.shape)
        return _plan_model9(gf, nz, determined)
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
    for d in und:
        refused[d] = assess(gf[d], model).reason
    return HoldPlan(held, refused)


def hold_plan(gf: np.ndarray, model: str, noise_g: np.ndarray | None = None, confirm: bool = False) -> list[Held]:
    """One board's ``hold_plans``: the terms to hold for readings ``gf`` (P, 3) with standard
    errors ``noise_g`` (P, 3) in g or None; raises UnderdeterminedError with the reason when
    the board is refused.  ``confirm``: model 9's holds checked by held-out data as the fit
    checks them (``confirm_holds``: refits; a refusal does not depend on it)."""
    g = np.asarray(gf, dtype=float)[None]
    nz = None if noise_g is None else np.asarray(noise_g, dtype=float)[None]
    plan = hold_plans(g, model, nz)
    if plan.refused[0]:
        raise UnderdeterminedError(plan.refused[0])
    if model == "9" and confirm:
        plan = confirm_holds(g, nz, plan)
    return list(plan.held[0])  # its own list (the plan shares one empty list among boards)


def free_mask(held: list[Held], names: list[str]) -> np.ndarray:
    """(k,) bool: the parameters fitted (not held)."""
    terms = {h.term for h in held}
    return np.array([n not in terms for n in names])


__all__ = ["CONFIRM_SE_MAX", "HOLDABLE_9", "PRIOR_SD_NONORTHO", "Held", "HoldPlan", "confirm_holds", "cubic_held",
           "free_mask", "hold_plan", "hold_plans",
           "norm_sigma_g"]

"""Sequential capture against the parameters' targets (docs/capture.md, "Sequential capture").

One plan per board and design: before each pose stops, the station re-estimates the chip's noise
from the samples so far (per axis, for the poses to come: the sample variance pooled over the poses
captured and this one's samples, and tau_int, the mean of the poses' own estimates:
models/effective_samples.py; for this pose: its own so far), then
allocates the samples still to take across this pose and the ones after it by their leverage
(models/allocation.py), the captured poses entering with their own measured standard errors.
The pose stops when it holds its allocated count (re-estimated each time the count is reached, so
a noisier chip than first seen extends it) and at least ``capture.min_samples``; the targets are
met when the last pose reaches its count.  What the fit reports is still each pose's measured
scatter with its own n_eff (models/fitting.py), never the target.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..drivers.base import Capture
from ..models.allocation import Allocation, DesignRows, allocate, block_variance, design_rows, target_variances
from ..models.effective_samples import tau_int
from .capture import CaptureSettings
from .report import PoseSummary


@dataclass(frozen=True)
class ParameterTargets:
    """Standard uncertainty targets: the fitted offset in mg, the gain as a fraction (None: no target)."""

    offset_u_mg: float | None
    gain_u: float | None


@dataclass
class SequentialPlan:
    """The samples each pose of one board's design needs (module docstring)."""

    rows: DesignRows
    target_var: np.ndarray  # (B, p) g^2 (offsets) and fraction^2 (gains); inf: no target
    counts_per_g: float
    min_samples: int
    max_samples: int
    sem2_g2: np.ndarray = field(init=False)  # (m, 3) captured poses' squared standard error, g^2
    var_g2: np.ndarray = field(init=False)  # (m, 3) captured poses' per-sample variance, g^2
    tau: np.ndarray = field(init=False)  # (m, 3) captured poses' tau_int
    n: np.ndarray = field(init=False)  # (m,) captured poses' sample counts (0: not yet)
    last: Allocation | None = None

    def __post_init__(self) -> None:
        m = self.rows.poses
        self.sem2_g2 = np.zeros((m, 3))
        self.var_g2 = np.zeros((m, 3))
        self.tau = np.ones((m, 3))
        self.n = np.zeros(m, dtype=int)

    @classmethod
    def for_design(cls, model: str, expected_g: np.ndarray, targets: ParameterTargets, counts_per_g: float,
                   min_samples: int, max_samples: int) -> SequentialPlan:
        """A plan for the poses' expected readings (m, 3) in g as the chip reads them (mounting applied)."""
        rows = design_rows(model, expected_g)
        off = None if targets.offset_u_mg is None else targets.offset_u_mg * 1e-3
        return cls(rows, target_variances(rows, off, targets.gain_u), counts_per_g, min_samples, max_samples)

    def needed(self, pose: int, counts: np.ndarray) -> int:
        """Samples pose ``pose`` needs, with the noise measured so far and this pose's samples (n, 3)."""
        c = np.asarray(counts, dtype=float) / self.counts_per_g
        done = self.n > 0
        dof = np.concatenate([self.n[done] - 1.0, [len(c) - 1.0]])
        own_var, own_tau = c.var(axis=0, ddof=1), tau_int(c)
        var = np.vstack([self.var_g2[done], own_var])
        taus = np.vstack([self.tau[done], own_tau])
        q = np.tile((dof @ var) / max(float(dof.sum()), 1.0) * taus.mean(axis=0), (self.rows.poses, 1))
        remaining = ~done
        remaining[:pose] = False  # a skipped pose is not captured later
        fixed = block_variance(self.rows, self.sem2_g2)
        self.last = allocate(self.rows, fixed, block_variance(self.rows, q), remaining, self.target_var,
                             self.min_samples, self.max_samples)
        if len(c) >= self.last.n[pose]:
            # an ask that would end the pose: with its own sigma^2 tau (all its samples in) the prediction is
            # what the fit will report from its std and n_eff (the pooled figure steadies the earlier asks)
            q[pose] = own_var * own_tau
            self.last = allocate(self.rows, fixed, block_variance(self.rows, q), remaining, self.target_var,
                                 self.min_samples, self.max_samples)
        return int(self.last.n[pose])

    def record(self, pose: int, capture: Capture) -> None:
        """Pose ``pose`` captured: its own per-axis scatter, tau_int and standard error from now on."""
        cpg = self.counts_per_g
        n_eff = np.full(3, float(capture.n)) if capture.n_eff is None else np.asarray(capture.n_eff, dtype=float)
        self.n[pose] = capture.n
        self.var_g2[pose] = (np.asarray(capture.std_counts, dtype=float) / cpg) ** 2
        self.tau[pose] = capture.n / n_eff
        self.sem2_g2[pose] = self.var_g2[pose] / n_eff

    def floor_samples(self) -> int | None:
        """The fewest fit samples that meet the targets at the noise the board showed (every pose's own
        sigma^2 tau_int, allocated afresh over all poses: the time budget's floor); None before every pose
        was captured."""
        if not np.all(self.n > 0):
            return None
        q = block_variance(self.rows, self.var_g2 * self.tau)
        none = np.zeros_like(q)
        best = allocate(self.rows, none, q, np.ones(self.rows.poses, dtype=bool), self.target_var,
                        self.min_samples, self.max_samples)
        return int(best.n.sum())

    def predicted_u(self) -> Allocation | None:
        """The last allocation (its predicted uncertainties), None before any."""
        return self.last


def targets_of(offset_u_mg: float | None, gain_u: float | None) -> ParameterTargets | None:
    """The parameter targets, or None when neither is set (the per-pose SEM rule alone)."""
    if offset_u_mg is None and gain_u is None:
        return None
    return ParameterTargets(offset_u_mg, gain_u)


# the samples a pose needs given its samples so far (counts, (n, 3)): what gated_capture asks
Needed = Callable[[np.ndarray], int]


def plan_for(model: str, settings: CaptureSettings, expected_g: list[np.ndarray], counts_per_g: float,
             odr_hz: float) -> SequentialPlan | None:
    """A board's plan for its design's expected readings in g; None when no parameter target is set."""
    targets = targets_of(settings.target_offset_u_mg, settings.target_gain_u)
    if targets is None:
        return None
    r = np.array(expected_g, dtype=float)
    model = str(model)
    if model == "15" and not determined(model, r):
        model = "12"  # the fit holds the cubic at 0 where the design cannot tell it from the gain (models/held.py)
    if not determined(model, r):
        return None  # the fit will refuse the design; the per-pose SEM rule captures it meanwhile
    return SequentialPlan.for_design(model, r, targets, counts_per_g, settings.min_samples,
                                     max(settings.min_samples, int(settings.max_s * odr_hz)))


WEAK_COND = 1e3  # a design this ill-conditioned (columns scaled to unit norm) leaves a term to the fit's hold rule


def determined(model: str, expected_g: np.ndarray) -> bool:
    """Whether the poses pin every parameter of ``model`` well (each block's unit-norm columns with condition
    number below WEAK_COND): where they do not (the cubic on cube vertices or faces, a weak model-9 term) the
    fit holds terms (models/held.py) and this plan, made for the free fit, would not predict it."""
    A = design_rows(model, expected_g).A
    if A.shape[1] < A.shape[2]:
        return False
    norms = np.linalg.norm(A, axis=1, keepdims=True)
    return bool(np.all(np.linalg.cond(A / np.where(norms > 0, norms, 1.0)) < WEAK_COND))


def needed_at(plan: SequentialPlan | None, pose: int) -> Needed | None:
    """The plan's count for pose ``pose`` as gated_capture asks it (None without a plan)."""
    if plan is None:
        return None
    return lambda counts: plan.needed(pose, counts)


def plan_record(plan: SequentialPlan | None, pose: int, capture: Capture) -> PoseSummary:
    """Record pose ``pose``'s capture in the plan; what the run report says of the plan for it."""
    if plan is None or plan.last is None:
        return {}
    planned = int(plan.last.n[pose])
    off = np.array([plan.last.u[b, p] for b, p in plan.rows.offset_at])
    plan.record(pose, capture)
    return {"planned_n": planned, "predicted_offset_u_mg": round(float(np.max(off)) * 1e3, 5)}

"""Acceptance: configurable limits on a fit, giving PASS or FAIL with every reason.

One rule table (``MEASURES`` and the distinct-poses rule) judged by ``judge_all`` over B
boards at once: the station and pose-table batch judge stacks of their fits, a lot file
each chunk, so a board gets the same verdict and reasons whichever path it came by."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..config.parts import parse
from ..config.schema import AcceptanceSection
from ..models.result import FitResult
from ..models.sanity import distinct_directions, distinct_directions_batch, poses_needed
from .reasons import Reason

# the acceptance keys that are not a limit on a fitted figure: the self-test's and the offset trim's
# settings (judged by the station: Limits.self_test, Limits.offset_trim_tolerance)
STEP_KEYS = ("self_test", "self_test_low_g", "self_test_high_g", "self_test_tolerance", "offset_trim_tolerance",
             "decision_rule")
# each limit's meaning, as the schema declares it (a FAIL reason names it)
LIMIT_KEYS = {k: f.description or k for k, f in AcceptanceSection.model_fields.items() if k not in STEP_KEYS}


@dataclass(frozen=True)
class SelfTestLimits:
    """The self-test step's settings: whether it runs, and limits overriding the data sheet's (None: kept)."""

    run: bool = True
    low_g: tuple[float, ...] | None = None
    high_g: tuple[float, ...] | None = None
    tolerance: float | None = None

    @property
    def overridden(self) -> bool:
        return self.low_g is not None or self.high_g is not None or self.tolerance is not None


# limits every run is judged on even when a config leaves them out (printed when used):
# a cross-validated error this large means some pose disagrees with the others by tens of mg
DEFAULT_LIMITS = {"crossval_rms_mg": 10.0}


@dataclass
class Limits:
    values: dict[str, float] = field(default_factory=dict)
    defaulted: list[str] = field(default_factory=list)  # keys filled from DEFAULT_LIMITS
    self_test: SelfTestLimits = field(default_factory=SelfTestLimits)
    offset_trim_tolerance: float = 0.25  # fraction of the expected trim change (AcceptanceSection)
    decision_rule: str = "guarded"  # simple or guarded acceptance (acceptance/decision.py)

    @classmethod
    def from_config(cls, d: object, path: str = "acceptance") -> Limits:
        """From an ``acceptance:`` mapping not yet validated (a batch's or a twin's config): validated
        once against AcceptanceSection, then :meth:`from_section`."""
        return cls.from_section(parse(d, AcceptanceSection, path))

    @classmethod
    def from_section(cls, section: AcceptanceSection | None) -> Limits:
        """From a validated ``acceptance`` section (None: none given): the safe defaults filled in."""
        sec = section or AcceptanceSection()
        checked = sec.model_dump(exclude_none=True)
        values = {k: float(v) for k, v in checked.items() if k not in STEP_KEYS}
        missing = [k for k in DEFAULT_LIMITS if k not in values]
        st = SelfTestLimits(sec.self_test, None if sec.self_test_low_g is None else tuple(sec.self_test_low_g),
                            None if sec.self_test_high_g is None else tuple(sec.self_test_high_g),
                            sec.self_test_tolerance)
        return cls({**values, **{k: DEFAULT_LIMITS[k] for k in missing}}, missing, st, sec.offset_trim_tolerance,
                   sec.decision_rule)

    def defaults_line(self) -> str:
        """One line naming the safe defaults in use, or ''."""
        if not self.defaulted:
            return ""
        return "acceptance: " + ", ".join(f"{k} not set, using the safe default {self.values[k]:g}"
                                          for k in self.defaulted)


@dataclass
class Verdict:
    passed: bool
    reasons: list[Reason]
    measured: dict[str, float]
    held: list[str] = field(default_factory=list)  # terms fitted at nominal (models/held.py), in words

    @property
    def label(self) -> str:
        return "PASS" if self.passed else "FAIL"


@dataclass
class FitFigures:
    """What the rules measure, for B boards at once (NaN: not measurable for that board).

    One board from the station or a pose table is B = 1 (``from_fits``); a lot-file chunk
    fills the arrays from its stacked fit directly."""

    model: str
    W: np.ndarray  # (B, 3, 3)
    V: np.ndarray  # (B, 3) in g
    Gamma: np.ndarray  # (B, 3) in 1/g^2
    residual_rms_g: np.ndarray  # (B,)
    residual_max_g: np.ndarray  # (B,)
    crossval_rms_g: np.ndarray  # (B,) held-out RMS judged: by orientation where orientations repeat
    stderr_V_max_g: np.ndarray  # (B,)
    stderr_W_max: np.ndarray  # (B,)
    distinct_poses: np.ndarray  # (B,) distinct pose directions the fit rests on
    held: list[list[str]] | None = None  # (B,) terms each fit holds at nominal (models/held.py), in words

    @classmethod
    def from_fits(cls, fits: list[FitResult]) -> FitFigures:
        """Stack single-board fits (all of one model)."""
        nan = float("nan")
        return cls(fits[0].model, np.array([f.W for f in fits]), np.array([f.V for f in fits]),
                   np.array([f.Gamma for f in fits]), np.array([f.residual_rms_g for f in fits]),
                   np.array([f.residual_max_g for f in fits]),
                   np.array([nan if f.acceptance_crossval_rms_g is None else f.acceptance_crossval_rms_g
                             for f in fits]),
                   np.array([nan if f.stderr is None else np.max(f.stderr["V"]) for f in fits]),
                   np.array([nan if f.stderr is None else np.max(f.stderr["W"]) for f in fits]),
                   distinct_directions_batch(np.array([f.readings_g for f in fits]))
                   if len({len(f.readings_g) for f in fits}) == 1
                   else np.array([distinct_directions(f.readings_g) for f in fits]),
                   [[h.text for h in f.held] for f in fits])


def _off_diagonal(W: np.ndarray) -> np.ndarray:
    return W * (1.0 - np.eye(3))


# The rule table: each limit key's measure over B boards, (B,) values in the key's unit.
# verify_error_max_mg is measured by the station's verification capture, not from the fit.
MEASURES: dict[str, Callable[[FitFigures], np.ndarray]] = {
    "residual_rms_mg": lambda f: f.residual_rms_g * 1e3,
    "residual_max_mg": lambda f: f.residual_max_g * 1e3,
    "crossval_rms_mg": lambda f: f.crossval_rms_g * 1e3,
    "gain_error_max": lambda f: np.max(np.abs(np.diagonal(f.W, axis1=1, axis2=2) - 1.0), axis=1),
    "cross_axis_max": lambda f: np.max(np.abs(_off_diagonal(f.W)).reshape(-1, 9), axis=1),
    "offset_max_mg": lambda f: np.max(np.abs(f.V), axis=1) * 1e3,
    "cubic_max": lambda f: np.max(np.abs(f.Gamma), axis=1),
    "stderr_offset_max_mg": lambda f: f.stderr_V_max_g * 1e3,
    "stderr_gain_max": lambda f: f.stderr_W_max,
}


def measure_all(figs: FitFigures) -> dict[str, np.ndarray]:
    """Every rule's measure over the boards (NaN: not measurable)."""
    return {k: np.asarray(fn(figs), dtype=float) for k, fn in MEASURES.items()}


def measure(fit: FitResult) -> dict[str, float]:
    """One board's measures (the keys that are measurable for it)."""
    return {k: float(v[0]) for k, v in measure_all(FitFigures.from_fits([fit])).items() if not np.isnan(v[0])}


RuleFailures = tuple[np.ndarray, str, list[str]]  # a rule's failing boards (indices, ascending), its code, the texts


def _pose_failures(have: np.ndarray, model: str, planned_poses: int) -> list[RuleFailures]:
    need = poses_needed(model)
    few = np.flatnonzero(have < need)
    skipped = np.flatnonzero((have >= need) & (have < planned_poses))
    return [(few, "distinct_poses", [f"distinct_poses {have[b]} < {need} needed by model {model} (its unknowns "
                                     "per axis plus one, so cross-validation is measurable)" for b in few]),
            (skipped, "distinct_poses", [f"distinct_poses {have[b]} < {planned_poses} planned (a pose was skipped "
                                         "or repeated)" for b in skipped])]


def limit_failures(m: dict[str, np.ndarray], have: np.ndarray, model: str, limits: Limits,
                   planned_poses: int = 0) -> list[RuleFailures]:
    """Each rule's failing boards among B (``limit_reasons``' order: the distinct-pose rules, then
    the limits as configured), compared over all boards at once; the texts (a Reason's whole text)
    are formatted for the failing boards only, and no per-board list is built."""
    out = _pose_failures(have, model, planned_poses)
    for key, lim in limits.values.items():
        if key not in m:  # verify_error_max_mg before verification
            continue
        v = m[key]
        unmeasurable = np.isnan(v)
        if unmeasurable.any():
            idx = np.flatnonzero(unmeasurable)
            out.append((idx, key, [f"{key}: not measurable for this fit (limit {lim:g})"] * len(idx)))
        idx = np.flatnonzero(~unmeasurable & ~(v <= lim))
        tail = f" > limit {lim:g} ({LIMIT_KEYS[key]})"
        out.append((idx, key, [f"{key} {x:.4g}{tail}" for x in v[idx].tolist()]))
    return out


def limit_reasons(m: dict[str, np.ndarray], have: np.ndarray, model: str, limits: Limits,
                  planned_poses: int = 0) -> list[list[Reason]]:
    """Why each of B boards fails (``[]`` when it passes), from its measured figures ``m``
    (measure_all) and distinct poses ``have``: the limits compared over all boards at once,
    the words formatted only for the boards that fail."""
    reasons: list[list[Reason]] = [[] for _ in range(len(have))]
    for idx, code, texts in limit_failures(m, have, model, limits, planned_poses):
        for b, t in zip(idx.tolist(), texts, strict=True):
            reasons[b].append(Reason.of(code, t))
    return reasons


def judge_all(figs: FitFigures, limits: Limits, verify_error_max_mg: np.ndarray | None = None,
              planned_poses: int = 0) -> list[Verdict]:
    """The verdict of each of B boards: PASS only if the fit rests on enough distinct poses
    (the model's unknowns per axis plus one, and every pose the plan has) and every
    configured limit holds; a limit that cannot be measured fails.  ``verify_error_max_mg``
    (B,) is judged when given (after verification).  Each verdict names the terms its fit
    held at nominal (``figs.held``): held, not failed."""
    m = measure_all(figs)
    if verify_error_max_mg is not None:
        m["verify_error_max_mg"] = np.asarray(verify_error_max_mg, dtype=float)
    have = np.asarray(figs.distinct_poses, dtype=int)
    reasons = limit_reasons(m, have, figs.model, limits, planned_poses)
    held = figs.held or [[] for _ in reasons]
    return [Verdict(not r, r, {**{k: float(v[b]) for k, v in m.items() if not np.isnan(v[b])},
                               "distinct_poses": float(have[b])}, list(held[b]))
            for b, r in enumerate(reasons)]


def judge(fit: FitResult, limits: Limits, verify_error_max_mg: float | None = None,
          planned_poses: int = 0) -> Verdict:
    """One board's verdict: ``judge_all`` on a stack of one."""
    verify = None if verify_error_max_mg is None else np.array([verify_error_max_mg])
    return judge_all(FitFigures.from_fits([fit]), limits, verify, planned_poses)[0]

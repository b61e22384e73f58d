"""Acceptance: configurable limits on a fit, giving PASS or FAIL with every reason."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config.checks import check_keys, number
from ..models.result import FitResult
from ..models.sanity import distinct_directions, poses_needed
from .reasons import Reason

LIMIT_KEYS = {
    "residual_rms_mg": "RMS of per-pose per-axis residuals, mg",
    "residual_max_mg": "largest per-pose per-axis residual, mg",
    "crossval_rms_mg": "leave-one-pose-out RMS, mg",
    "gain_error_max": "largest |W_ii - 1| (W maps reading in g to g), fraction",
    "cross_axis_max": "largest |W_ij|, i != j, fraction",
    "offset_max_mg": "largest |V_i|, mg",
    "cubic_max": "largest |Gamma_ii|, 1/g^2",
    "stderr_offset_max_mg": "largest standard error of V, mg",
    "stderr_gain_max": "largest standard error of W, fraction",
    "verify_error_max_mg": "closed-loop verification: largest |calibrated - expected|, mg",
}


# limits every run is judged on even when a config leaves them out (printed when used):
# a cross-validated error this large means some pose disagrees with the others by tens of mg
DEFAULT_LIMITS = {"crossval_rms_mg": 10.0}


@dataclass
class Limits:
    values: dict[str, float] = field(default_factory=dict)
    defaulted: list[str] = field(default_factory=list)  # keys filled from DEFAULT_LIMITS

    @classmethod
    def from_config(cls, d: dict | None, path: str = "acceptance") -> Limits:
        d = check_keys(d or {}, LIMIT_KEYS, path)
        values = {k: number(d, k, path, lo=0.0) for k in d}
        missing = [k for k in DEFAULT_LIMITS if k not in values]
        return cls({**values, **{k: DEFAULT_LIMITS[k] for k in missing}}, missing)

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


def measure(fit: FitResult) -> dict[str, float]:
    W = fit.W
    off = W - np.diag(np.diag(W))
    m = {
        "residual_rms_mg": fit.residual_rms_g * 1e3,
        "residual_max_mg": fit.residual_max_g * 1e3,
        "gain_error_max": float(np.max(np.abs(np.diag(W) - 1.0))),
        "cross_axis_max": float(np.max(np.abs(off))),
        "offset_max_mg": float(np.max(np.abs(fit.V))) * 1e3,
        "cubic_max": float(np.max(np.abs(fit.Gamma))),
    }
    if fit.crossval_rms_g is not None:
        m["crossval_rms_mg"] = fit.crossval_rms_g * 1e3
    if fit.stderr is not None:
        m["stderr_offset_max_mg"] = float(np.max(fit.stderr["V"])) * 1e3
        m["stderr_gain_max"] = float(np.max(fit.stderr["W"]))
    return m


def judge(fit: FitResult, limits: Limits, verify_error_max_mg: float | None = None,
          planned_poses: int = 0) -> Verdict:
    """PASS only if every configured limit holds; a limit that cannot be measured fails.

    The fit must also rest on enough distinct poses: the model's unknowns per axis plus
    one, and every pose the plan has (a skipped pose fails the run)."""
    m = measure(fit)
    if verify_error_max_mg is not None:
        m["verify_error_max_mg"] = verify_error_max_mg
    reasons = []
    have, need = distinct_directions(fit.readings_g), poses_needed(fit.model)
    m["distinct_poses"] = float(have)
    if have < need:
        reasons.append(Reason("distinct_poses", f"{have} < {need} needed by model {fit.model} (its unknowns "
                              "per axis plus one, so cross-validation is measurable)", " "))
    elif have < planned_poses:
        reasons.append(Reason("distinct_poses", f"{have} < {planned_poses} planned (a pose was skipped or "
                              "repeated)", " "))
    for key, lim in limits.values.items():
        if key not in m:
            if key == "verify_error_max_mg" and verify_error_max_mg is None:
                continue  # judged after verification
            reasons.append(Reason(key, f"not measurable for this fit (limit {lim:g})"))
        elif not m[key] <= lim:
            reasons.append(Reason(key, f"{m[key]:.4g} > limit {lim:g} ({LIMIT_KEYS[key]})", " "))
    return Verdict(not reasons, reasons, m, [h.text for h in fit.held])

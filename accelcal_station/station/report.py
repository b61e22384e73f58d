"""What one run did: the run report (the `accelcal run --json` object of a board) and the
fit's figures as the store keeps them."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..acceptance.reasons import Reason, codes
from ..calibration import Calibration
from ..models.result import FitResult


@dataclass
class RunReport:
    """What one run did; ``to_dict`` is the `accelcal run --json` object."""

    run_id: int | None = None
    serial: str = ""
    chip: str = ""
    station_id: str = ""
    verdict: str = "FAIL"
    reasons: list[Reason] = field(default_factory=list)
    model: str = ""
    design: str = ""
    fit: FitResult | None = None
    measured: dict[str, float] = field(default_factory=dict)
    verify_error_max_mg: float | None = None
    nvm: dict[str, Any] | None = None
    nvm_verified: bool = False
    offset_trim_lsb: list[int] | None = None
    calibration: Calibration | None = None  # what was (or would be) written: the fit's, trim applied
    poses: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    timing: dict[str, Any] = field(default_factory=dict)  # seconds, counts; a thermal plan adds its clock
    store: str = ""

    def to_dict(self) -> dict[str, Any]:
        f, c = self.fit, self.calibration
        return {
            "run_id": self.run_id, "serial": self.serial, "chip": self.chip, "station_id": self.station_id,
            "verdict": self.verdict, "reasons": [str(r) for r in self.reasons], "reason_codes": codes(self.reasons),
            "model": self.model, "design": self.design,
            "W": None if c is None else c.W.tolist(), "V": None if c is None else c.V.tolist(),
            "Gamma": None if c is None else c.Gamma.tolist(),
            "residual_rms_mg": None if f is None else f.residual_rms_g * 1e3,
            "crossval_rms_mg": None if f is None or f.crossval_rms_g is None else f.crossval_rms_g * 1e3,
            "held": [] if f is None else [h.to_json() for h in f.held],  # terms at nominal (models/held.py)
            "measured": self.measured, "verify_error_max_mg": self.verify_error_max_mg,
            "nvm": self.nvm, "nvm_verified": self.nvm_verified, "offset_trim_lsb": self.offset_trim_lsb,
            "poses": self.poses, "skipped": self.skipped,
            "events": self.events, "timing": self.timing, "store": self.store,
        }


def fit_figures(fit: FitResult | None) -> dict[str, float | None]:
    """The fit's scalar figures as the store keeps them (report list/export columns)."""
    if fit is None:
        return {}
    return {"residual_rms_g": fit.residual_rms_g, "residual_max_g": fit.residual_max_g,
            "crossval_rms_g": fit.crossval_rms_g, "crossval_by_orientation_rms_g": fit.crossval_by_orientation_rms_g,
            "condition_number": fit.condition_number}

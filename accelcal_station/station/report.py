"""What one run did: the run report (the `accelcal run --json` object of a board) and the
fit's figures as the store keeps them.  Its verdict is never set: the flow records each stage's
outcome and the verdict is made from them in one place (verdict.py ``run_verdict``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, TypedDict

from ..acceptance.reasons import Reason, codes
from ..calibration import Calibration
from ..models.result import FitResult
from .verdict import Outcome, RunVerdict, Stage, run_verdict


class PoseSummary(TypedDict, total=False):
    """One captured pose as the run report lists it; a thermal plan's adds its set point (C), its
    role (calibrate or verify) and the board temperature (C) and leaves out the mean counts."""

    pose: str
    n: int  # samples averaged
    mean_counts: list[float]
    sem_mg: list[float]  # standard error of the mean per axis, mg
    retries: int
    reached_target: bool  # the SEM target was met before capture.max_s
    set_point_c: float
    role: str
    temp_c: float | None


class Timing(TypedDict, total=False):
    """Where a board's time went, s (counts of samples; a thermal plan's split: soak, sampling floor,
    rest; a real-time board's device time is wall time)."""

    odr_hz: float
    samples_averaged: int
    samples_read: int
    sampling_floor_s: float  # samples averaged / ODR
    sampling_s: float  # samples read / ODR
    wall_s: float
    operator_wait_s: float
    host_compute_s: float
    device_time_s: float  # on the device's clock: moves, waits, EEPROM cycles, sampling
    board_time_s: float
    soak_s: float
    rest_s: float
    boards: int
    per_board_s: float
    clock: Literal["real", "virtual"]


@dataclass
class RunReport:
    """What one run did; ``to_dict`` is the `accelcal run --json` object."""

    run_id: int | None = None
    serial: str = ""
    chip: str = ""
    station_id: str = ""
    outcomes: list[Outcome] = field(default_factory=list)  # what decided the verdict, stage by stage
    model: str = ""
    design: str = ""
    fit: FitResult | None = None
    measured: dict[str, float] = field(default_factory=dict)
    verify_error_max_mg: float | None = None
    nvm: dict[str, Any] | None = None
    nvm_verified: bool = False
    offset_trim_lsb: list[int] | None = None
    offset_trim: dict[str, Any] | None = None  # the trim written and its measured change (board.py _trim_offsets)
    self_test: dict[str, Any] | None = None  # the chip's self-test (drivers/self_test.py SelfTestResult.to_json)
    calibration: Calibration | None = None  # what was (or would be) written: the fit's, trim applied
    poses: list[PoseSummary] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    timing: Timing = field(default_factory=lambda: Timing())
    store: str = ""

    def record(self, stage: Stage, *reasons: Reason) -> None:
        """What a stage of the run found: the reasons it fails the board (none: it passed)."""
        self.outcomes.append(Outcome(stage, tuple(reasons)))

    @property
    def failed(self) -> bool:
        """A stage has failed the board (it takes no further part in the flow)."""
        return any(o.failed for o in self.outcomes)

    @property
    def final(self) -> RunVerdict:
        """The run's verdict, made from the outcomes recorded so far (verdict.py)."""
        return run_verdict(self.outcomes)

    @property
    def verdict(self) -> str:
        return self.final.label

    @property
    def reasons(self) -> list[Reason]:
        return list(self.final.reasons)

    def plan_summary(self) -> dict[str, Any] | None:
        """The summary of a plan beyond one calibration at room temperature (a thermal plan's table
        and set points: thermal.py ThermalRunReport), recorded with the run; None here."""
        return None

    def to_dict(self) -> dict[str, Any]:
        f, c = self.fit, self.calibration
        final = self.final
        return {
            "run_id": self.run_id, "serial": self.serial, "chip": self.chip, "station_id": self.station_id,
            "verdict": final.label, "reasons": [str(r) for r in final.reasons], "reason_codes": codes(final.reasons),
            "model": self.model, "design": self.design,
            "W": None if c is None else c.W.tolist(), "V": None if c is None else c.V.tolist(),
            "Gamma": None if c is None else c.Gamma.tolist(),
            "residual_rms_mg": None if f is None else f.residual_rms_g * 1e3,
            "crossval_rms_mg": None if f is None or f.crossval_rms_g is None else f.crossval_rms_g * 1e3,
            "held": [] if f is None else [h.to_json() for h in f.held],  # terms at nominal (models/held.py)
            "measured": self.measured, "verify_error_max_mg": self.verify_error_max_mg,
            "nvm": self.nvm, "nvm_verified": self.nvm_verified, "offset_trim_lsb": self.offset_trim_lsb,
            "offset_trim": self.offset_trim, "self_test": self.self_test,
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

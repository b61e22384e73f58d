"""What one run did: the run report (the `accelcal run --json` object of a board) and the
fit's figures as the store keeps them.  Its verdict is never set: the flow records each stage's
outcome and the verdict is made from them in one place (verdict.py ``run_verdict``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, TypedDict

from ..acceptance.budget import UncertaintyJson
from ..acceptance.decision import DecisionRuleJson
from ..acceptance.reasons import Reason, codes
from ..calibration import Calibration
from ..config.site import SiteJson
from ..jsontypes import JsonObject
from ..models.result import FitResult
from .offset_trim import OffsetTrimRecord
from .time_budget import TimeBudget
from .verdict import Outcome, RunVerdict, Stage, run_verdict


class WarmupRecord(TypedDict):
    """``warmup`` in run --json and the store's run summary."""

    mode: str  # settled | time
    held_s: float  # board time held
    settled: bool | None  # mode settled: the drift fell below the limit (None: mode time)
    drift_mg: list[float] | None  # the last window-to-window change of the mean per axis, mg
    window_s: float | None
    drift_limit_mg: float | None
    powered_ahead_s: float  # capture.powered_ahead_s: how long the board was powered before it was placed


class PoseSummary(TypedDict, total=False):
    """One captured pose as the run report lists it; a thermal plan's adds its set point (C), its
    role (calibrate or verify) and the board temperature (C) and leaves out the mean counts."""

    pose: str
    n: int  # samples averaged
    mean_counts: list[float]
    sem_mg: list[float]  # standard error of the mean per axis, mg: std / sqrt(n_eff)
    n_eff: list[float]  # effective sample count per axis, n / tau_int (correlated samples)
    retries: int
    reached_target: bool  # the pose's stopping rule (its planned count, or the SEM target) was met before capture.max_s
    planned_n: int  # the samples the sequential plan allocated this pose (station/sequential_capture.py)
    predicted_offset_u_mg: float  # the plan's predicted largest offset standard uncertainty once this pose was in
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
    warmup_s: float  # the warm-up hold, board time (station/warmup.py; counted in the time budget)
    soak_s: float
    rest_s: float
    boards: int
    per_board_s: float
    clock: Literal["real", "virtual"]


class FitFigures(TypedDict, total=False):
    """The fit's scalar figures as the store keeps them, g (report list/export columns)."""

    residual_rms_g: float
    residual_max_g: float
    crossval_rms_g: float | None
    crossval_by_orientation_rms_g: float | None
    condition_number: float


class SetPointRecord(TypedDict):
    """A set point as the run records it (SetPointResult.to_dict)."""

    set_point_c: float
    role: str
    temp_source: str
    soak_s: float
    board_temp_c: float | None
    air_temp_c: float | None
    sampling_floor_s: float
    poses_s: float
    poses: int
    fit: dict[str, float | list[float]] | None
    verdict: str | None
    reasons: list[Reason]
    verify_error_max_mg: float | None
    without_table_error_max_mg: float | None
    t_start_s: float
    t_soaked_s: float | None
    t_end_s: float | None
    uncertainty: UncertaintyJson | None  # a calibration set point's budget (thermal_budget.py)


class VerifyRow(TypedDict):
    """The table checked at one verification set point: its largest error, mg, and the error of
    the single calibration nearest the reference temperature, for comparison."""

    set_point_c: float
    board_temp_c: float
    error_max_mg: float
    without_table_error_max_mg: float
    without_table_calibration_c: float
    limit_mg: float | None
    within_limit: bool
    without_table_within_limit: bool


class TableVerdict(TypedDict):
    """The temperature table's verdict before writing (every set point's fit and the verification)."""

    verdict: str
    reasons: list[str]


class TableSummary(TypedDict, total=False):
    """The table written: its temperatures (C), its interpolation and its verdict."""

    temps_c: list[float]
    method: str
    verdict: str
    reasons: list[str]


class PanelOfPlan(TypedDict):
    """The panel a thermal plan's board was calibrated on."""

    panel_id: str | None
    boards: int


class ThermalSummary(TypedDict, total=False):
    """A thermal plan's summary, as its run report and the store keep it."""

    set_points_c: list[float]
    verify_set_points_c: list[float]
    method: str
    soak: dict[str, float]  # the soak rule (thermal_plan.SoakRule)
    temp_source: str | None
    visits: list[SetPointRecord]
    table: TableSummary | None
    verify: list[VerifyRow]
    panel: PanelOfPlan | None


class RunReportJson(TypedDict):
    """A board's run as `accelcal run --json` prints it (RunReport.to_dict): W, V (g) and Gamma of the
    calibration written, the fit's residuals (mg), what was measured, burned and captured, the timing."""

    run_id: int | None
    serial: str
    chip: str
    station_id: str
    verdict: str
    reasons: list[str]
    reason_codes: list[str]
    station_fault: str | None
    model: str
    design: str
    W: list[list[float]] | None
    V: list[float] | None
    Gamma: list[float] | None
    residual_rms_mg: float | None
    crossval_rms_mg: float | None
    held: list[JsonObject]  # terms held at nominal (models.held.Held.to_json)
    measured: dict[str, float]
    verify_error_max_mg: float | None
    verify_mode: str | None  # "fit-poses" or "independent" (station/verification.py); None: no verification
    nvm: JsonObject | None
    nvm_verified: bool
    offset_trim_lsb: list[int] | None
    offset_trim: OffsetTrimRecord | None
    self_test: dict[str, object] | None  # drivers.self_test.SelfTestResult.to_json
    warmup: WarmupRecord | None  # station/warmup.py
    poses: list[PoseSummary]
    skipped: list[str]
    events: list[str]
    timing: Timing
    time_budget: TimeBudget  # where the board's time went and its floor (station/time_budget.py)
    store: str
    site: SiteJson | None  # the site's gravity the references were scaled to (config/site.py)
    uncertainty: UncertaintyJson | None  # {k, expanded, combined, budget} (acceptance/budget.py)
    decision_rule: DecisionRuleJson | None  # the acceptance decision rule applied (acceptance/decision.py)
    warnings: list[str]  # reasons that did not fail the board (within_uncertainty_of_limit, simple rule)
    warning_codes: list[str]


class ThermalRunReportJson(RunReportJson):
    """A thermal plan's board: its run and the plan's summary."""

    thermal: ThermalSummary


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
    verify_mode: str | None = None  # how the verification poses were chosen (station/verification.py)
    nvm: JsonObject | None = None  # the burn's outcome (nvm.writer.BurnOutcome.to_dict)
    nvm_verified: bool = False
    offset_trim_lsb: list[int] | None = None
    offset_trim: OffsetTrimRecord | None = None  # the trim written and its measured change (board.py _trim_offsets)
    self_test: dict[str, object] | None = None  # the chip's self-test (drivers/self_test.py SelfTestResult.to_json)
    warmup: WarmupRecord | None = None  # the warm-up hold (station/warmup.py)
    calibration: Calibration | None = None  # what was (or would be) written: the fit's, trim applied
    poses: list[PoseSummary] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    timing: Timing = field(default_factory=lambda: Timing())
    time_budget: TimeBudget = field(default_factory=dict)  # station/time_budget.py
    store: str = ""
    # the station's fault that ended this board's run (station_fault.py): the board is not judged
    station_fault: str | None = None
    site: SiteJson | None = None  # station.site as used (config/site.py Site.to_json)
    uncertainty: UncertaintyJson | None = None  # the board's uncertainty budget (docs/uncertainty.md)
    decision_rule: DecisionRuleJson | None = None  # the decision rule acceptance applied
    warnings: list[Reason] = field(default_factory=list)  # reasons that did not fail the board (simple rule)

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
        """PASS or FAIL; ERROR when a station fault ended the run (no verdict on the board)."""
        return "ERROR" if self.station_fault else self.final.label

    @property
    def reasons(self) -> list[Reason]:
        return list(self.final.reasons)

    def plan_summary(self) -> ThermalSummary | None:
        """The summary of a plan beyond one calibration at room temperature (a thermal plan's table
        and set points: thermal_table.ThermalRunReport), recorded with the run; None here."""
        return None

    def to_dict(self) -> RunReportJson:
        f, c = self.fit, self.calibration
        final = self.final
        return {
            "run_id": self.run_id, "serial": self.serial, "chip": self.chip, "station_id": self.station_id,
            "verdict": self.verdict, "reasons": [str(r) for r in final.reasons], "reason_codes": codes(final.reasons),
            "station_fault": self.station_fault,
            "model": self.model, "design": self.design,
            "W": None if c is None else c.W.tolist(), "V": None if c is None else c.V.tolist(),
            "Gamma": None if c is None else c.Gamma.tolist(),
            "residual_rms_mg": None if f is None else f.residual_rms_g * 1e3,
            "crossval_rms_mg": None if f is None or f.crossval_rms_g is None else f.crossval_rms_g * 1e3,
            "held": [] if f is None else [h.to_json() for h in f.held],  # terms at nominal (models/held.py)
            "measured": self.measured, "verify_error_max_mg": self.verify_error_max_mg,
            "verify_mode": self.verify_mode,
            "nvm": self.nvm, "nvm_verified": self.nvm_verified, "offset_trim_lsb": self.offset_trim_lsb,
            "offset_trim": self.offset_trim, "self_test": self.self_test, "warmup": self.warmup,
            "poses": self.poses, "skipped": self.skipped,
            "events": self.events, "timing": self.timing, "time_budget": self.time_budget, "store": self.store,
            "site": self.site, "uncertainty": self.uncertainty, "decision_rule": self.decision_rule,
            "warnings": [str(w) for w in self.warnings], "warning_codes": codes(self.warnings),
        }


def fit_figures(fit: FitResult | None) -> FitFigures:
    """The fit's scalar figures as the store keeps them (report list/export columns)."""
    if fit is None:
        return {}
    return {"residual_rms_g": fit.residual_rms_g, "residual_max_g": fit.residual_max_g,
            "crossval_rms_g": fit.crossval_rms_g, "crossval_by_orientation_rms_g": fit.crossval_by_orientation_rms_g,
            "condition_number": fit.condition_number}

"""One board's part of a thermal plan (AN4399 section 9): its set points, one fit per calibration
temperature, the temperature table (Eqns 83-92, piecewise ``linear`` or ``quadratic``) verified
at the set points not used in the fit, its verdict, its burn with read-back, its time split and
the summary its run records.  The plan's conditions (thermal.py) keep one BoardPlan per board.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..acceptance.budget import UncertaintyJson
from ..acceptance.reasons import Reason, wrap
from ..acceptance.rules import judge
from ..calibration import Calibration, TemperatureTable
from ..drivers.base import Clock, Driver
from ..errors import AccelcalError, UnderdeterminedError
from ..fixtures.base import PoseSpec
from ..fixtures.designs import get_design
from ..models.fitting import fit_session
from ..models.result import FitResult
from ..nvm.outcome import holds_text
from ..nvm.writer import BurnError, CalibrationWriter
from ..session import PoseRecord, Session
from .board import BoardSteps
from .report import (
    PanelOfPlan,
    RunReport,
    SetPointRecord,
    TableVerdict,
    ThermalRunReportJson,
    ThermalSummary,
    Timing,
    VerifyRow,
)
from .settings import StationConfig
from .thermal_budget import SetPointFit, set_point_budgets
from .thermal_plan import ThermalPlan
from .verdict import Stage

# a plan's poses by set point (C), in capture order
Groups = dict[float, list[PoseRecord]]


@dataclass
class SetPointResult:
    """What one set point gave: soak, poses, temperatures, time split (s, on the station's clock)."""

    set_point_c: float
    role: str
    temp_source: str = ""
    soak_s: float = 0.0
    board_temp_c: float | None = None
    air_temp_c: float | None = None
    sampling_floor_s: float = 0.0
    poses_s: float = 0.0
    poses: int = 0
    fit: dict[str, float | list[float]] | None = None
    verdict: str | None = None
    reasons: list[Reason] = field(default_factory=list)
    verify_error_max_mg: float | None = None
    without_table_error_max_mg: float | None = None
    t_start_s: float = 0.0
    t_soaked_s: float | None = None
    t_end_s: float | None = None
    uncertainty: UncertaintyJson | None = None  # a calibration set point's budget (thermal_budget.py)

    def to_dict(self) -> SetPointRecord:
        return SetPointRecord(
            set_point_c=self.set_point_c, role=self.role, temp_source=self.temp_source, soak_s=self.soak_s,
            board_temp_c=self.board_temp_c, air_temp_c=self.air_temp_c, sampling_floor_s=self.sampling_floor_s,
            poses_s=self.poses_s, poses=self.poses, fit=self.fit, verdict=self.verdict, reasons=self.reasons,
            verify_error_max_mg=self.verify_error_max_mg, without_table_error_max_mg=self.without_table_error_max_mg,
            t_start_s=self.t_start_s, t_soaked_s=self.t_soaked_s, t_end_s=self.t_end_s, uncertainty=self.uncertainty)

    def pose_temp_c(self, capture_temp_c: float | None, air_c: float) -> float:
        """A pose's board temperature: the die's during the capture, else the chamber air's."""
        temp = capture_temp_c if self.temp_source == "die" else air_c
        assert temp is not None, "a chip with a temperature sensor reads it with every capture"
        return temp

    def moved_c(self, temp_c: float) -> float:
        """How far a pose's board temperature is from the soaked one (the capture band's test)."""
        assert self.board_temp_c is not None, "poses are captured after the soak"
        return abs(temp_c - self.board_temp_c)


@dataclass
class ThermalRunReport(RunReport):
    """A board's run report with its thermal plan's summary (``thermal``)."""

    thermal: ThermalSummary = field(default_factory=lambda: ThermalSummary())

    def plan_summary(self) -> ThermalSummary | None:
        return self.thermal

    def to_dict(self) -> ThermalRunReportJson:
        return {**super().to_dict(), "thermal": self.thermal}


def poses_for(cfg: StationConfig, role: str) -> list[PoseSpec]:
    """The poses of a set point: the design at a calibration set point, the verification poses (at
    least one) at a verification set point."""
    if role == "calibrate":
        return get_design(cfg.design)
    design = get_design(cfg.verify_design or cfg.design)
    return design[:max(cfg.verify_poses, 1)]


@dataclass
class BoardPlan:
    """One board's part of a thermal plan (module docstring): what its set points gave, its poses
    by set point, its soak time, its table's verification and verdict."""

    cfg: StationConfig
    plan: ThermalPlan
    steps: BoardSteps  # the board's own steps: its sample counts and its words
    results: list[SetPointResult] = field(default_factory=list)
    groups: Groups = field(default_factory=dict)
    soak_s: float = 0.0
    report_events: list[str] = field(default_factory=list)
    verify: list[VerifyRow] = field(default_factory=list)
    table_verdict: TableVerdict | None = None

    def where(self, of_visits: bool) -> str:
        """Where in the plan the board's run ended (``of_visits``: with the set point's number)."""
        if not self.results:
            return "before the first set point"
        r = self.results[-1]
        poses = sum(x.poses for x in self.results)
        if not of_visits:
            return f"at set point {r.set_point_c:g} C, {poses} poses captured"
        of = f"{len(self.results)}/{len(self.plan.visits())}"
        return f"at set point {r.set_point_c:g} C ({of}), {poses} poses captured"

    # -- fit, table, verify, burn ----------------------------------------------------------
    def fit_each(self, cpg: float, rep: RunReport) -> tuple[list[tuple[float, FitResult]], list[Reason]]:
        """Fit and judge each calibration set point: (mean board temperature, fit) and the reasons."""
        fits: list[tuple[float, FitResult]] = []
        reasons: list[Reason] = []
        done: list[SetPointFit] = []
        for res in (r for r in self.results if r.role == "calibrate"):
            sp = res.set_point_c
            temps = np.array([p.temp_c for p in self.groups[sp]], dtype=float)
            session = Session(self.groups[sp], "counts", cpg, device=rep.serial,  # model 9's norm: the site
                              metadata={"site": dict(self.cfg.site.to_json())})
            try:
                fit = fit_session(session, self.cfg.model)
            except UnderdeterminedError as e:
                res.verdict, res.reasons = "FAIL", [Reason("fit", str(e))]
                reasons.append(wrap(Reason("fit", str(e)), f"at {sp:g} C: "))
                continue
            v = judge(fit, self.cfg.limits)
            res.fit = {"residual_rms_mg": fit.residual_rms_g * 1e3, "V_mg": (fit.V * 1e3).tolist(), **v.measured}
            res.verdict, res.reasons = v.label, v.reasons
            reasons += [wrap(r, f"at {sp:g} C: ") for r in v.reasons]
            fits.append((float(np.mean(temps)), fit))
            done.append((sp, float(np.mean(temps)), fit, session))
        budgets = set_point_budgets(self.cfg, self.plan.temperature_u_c, done, rep, cpg)
        for res in self.results:
            res.uncertainty = budgets.get(res.set_point_c) if res.role == "calibrate" else None
        return fits, reasons

    def fit_table_burn(self, driver: Driver, rep: RunReport) -> None:
        """Every set point's fit, the table, its verification and verdict, then its burn."""
        cfg, plan, cpg = self.cfg, self.plan, driver.counts_per_g
        fits, reasons = self.fit_each(cpg, rep)
        if len(fits) < len(plan.set_points_c):
            rep.record(Stage.FIT, *reasons)
            return
        table = TemperatureTable([t for t, _ in fits], [f.W for _, f in fits], [f.V for _, f in fits],
                                 [f.Gamma for _, f in fits], plan.method)
        cal = Calibration(cfg.model, table.W[0], table.V[0], table.Gamma[0], "counts", cpg, temperature=table,
                          metadata={"thermal": {"set_points_c": list(plan.set_points_c), "method": plan.method},
                                    "site": cfg.site.to_metadata()})
        ref_t, ref_fit = min(fits, key=lambda tf: abs(tf[0] - plan.reference_c))
        rep.calibration, rep.fit = cal, ref_fit
        rep.measured = judge(ref_fit, cfg.limits).measured
        reasons += self._verify_table(cal, ref_t, ref_fit)
        rep.verify_error_max_mg = max((v["error_max_mg"] for v in self.verify), default=None)
        if rep.verify_error_max_mg is not None:
            rep.measured["verify_error_max_mg"] = rep.verify_error_max_mg
        self.table_verdict = {"verdict": "FAIL" if reasons else "PASS", "reasons": [str(r) for r in reasons]}
        if reasons:
            rep.record(Stage.ACCEPTANCE, *reasons)
            self.steps.echo("FAIL before writing: " + "; ".join(reasons))
            return
        rep.record(Stage.JUDGED)
        if cfg.nvm_write:
            self.burn_table(driver, cal, rep)

    def _verify_table(self, cal: Calibration, ref_t: float, ref_fit: FitResult) -> list[Reason]:
        """The table at each verification set point (temperatures not used in the fit), beside the single
        calibration nearest the reference temperature; the reasons it fails."""
        limit = self.cfg.limits.values.get("verify_error_max_mg")
        reasons: list[Reason] = []
        self.verify = []
        for res in (r for r in self.results if r.role == "verify"):
            recs = self.groups[res.set_point_c]
            ref = np.array([p.reference_g for p in recs])
            x = np.array([p.mean for p in recs])
            t = np.array([p.temp_c for p in recs])
            try:
                with_table = float(np.max(np.abs(cal.apply(x, units="counts", temp_c=t) - ref))) * 1e3
            except AccelcalError as e:
                reasons.append(Reason.of("verify", f"verify at {res.set_point_c:g} C: {e}"))
                continue
            single = float(np.max(np.abs(ref_fit.calibration.apply(x, units="counts") - ref))) * 1e3
            res.verify_error_max_mg, res.without_table_error_max_mg = with_table, single
            res.verdict = "PASS" if limit is None or with_table <= limit else "FAIL"
            self.verify.append({"set_point_c": res.set_point_c, "board_temp_c": float(np.mean(t)),
                                "error_max_mg": with_table, "without_table_error_max_mg": single,
                                "without_table_calibration_c": ref_t, "limit_mg": limit,
                                "within_limit": limit is None or with_table <= limit,
                                "without_table_within_limit": limit is None or single <= limit})
            self.steps.echo(f"verify at {res.set_point_c:g} C: {with_table:.3f} mg with the table, "
                            f"{single:.3f} mg with the {ref_t:.1f} C calibration alone (limit {limit} mg)")
            if limit is not None and not with_table <= limit:
                reasons.append(Reason.of("verify_error_max_mg", f"verify at {res.set_point_c:g} C: "
                                         f"verify_error_max_mg {with_table:.4g} > limit {limit:g}"))
        return reasons

    def burn_table(self, driver: Driver, cal: Calibration, rep: RunReport) -> None:
        """Burn the table, read it back, and check it does what the fitted one did at the verification poses."""
        if driver.nvm is None:
            rep.record(Stage.NVM, Reason("nvm", "the device has no NVM to write; set nvm.write: false"))
            return
        writer = CalibrationWriter(driver.nvm, self.cfg.slot_size)
        try:
            outcome = writer.burn(cal, rep.serial, self.cfg.station_id)
        except BurnError as e:
            rep.nvm = e.outcome.to_dict()
            rep.record(Stage.NVM, Reason("nvm", str(e)))
            return
        rep.nvm = outcome.to_dict()
        back = writer.read_newest(rep.serial, settled=True)
        if back is None or back[0].temperature is None:
            writer.revert(outcome)  # a FAIL never leaves the unverified table as the board's newest
            rep.nvm = outcome.to_dict()
            rep.record(Stage.NVM, Reason("nvm", f"no temperature table readable after writing; {holds_text(outcome)}"))
            return
        stored, table = back[0], back[0].temperature
        assert cal.temperature is not None, "a thermal plan's calibration carries its table"
        recs = [p for r in self.results if r.role == "verify" for p in self.groups.get(r.set_point_c, [])]
        x, t = np.array([p.mean for p in recs]), np.array([p.temp_c for p in recs])
        same = np.allclose(stored.apply(x, units="counts", temp_c=t), cal.apply(x, units="counts", temp_c=t),
                           atol=1e-9) and np.allclose(table.temps_c, cal.temperature.temps_c)
        rep.nvm_verified = bool(same)
        if not same:
            writer.revert(outcome)
            rep.nvm = outcome.to_dict()
            rep.record(Stage.NVM, Reason("nvm", "the table read back from NVM differs from the fitted one; "
                                         f"{holds_text(outcome)}"))
            return
        self.steps.echo(f"NVM: slot {outcome.slot}, generation {outcome.generation}, {outcome.length} bytes, "
                        f"{len(table.temps_c)}-temperature table read back"
                        + (" and verified" if same else " DIFFERS"))

    # -- report ----------------------------------------------------------------------------
    def timing(self, driver: Driver, clock: Clock, t0: float, wall0: float) -> Timing:
        """Time per board: soak, the warm-up hold, the sampling floor (samples averaged / ODR) and the rest
        (moves, gating, I/O)."""
        total = clock.now() - t0
        used, read = self.steps.samples_used, self.steps.samples_read
        floor = used / driver.odr_hz
        warm = self.steps.warmup_s
        return {"odr_hz": driver.odr_hz, "samples_averaged": used, "samples_read": read,
                "board_time_s": total, "soak_s": self.soak_s, "warmup_s": warm, "sampling_floor_s": floor,
                "sampling_s": read / driver.odr_hz, "rest_s": total - self.soak_s - warm - floor,
                "boards": 1, "per_board_s": total, "clock": "real" if clock.realtime else "virtual",
                "host_compute_s": time.perf_counter() - wall0}

    def summary(self, rep: RunReport, panel: PanelOfPlan | None = None) -> ThermalSummary:
        p = self.plan
        table = rep.calibration.temperature if rep.calibration is not None else None
        return {"set_points_c": list(p.set_points_c), "verify_set_points_c": list(p.verify_set_points_c),
                "method": p.method, "soak": p.soak.__dict__,
                "temp_source": self.results[0].temp_source if self.results else None,
                "visits": [r.to_dict() for r in self.results],
                "table": None if table is None else {"temps_c": table.temps_c.tolist(), "method": table.method,
                                                     **(self.table_verdict or {})},
                "verify": self.verify, "panel": panel}

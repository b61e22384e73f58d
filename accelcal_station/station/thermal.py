"""Temperature calibration at the station: a thermal plan run in a chamber (AN4399 section 9).

For each set point (ascending, calibration and verification set points together, so the
chamber travels one way): set the chamber, soak until the board's temperature is stable,
run the pose design with the configured jig and record every pose with its temperature.
Then fit one calibration per calibration temperature, judge each, build the temperature
table (AN4399 Eqns 83-92, piecewise ``linear`` or ``quadratic``), verify it on the poses
captured at the verification set points (temperatures not used in the fit), judge the table,
burn it (A/B slot, CRC) and read it back.  A chamber that never reaches its set point, an
alarm, a door opened during a capture, or a board that drifts out of its band during the
poses ends the run with a recorded FAIL verdict and its reason; nothing is burned.

The plan, the soak rule and the chamber's faults: thermal_plan.py.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np

from ..acceptance.reasons import Reason, wrap
from ..acceptance.rules import judge
from ..calibration import Calibration, TemperatureTable
from ..drivers.base import Clock, Driver
from ..errors import AccelcalError, ConfigError, NVMError, PortLostError, UnderdeterminedError
from ..fixtures.base import Jig, PoseSpec
from ..fixtures.designs import get_design
from ..fixtures.factory import board_of, clock_of, make_jig
from ..instruments.chamber import Chamber, ChamberStatus
from ..instruments.factory import make_chamber
from ..models.fitting import fit_session
from ..models.result import FitResult
from ..nvm.writer import BurnError, CalibrationWriter, holds_text
from ..session import PoseRecord, Session
from ..store.runs import Store
from .board import Station
from .capture import WrongPose
from .recording import record_result, start_args
from .report import RunReport, Timing
from .settings import StationConfig
from .thermal_plan import ChamberFault, ThermalPlan, WallClock, soak_until
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
    fit: dict[str, Any] | None = None
    verdict: str | None = None
    reasons: list[Reason] = field(default_factory=list)
    verify_error_max_mg: float | None = None
    without_table_error_max_mg: float | None = None
    t_start_s: float = 0.0
    t_soaked_s: float | None = None
    t_end_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)

    def pose_temp_c(self, capture_temp_c: float | None, air_c: float) -> float:
        """A pose's board temperature: the die's during the capture, else the chamber air's."""
        temp = capture_temp_c if self.temp_source == "die" else air_c
        assert temp is not None, "a chip with a temperature sensor reads it with every capture"
        return temp

    def moved_c(self, temp_c: float) -> float:
        """How far a pose's board temperature is from the soaked one (the capture band's test)."""
        assert self.board_temp_c is not None, "poses are captured after the soak"
        return abs(temp_c - self.board_temp_c)


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


@dataclass
class ThermalRunReport(RunReport):
    """A board's run report with its thermal plan's summary (``thermal``)."""

    thermal: dict[str, Any] = field(default_factory=dict)

    def plan_summary(self) -> dict[str, Any] | None:
        return self.thermal

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "thermal": self.thermal}


class ThermalStation(Station):
    """Runs a thermal plan for one board (module docstring); ``run()`` returns a ThermalRunReport."""

    def __init__(self, config: StationConfig, **kw: Any) -> None:
        super().__init__(config, **kw)
        thermal, chamber = config.schema.thermal, config.schema.chamber
        if thermal is None or chamber is None:
            raise ConfigError(f"{config.path}: a thermal plan needs both thermal: and chamber: sections")
        if config.offset_trim:
            raise ConfigError("nvm.offset_trim: not with a thermal plan (the offset moves with temperature); "
                              "allowed: false")
        self.plan = ThermalPlan.from_section(thermal, config.model)
        self.chamber_section = chamber
        self.results: list[SetPointResult] = []
        self.soak_s = 0.0
        self.report_events: list[str] = []
        self.verify: list[VerifyRow] = []
        self.table_verdict: TableVerdict | None = None

    # -- the run (Station.run, with the chamber's set points as the conditions) --------------
    def _new_report(self) -> ThermalRunReport:
        cfg = self.cfg
        return ThermalRunReport(station_id=cfg.station_id, model=cfg.model, design=cfg.design,
                                store=str(cfg.store_file))

    def _announce(self, rep: RunReport) -> None:
        """Nothing: a thermal plan's limits are said at each set point."""

    def _device_clock(self, driver: Driver) -> Clock:
        return clock_of(driver) or WallClock()  # the device's clock, from the factory

    def _calibrate(self, store: Store, run_id: int, driver: Driver, clock: Clock | None, session: Session,
                   retries: list[int], rep: RunReport) -> None:
        """Every set point in the chamber, then the table, its verdict and its burn; a chamber fault or
        a lost port ends the run FAIL (recorded), any other error or Ctrl-C interrupts it."""
        assert clock is not None, "a thermal plan runs on its device's clock or the wall's"
        records = session.poses
        assert isinstance(records, list), "a station's session is the list its poses are captured into"
        try:
            with make_chamber(self.chamber_section, board_of(driver)) as chamber, \
                    make_jig(self.cfg.jig, driver, self.ui) as jig:
                jig.mount = self.mount
                self._plan(driver, chamber, jig, clock, records, retries, rep)
        except (AccelcalError, KeyboardInterrupt) as e:
            if isinstance(e, ChamberFault):
                rep.record(Stage.CHAMBER, Reason("chamber", str(e)))
                self.echo(f"FAIL: chamber: {e} (nothing burned)")
            elif isinstance(e, (PortLostError, NVMError)):  # a lost sensor/jig port, unsettled NVM reads
                rep.record(Stage.FAULT, Reason(e.reason_code, f"{e} ({self._where()})"))
                self.echo(f"FAIL: {e} ({len(records)} poses captured)")
            else:
                why = "interrupted" if isinstance(e, KeyboardInterrupt) else str(e)
                store.interrupt_run(run_id, f"{why} ({self._where()})", session=session if records else None,
                                    status="interrupted" if isinstance(e, KeyboardInterrupt) else "error",
                                    retries=retries if records else None, nvm_outcome=rep.nvm)
                raise

    def _timing(self, driver: Driver, clock: Clock | None, clock0: float | None, wall0: float) -> Timing:
        assert clock is not None and clock0 is not None, "a thermal plan's clock started with its run"
        return self._thermal_timing(driver, clock, clock0, wall0)

    def _finish(self, store: Store, run_id: int, session: Session, retries: list[int], rep: RunReport) -> None:
        """Record the finished run with the plan's events and summary."""
        assert isinstance(rep, ThermalRunReport), "a thermal plan's run report (_new_report)"
        rep.events.extend(self.report_events)
        rep.thermal = self._summary(rep)
        self._record_run(store, run_id, session, retries, rep)

    def _record_run(self, store: Store, run_id: int, session: Session, retries: list[int],
                    rep: ThermalRunReport) -> None:
        """Record the finished run with the plan's summary (or keep it in the outbox: recording.py)."""
        finish = {"session": session, "calibration": rep.calibration,
                  "verdict": rep.verdict, "reasons": rep.reasons, "nvm_outcome": rep.nvm,
                  "fit_summary": {"measured": rep.measured, "verify_error_max_mg": rep.verify_error_max_mg,
                                  "design": self.cfg.design, "timing": rep.timing, "thermal": rep.thermal,
                                  "nvm_verified": rep.nvm_verified, "self_test": rep.self_test},
                  "model": self.cfg.model, "retries": retries,
                  "limits": self.cfg.limits.values}
        record_result(store, run_id, start_args(self.cfg, rep, self.operator, self.lot, session.counts_per_g),
                      finish, self.cfg.outbox)

    def _where(self) -> str:
        if not self.results:
            return "before the first set point"
        r = self.results[-1]
        return f"at set point {r.set_point_c:g} C ({len(self.results)}/{len(self.plan.visits())}), " \
               f"{sum(x.poses for x in self.results)} poses captured"

    def _plan(self, driver: Driver, chamber: Chamber, jig: Jig, clock: Clock, records: list[PoseRecord],
              retries: list[int], rep: RunReport) -> None:
        try:
            self._visit_all(driver, chamber, jig, clock, records, retries, rep)
        except BaseException:
            with contextlib.suppress(AccelcalError):
                chamber.standby()  # leave the chamber safe; the original error is what matters
            raise

    def _visit_all(self, driver: Driver, chamber: Chamber, jig: Jig, clock: Clock, records: list[PoseRecord],
                   retries: list[int], rep: RunReport) -> None:
        visits = self.plan.visits()
        groups: Groups = {}
        for i, (sp, role) in enumerate(visits):
            self.echo(f"[set point {i + 1}/{len(visits)}] {sp:g} C ({role})")
            res = SetPointResult(sp, role, t_start_s=clock.now())
            self.results.append(res)
            chamber.set_point(sp)
            self._soak(driver, chamber, clock, res)
            # calibration poses go to the run's session as they come: an interrupted run keeps them
            sink = (records, retries) if role == "calibrate" else None
            groups[sp] = self._capture_set_point(driver, chamber, jig, clock, self._poses_for(role), res, rep, sink)
            if self.progress:
                self.progress("set points", (i + 1) / len(visits))
        chamber.standby()
        self._fit_table_burn(driver, groups, rep)

    def _poses_for(self, role: str) -> list[PoseSpec]:
        if role == "calibrate":
            return get_design(self.cfg.design)
        design = get_design(self.cfg.verify_design or self.cfg.design)
        return design[:max(self.cfg.verify_poses, 1)]

    # -- soak and capture --------------------------------------------------------------
    def _check_alarms(self, st: ChamberStatus, context: str) -> None:
        if st.door_open:
            raise ChamberFault("door open", f"door opened {context} (alarm {st.alarm_text()})")
        if st.alarms:
            raise ChamberFault("alarm", f"alarm {st.alarm_text()} {context}")
        if st.mode != "CONSTANT":
            raise ChamberFault("stopped", f"the chamber left constant mode ({st.mode}) {context}")

    def _soak(self, driver: Driver, chamber: Chamber, clock: Clock, res: SetPointResult) -> None:
        """Wait until the soak rule holds (thermal_plan.py); ChamberFault on timeout or alarm."""
        has_sensor = driver.temperature_c() is not None
        res.temp_source = "die" if has_sensor else "chamber_air"
        if not has_sensor and len(self.results) == 1:
            note = (f"{driver.name}: the chip has no temperature sensor; the soak and every pose use the "
                    "chamber air temperature (the board is taken to be at the air temperature after the soak)")
            self.echo(f"  note: {note}")
            self.report_events.append(note)
        read = (lambda st: np.array([driver.temperature_c()])) if has_sensor else (lambda st: np.array([st.air_c]))
        try:
            soak_s, temps, air_c, now = soak_until(self.plan.soak, res.set_point_c, chamber, clock, read,
                                                   self._check_alarms, self.echo)
        except ChamberFault as e:
            res.soak_s = e.soak_s
            self.soak_s += e.soak_s
            raise
        self.soak_s += soak_s
        res.soak_s, res.board_temp_c, res.air_temp_c, res.t_soaked_s = soak_s, float(temps[0]), air_c, now
        self.echo(f"  soaked in {soak_s:.0f} s: board {temps[0]:.2f} C ({res.temp_source}), air {air_c:.1f} C")

    def _capture_set_point(self, driver: Driver, chamber: Chamber, jig: Jig, clock: Clock, poses: list[PoseSpec],
                           res: SetPointResult, rep: RunReport, sink: tuple[list[PoseRecord], list[int]] | None
                           ) -> list[PoseRecord]:
        used0, t0 = self.samples_used, clock.now()
        floor: np.ndarray | None = None
        out: list[PoseRecord] = []
        sp = res.set_point_c
        deferred: WrongPose | None = None  # a wrong pose another mounting may explain: read on (Station._defer)
        for k, pose in enumerate(poses):
            self.echo(f"  [{k + 1}/{len(poses)}] {pose.name}")
            try:
                gc, tries = self._capture_pose(driver, jig, pose, floor, rep)
            except WrongPose as e:
                deferred = self._defer(jig, pose, e, deferred)
                continue
            st = chamber.status()
            self._check_alarms(st, f"during the capture of {pose.name} at {sp:g} C; the capture is discarded")
            floor, c = gc.floor_counts, gc.capture
            temp = res.pose_temp_c(c.temp_c, st.air_c)
            if res.moved_c(temp) > self.plan.capture_band_c:
                raise ChamberFault("temperature moved", f"board temperature {temp:.2f} C during {pose.name} at "
                                   f"{sp:g} C left the band +-{self.plan.capture_band_c:g} C around "
                                   f"{res.board_temp_c:.2f} C")
            pitch, roll = self._chip_angles(pose)
            rec = PoseRecord(f"{pose.name}@{sp:g}C", c.mean_counts, c.std_counts, c.n, self.mount @ pose.reference_g,
                             pitch, roll, temp, c.dropped, c.t_start, c.t_end)
            out.append(rec)
            if sink is not None:
                sink[0].append(rec)
                sink[1].append(tries + gc.recaptures)
            rep.poses.append({"pose": rec.name, "set_point_c": sp, "role": res.role, "temp_c": temp, "n": c.n,
                              "sem_mg": (c.sem_counts / driver.counts_per_g * 1e3).tolist(),
                              "retries": tries + gc.recaptures})
            res.poses += 1
        if deferred is not None:
            raise deferred
        res.sampling_floor_s = (self.samples_used - used0) / driver.odr_hz
        res.t_end_s = clock.now()
        res.poses_s = res.t_end_s - t0
        return out

    # -- fit, table, verify, burn ----------------------------------------------------------
    def _fit_each(self, groups: Groups, cpg: float, rep: RunReport
                  ) -> tuple[list[tuple[float, FitResult]], list[Reason]]:
        """Fit and judge each calibration set point: (mean board temperature, fit) and the reasons."""
        fits: list[tuple[float, FitResult]] = []
        reasons: list[Reason] = []
        for res in (r for r in self.results if r.role == "calibrate"):
            sp = res.set_point_c
            temps = np.array([p.temp_c for p in groups[sp]], dtype=float)
            try:
                fit = fit_session(Session(groups[sp], "counts", cpg, device=rep.serial), self.cfg.model)
            except UnderdeterminedError as e:
                res.verdict, res.reasons = "FAIL", [Reason("fit", str(e))]
                reasons.append(wrap(Reason("fit", str(e)), f"at {sp:g} C: "))
                continue
            v = judge(fit, self.cfg.limits)
            res.fit = {"residual_rms_mg": fit.residual_rms_g * 1e3, "V_mg": (fit.V * 1e3).tolist(), **v.measured}
            res.verdict, res.reasons = v.label, v.reasons
            reasons += [wrap(r, f"at {sp:g} C: ") for r in v.reasons]
            fits.append((float(np.mean(temps)), fit))
        return fits, reasons

    def _fit_table_burn(self, driver: Driver, groups: Groups, rep: RunReport) -> None:
        cfg, plan, cpg = self.cfg, self.plan, driver.counts_per_g
        fits, reasons = self._fit_each(groups, cpg, rep)
        if len(fits) < len(plan.set_points_c):
            rep.record(Stage.FIT, *reasons)
            return
        table = TemperatureTable([t for t, _ in fits], [f.W for _, f in fits], [f.V for _, f in fits],
                                 [f.Gamma for _, f in fits], plan.method)
        cal = Calibration(cfg.model, table.W[0], table.V[0], table.Gamma[0], "counts", cpg, temperature=table,
                          metadata={"thermal": {"set_points_c": list(plan.set_points_c), "method": plan.method}})
        ref_t, ref_fit = min(fits, key=lambda tf: abs(tf[0] - plan.reference_c))
        rep.calibration, rep.fit = cal, ref_fit
        rep.measured = judge(ref_fit, cfg.limits).measured
        limit = cfg.limits.values.get("verify_error_max_mg")
        self.verify = []
        for res in (r for r in self.results if r.role == "verify"):
            recs = groups[res.set_point_c]
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
            self.echo(f"verify at {res.set_point_c:g} C: {with_table:.3f} mg with the table, "
                      f"{single:.3f} mg with the {ref_t:.1f} C calibration alone (limit {limit} mg)")
            if limit is not None and not with_table <= limit:
                reasons.append(Reason.of("verify_error_max_mg", f"verify at {res.set_point_c:g} C: verify_error_max_mg "
                                          f"{with_table:.4g} > limit {limit:g}"))
        rep.verify_error_max_mg = max((v["error_max_mg"] for v in self.verify), default=None)
        if rep.verify_error_max_mg is not None:
            rep.measured["verify_error_max_mg"] = rep.verify_error_max_mg
        self.table_verdict = {"verdict": "FAIL" if reasons else "PASS", "reasons": [str(r) for r in reasons]}
        if reasons:
            rep.record(Stage.ACCEPTANCE, *reasons)
            self.echo("FAIL before writing: " + "; ".join(reasons))
            return
        rep.record(Stage.JUDGED)
        if cfg.nvm_write:
            self._burn_table(driver, cal, groups, rep)

    def _burn_table(self, driver: Driver, cal: Calibration, groups: Groups, rep: RunReport) -> None:
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
        recs = [p for r in self.results if r.role == "verify" for p in groups.get(r.set_point_c, [])]
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
        self.echo(f"NVM: slot {outcome.slot}, generation {outcome.generation}, {outcome.length} bytes, "
                  f"{len(table.temps_c)}-temperature table read back"
                  + (" and verified" if same else " DIFFERS"))

    # -- report ----------------------------------------------------------------------------
    def _thermal_timing(self, driver: Driver, clock: Clock, t0: float, wall0: float) -> Timing:
        """Time per board: soak, the sampling floor (samples averaged / ODR) and the rest (moves, gating, I/O)."""
        total = clock.now() - t0
        floor = self.samples_used / driver.odr_hz
        return {"odr_hz": driver.odr_hz, "samples_averaged": self.samples_used, "samples_read": self.samples_read,
                "board_time_s": total, "soak_s": self.soak_s, "sampling_floor_s": floor,
                "sampling_s": self.samples_read / driver.odr_hz, "rest_s": total - self.soak_s - floor,
                "boards": 1, "per_board_s": total, "clock": "real" if clock.realtime else "virtual",
                "host_compute_s": time.perf_counter() - wall0}

    def _summary(self, rep: RunReport) -> dict[str, Any]:
        p = self.plan
        table = rep.calibration.temperature if rep.calibration is not None else None
        return {"set_points_c": list(p.set_points_c), "verify_set_points_c": list(p.verify_set_points_c),
                "method": p.method, "soak": p.soak.__dict__,
                "temp_source": self.results[0].temp_source if self.results else None,
                "visits": [r.to_dict() for r in self.results],
                "table": None if table is None else {"temps_c": table.temps_c.tolist(), "method": table.method,
                                                     **(self.table_verdict or {})},
                "verify": self.verify, "panel": None}

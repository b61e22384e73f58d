"""The thermal conditions of the station's flow: a thermal plan run in a chamber (AN4399 section 9).

For each set point (ascending, calibration and verification set points together, so the
chamber travels one way): set the chamber, soak until the boards' temperatures are stable,
run the pose design with the configured jig and record every pose with its temperature.
Then each board's calibration per calibration temperature, its temperature table, verified
on the poses captured at the verification set points (temperatures not used in the fit), its
verdict, burn and read-back (thermal_table.py).  A chamber that never reaches its set point,
an alarm, a door opened during a capture, or a board that drifts out of its band during the
poses ends the run with a recorded FAIL verdict and its reason; nothing is burned.

A single board is captured alone here (flow.FlowPolicy.wrong_pose_ends_run); a panel's boards
at once, soaked together in one chamber (thermal_panel.py).  The plan, the soak rule and the
chamber's faults: thermal_plan.py.
"""
from __future__ import annotations

import numpy as np

from ..acceptance.reasons import Reason
from ..drivers.base import Clock, Driver
from ..errors import AccelcalError, ConfigError, NVMError, PortLostError
from ..fixtures.base import Jig
from ..fixtures.factory import board_of, clock_of, make_jig
from ..instruments.chamber import Chamber
from ..instruments.factory import make_chamber
from ..session import PoseRecord
from .capture import WrongPose
from .panel import PanelBoard
from .policy import FlowView, panel_why, stopped_by_operator
from .recording import RunSummary, panel_summary, thermal_summary
from .report import PanelOfPlan
from .settings import StationConfig
from .thermal_panel import ThermalPanel
from .thermal_plan import ChamberFault, ThermalPlan, WallClock, check_alarms, soak_until, standby
from .thermal_table import BoardPlan, SetPointResult, ThermalRunReport, poses_for
from .verdict import Stage


class ThermalConditions:
    """The boards calibrated at each set point of a thermal plan (module docstring)."""

    # a lost sensor or jig port, unsettled NVM reads: the run ends FAIL (recorded); a chamber's
    # fault is handled where it happens (CHAMBER), anything else interrupts every run
    ending_faults: tuple[type[AccelcalError], ...] = (PortLostError, NVMError)

    def __init__(self, config: StationConfig) -> None:
        thermal, chamber = config.schema.thermal, config.schema.chamber
        if thermal is None or chamber is None:
            raise ConfigError(f"{config.path}: a thermal plan needs both thermal: and chamber: sections")
        if config.offset_trim:
            raise ConfigError("nvm.offset_trim: not with a thermal plan (the offset moves with temperature); "
                              "allowed: false")
        self.cfg = config
        self.plan = ThermalPlan.from_section(thermal, config.model)
        self.chamber_section = chamber
        self.boards: dict[int, BoardPlan] = {}  # each board's part of the plan, by its index
        self.panel: ThermalPanel | None = None  # a panel's shared soaks, captures and clock

    def new_report(self, cfg: StationConfig) -> ThermalRunReport:
        return ThermalRunReport(station_id=cfg.station_id, model=cfg.model, design=cfg.design,
                                store=str(cfg.store_file))

    def clock(self, driver: Driver) -> Clock:
        return clock_of(driver) or WallClock()  # the device's clock, from the factory

    def of(self, b: PanelBoard) -> BoardPlan:
        """The board's part of the plan."""
        if b.index not in self.boards:
            self.boards[b.index] = BoardPlan(self.cfg, self.plan, b.steps)
        return self.boards[b.index]

    def calibrate(self, flow: FlowView, boards: list[PanelBoard]) -> None:
        """Every set point in the chamber, then each board's table, its verdict and its burn; a chamber
        fault ends every board's run FAIL (recorded)."""
        for b in boards:
            self.of(b)
        if not flow.policy.wrong_pose_ends_run:
            self.panel = ThermalPanel(self.plan, self.chamber_section, self.of, flow)
            self.panel.calibrate(boards)
            return
        b = boards[0]
        if not b.active:
            return
        try:
            with make_chamber(self.chamber_section, board_of(b.driver)) as chamber, \
                    (flow.panel.jig or make_jig(self.cfg.jig, b.driver, flow.ui)) as jig:
                jig.mount = b.steps.mount
                try:
                    self._visit_all(flow, b, chamber, jig)
                except BaseException:
                    standby(chamber)
                    raise
        except ChamberFault as e:
            b.rep.record(Stage.CHAMBER, Reason("chamber", str(e)))
            flow.echo(f"FAIL: chamber: {e} (nothing burned)")

    def _visit_all(self, flow: FlowView, b: PanelBoard, chamber: Chamber, jig: Jig) -> None:
        visits = self.plan.visits()
        plan, clock = self.of(b), b.clock
        assert clock is not None, "a thermal plan runs on its device's clock or the wall's"
        for i, (sp, role) in enumerate(visits):
            flow.echo(f"[set point {i + 1}/{len(visits)}] {sp:g} C ({role})")
            res = SetPointResult(sp, role, t_start_s=clock.now())
            plan.results.append(res)
            chamber.set_point(sp)
            self._soak(flow, b, chamber, clock, res)
            plan.groups[sp] = self._capture_set_point(flow, b, chamber, jig, clock, res)
            if flow.progress:
                flow.progress("set points", (i + 1) / len(visits))
        chamber.standby()
        plan.fit_table_burn(b.driver, b.rep)

    def _soak(self, flow: FlowView, b: PanelBoard, chamber: Chamber, clock: Clock, res: SetPointResult) -> None:
        """Wait until the soak rule holds (thermal_plan.py); ChamberFault on timeout or alarm."""
        driver, plan = b.driver, self.of(b)
        has_sensor = driver.temperature_c() is not None
        res.temp_source = "die" if has_sensor else "chamber_air"
        if not has_sensor and len(plan.results) == 1:
            note = (f"{driver.name}: the chip has no temperature sensor; the soak and every pose use the "
                    "chamber air temperature (the board is taken to be at the air temperature after the soak)")
            flow.echo(f"  note: {note}")
            plan.report_events.append(note)
        read = (lambda st: np.array([driver.temperature_c()])) if has_sensor else (lambda st: np.array([st.air_c]))
        try:
            soak_s, temps, air_c, now = soak_until(self.plan.soak, res.set_point_c, chamber, clock, read,
                                                   check_alarms, flow.echo)
        except ChamberFault as e:
            res.soak_s = e.soak_s
            plan.soak_s += e.soak_s
            raise
        plan.soak_s += soak_s
        res.soak_s, res.board_temp_c, res.air_temp_c, res.t_soaked_s = soak_s, float(temps[0]), air_c, now
        flow.echo(f"  soaked in {soak_s:.0f} s: board {temps[0]:.2f} C ({res.temp_source}), air {air_c:.1f} C")

    def _capture_set_point(self, flow: FlowView, b: PanelBoard, chamber: Chamber, jig: Jig, clock: Clock,
                           res: SetPointResult) -> list[PoseRecord]:
        """The set point's poses on a board alone (board.BoardSteps.capture_pose); its calibration poses go to
        the run's session as they come (an interrupted run keeps them)."""
        steps, rep, driver = b.steps, b.rep, b.driver
        poses = poses_for(self.cfg, res.role)
        used0, t0 = steps.samples_used, clock.now()
        floor: np.ndarray | None = None
        out: list[PoseRecord] = []
        sp = res.set_point_c
        deferred: WrongPose | None = None  # a wrong pose another mounting may explain: read on (BoardSteps.defer)
        for k, pose in enumerate(poses):
            flow.echo(f"  [{k + 1}/{len(poses)}] {pose.name}")
            try:
                gc, tries = steps.capture_pose(driver, jig, pose, floor, rep)
            except WrongPose as e:
                deferred = steps.defer(jig, pose, e, deferred)
                continue
            st = chamber.status()
            check_alarms(st, f"during the capture of {pose.name} at {sp:g} C; the capture is discarded")
            floor, c = gc.floor_counts, gc.capture
            temp = res.pose_temp_c(c.temp_c, st.air_c)
            if res.moved_c(temp) > self.plan.capture_band_c:
                raise ChamberFault("temperature moved", f"board temperature {temp:.2f} C during {pose.name} at "
                                   f"{sp:g} C left the band +-{self.plan.capture_band_c:g} C around "
                                   f"{res.board_temp_c:.2f} C")
            pitch, roll = steps.chip_angles(pose)
            rec = PoseRecord(f"{pose.name}@{sp:g}C", c.mean_counts, c.std_counts, c.n, steps.expected_g(pose),
                             pitch, roll, temp, c.dropped, c.t_start, c.t_end, c.n_eff)
            out.append(rec)
            if res.role == "calibrate":
                b.records.append(rec)
                b.retries.append(tries + gc.recaptures)
            rep.poses.append({"pose": rec.name, "set_point_c": sp, "role": res.role, "temp_c": temp, "n": c.n,
                              "sem_mg": (c.sem_counts / driver.counts_per_g * 1e3).tolist(),
                              "retries": tries + gc.recaptures})
            res.poses += 1
        if deferred is not None:
            raise deferred
        res.sampling_floor_s = (steps.samples_used - used0) / driver.odr_hz
        res.t_end_s = clock.now()
        res.poses_s = res.t_end_s - t0
        return out

    # -- ending, timing, recording ---------------------------------------------------------
    def fault_reason(self, flow: FlowView, b: PanelBoard, e: AccelcalError) -> tuple[str, bool]:
        """A single board's FAULT says where in the plan it came; a panel's says it in the events."""
        if flow.policy.single_board:
            return f"{e} ({self.of(b).where(of_visits=True)})", False
        return str(e), True

    def interruption(self, flow: FlowView, b: PanelBoard, e: BaseException) -> tuple[str, str]:
        """Why the run was closed early and where in the plan, and its status."""
        single = flow.policy.single_board
        where = self.of(b).where(of_visits=single)
        if single:  # a single board's operator abort is recorded as an error, as it always was
            ki = isinstance(e, KeyboardInterrupt)
            return f"{'interrupted' if ki else e} ({where})", "interrupted" if ki else "error"
        return f"{panel_why(e)} ({where})", "interrupted" if stopped_by_operator(e) else "error"

    def timing(self, flow: FlowView, boards: list[PanelBoard], wall0: float) -> None:
        """Each board's split (soak, sampling floor, rest); a panel's too (thermal_panel.py)."""
        if self.panel is not None:
            self.panel.timing(boards, wall0)
            return
        b = boards[0]
        assert b.clock is not None and b.clock0 is not None, "a thermal plan's clock started with its run"
        b.rep.timing = self.of(b).timing(b.driver, b.clock, b.clock0, wall0)

    def finish(self, flow: FlowView, b: PanelBoard) -> RunSummary:
        """The plan's events and summary on the board's report, and what the store keeps of the run."""
        rep, plan = b.rep, self.of(b)
        assert isinstance(rep, ThermalRunReport), "a thermal plan's run report (new_report)"
        if flow.policy.single_board:
            rep.events.extend(plan.report_events)
            rep.thermal = plan.summary(rep)
            return thermal_summary(flow.cfg, rep, rep.thermal)
        if b.open_:
            rep.events.extend(plan.report_events)
            rep.thermal = plan.summary(rep, PanelOfPlan(panel_id=flow.panel_id, boards=len(flow.boards)))
        return panel_summary(flow.cfg, rep, flow.panel_id, flow.panel.estimate, rep.plan_summary())

"""The station's one flow: a run is boards x conditions (DESIGN.md "The flow of one board", "Scale").

``StationFlow.run`` builds the boards (``panel.Panel``: 1..N boards on one jig; a single board
is a panel of one), opens the store, opens each board and starts its run, runs each board's
self-test, hands the boards still in the flow to its conditions (``room.RoomTemperature``: the
poses once at room temperature; ``thermal.ThermalConditions``: the chamber's set points and the
temperature table), then times, records and closes every run.  What a single board's run does
that a panel's does not is its ``FlowPolicy``, chosen once from the config, never a subclass.
``make_flow`` builds the flow a config asks for (`accelcal run`, a shift, the benchmarks).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Unpack

from ..acceptance.reasons import Reason
from ..config.serials import check_serial
from ..drivers.factory import make_driver
from ..errors import AccelcalError, DeviceError
from ..fixtures.base import Jig
from ..fixtures.factory import make_jig, sync_clocks
from ..store.outbox import open_store
from ..store.runs import Store
from .board import BoardSteps
from .flow_options import FlowOptions, FlowSetup
from .panel import Panel, PanelBoard, PanelTiming, board_rate, board_session, make_panel_jig
from .policy import Conditions, FlowPolicy
from .recording import FinishArgs, record_result, start_args, stored_uncertainty
from .report import RunReport
from .room import RoomTemperature
from .settings import StationConfig, configured_rate
from .station_fault import (
    is_station_fault,
    nvm_held_line,
    preflight_chamber,
    preflight_jig,
    station_fault_line,
    station_fault_reason,
)
from .thermal import ThermalConditions
from .verdict import Stage
from .warmup import hold_boards, power_ahead


def _raiser(e: AccelcalError) -> Callable[[], None]:
    """A step that raises ``e`` (a board's warm-up error, judged as its other steps' are)."""
    def step() -> None:
        raise e
    return step


def _quiet(_: str) -> None:
    """A board of a panel says nothing itself: the panel speaks for its boards."""


class StationFlow:
    """Runs boards x conditions: 1..N boards (``panel``), at room temperature or a thermal plan
    (``conditions``), a single board's differences in ``policy`` (module docstring)."""

    def __init__(self, config: StationConfig, conditions: Conditions, policy: FlowPolicy,
                 setup: FlowSetup) -> None:
        self.cfg = config
        self.conditions = conditions
        self.policy = policy
        self.ui = setup.ui  # the operator's front end (terminal or browser), for an operator jig
        self.operator, self.serial_override, self.lot, self.echo = setup.operator, setup.serial, setup.lot, setup.echo
        self.progress = setup.progress
        self.panel = Panel(config, setup.echo, setup.drivers, setup.jig, setup.ui)
        self.boards: list[PanelBoard] = []

    @property
    def panel_id(self) -> str | None:
        return self.policy.panel_id

    @property
    def run_id(self) -> int | None:
        """The first board's run, once started (a shift names an aborted board's run)."""
        return self.boards[0].rep.run_id if self.boards else None

    @property
    def timing(self) -> PanelTiming:
        """The panel's time (panel.Panel.timing); empty for a single board."""
        return self.panel.timing

    # -- the run ---------------------------------------------------------------------
    def run(self) -> list[RunReport]:
        """Open every board and start its run, calibrate them (the conditions), then time and record
        each run; the reports, one per board."""
        cfg = self.cfg
        wall0 = time.perf_counter()
        boards = self.boards = self.panel.build(self._steps, lambda: self.conditions.new_report(cfg),
                                                single=self.policy.single_board)
        with open_store(cfg.store_file, cfg.outbox, cfg.heartbeat_s) as store:
            store.mark_stale_interrupted()
            try:
                self._announce(boards[0].rep)
                self._preflight(store, boards)
                self._open_all(store, boards)
                self._calibrate(store, boards)
                if self.policy.closes_before_timing:
                    self.panel.close(boards)
                self.conditions.timing(self, boards, wall0)
                for b in boards:
                    self._record(store, b)
            finally:
                self.panel.close(boards)
        return [b.rep for b in boards]

    def _steps(self) -> BoardSteps:
        """A board's own steps: a single board speaks and shows its progress, a panel's boards do not."""
        p = self.policy
        return BoardSteps(self.cfg, echo=self.echo if p.single_board else _quiet,
                          progress=self.progress if p.single_board else None,
                          ui=self.ui if p.single_board else None, live_reading=p.live_reading)

    def _announce(self, rep: RunReport) -> None:
        """The safe default limits in use, said and kept with the run's events."""
        line = self.cfg.limits.defaults_line()
        if line and self.policy.says_default_limits:
            self.echo(line)
            rep.events.append(line)

    def _calibrate(self, store: Store, boards: list[PanelBoard]) -> None:
        """The conditions with the boards; an instrument's fault is the station's (``_station_fault``), an
        ending fault fails every board still in the flow, any other error or Ctrl-C closes each run
        (interrupted or error) with its poses, then propagates."""
        try:
            self.conditions.calibrate(self, boards)
        except (AccelcalError, KeyboardInterrupt) as e:
            if is_station_fault(e):
                self._station_fault(store, boards, e)
                if self.policy.single_board:
                    raise
                return
            if not isinstance(e, self.conditions.ending_faults):
                self._interrupted(store, boards, e)
                raise
            self._fault(boards, e)

    # -- opening ----------------------------------------------------------------------
    def _preflight(self, store: Store, boards: list[PanelBoard]) -> None:
        """Open and identify the instruments the run needs besides the boards before any board's first
        step: a fault here is the station's (station_fault.py), recorded as an error run, exit 3."""
        try:
            self.panel.jig = preflight_jig(self.cfg.jig, self.panel.jig, lambda: self._build_jig(boards))
            preflight_chamber(self.cfg.schema.chamber)
        except DeviceError as e:
            if self.panel.jig is not None:
                self.panel.jig.close()
            self.echo(station_fault_line(e, before_board=True))
            self._record_unreachable(store, e, what=station_fault_reason(e))
            raise

    def _build_jig(self, boards: list[PanelBoard]) -> Jig:
        """The configured jig: a single board's, or the whole panel's."""
        if self.policy.single_board:
            return make_jig(self.cfg.jig, boards[0].driver, self.ui)
        return make_panel_jig(self.cfg.jig, boards, self.ui)

    def _open_all(self, store: Store, boards: list[PanelBoard]) -> None:
        """Open every board; Ctrl-C closes a panel's runs started so far (a single board's: its self-test)."""
        try:
            for b in boards:
                self._open(b, store)
            self._warm_up(store, boards)
            for b in boards:
                self._self_test(b, store)
        except KeyboardInterrupt as e:
            if not self.policy.single_board:
                self._interrupted(store, boards, e)
            raise

    def _open(self, b: PanelBoard, store: Store) -> None:
        """Open, identify and configure one board (powered ahead: warmup.power_ahead) and start its run.
        A device fault fails that board (a panel's) or is recorded as an error run and raised (a single board)."""
        try:
            b.driver.open()
            b.open_ = True
            ident = b.driver.identify()
            if ident.serial:  # the serial the device reports (its EEPROM, the bridge) follows the one rule
                check_serial(ident.serial, f"the serial the {ident.chip or 'device'} reports")
            b.rep.serial = (self.serial_override or ident.serial) if self.policy.single_board else (
                ident.serial or b.rep.serial)
            b.rep.chip = ident.chip
            b.driver.configure(*(configured_rate(self.cfg.device) if self.policy.single_board else board_rate(b)))
            b.clock = self.conditions.clock(b.driver)
            b.clock0 = b.clock.now() if b.clock is not None else None
            power_ahead(b.driver, self.cfg.capture.powered_ahead_s)
        except AccelcalError as e:
            if self.policy.device_fault_ends_run:
                self._record_unreachable(store, e)
                raise
            if is_station_fault(e):
                b.station_fault(e)
            else:
                b.fail(Stage.DEVICE, Reason("device", str(e)))
        self._start_run(b, store)

    def _start_run(self, b: PanelBoard, store: Store) -> None:
        cfg, rep = self.cfg, b.rep
        single = self.policy.single_board
        rep.site = cfg.site.to_json()
        rep.run_id = store.start_run(
            device_serial=rep.serial if single else rep.serial or b.path,
            chip=rep.chip if single else rep.chip or b.driver_name,
            station_id=cfg.station_id, operator=self.operator, lot=self.lot, config_text=cfg.text,
            model=cfg.model, units="counts", counts_per_g=b.driver.counts_per_g if b.open_ else None,
            panel_id=self.panel_id)
        if self.policy.burn_steps_recorded:
            b.steps.burn_log = lambda kind, data, r=rep.run_id: store.record_burn(r, kind, data)

    def _record_unreachable(self, store: Store, err: AccelcalError, what: str | None = None) -> None:
        """A device (or an instrument) that does not answer still leaves a record: status error, with the
        reason; no verdict, so the board counts in no yield."""
        cfg = self.cfg
        rid = store.start_run(device_serial=self.serial_override, station_id=cfg.station_id,
                              operator=self.operator, lot=self.lot, config_text=cfg.text, model=cfg.model)
        store.interrupt_run(rid, what or f"device: {err}", status="error")

    def _warm_up(self, store: Store, boards: list[PanelBoard]) -> None:
        """The warm-up hold of every board still in the flow, all at once (station/warmup.py); the
        panel then waits for its slowest board (virtual clocks brought to the latest).  A board whose
        device errs is judged as in its self-test."""
        live = [b for b in boards if b.active]
        if not live or not self.cfg.capture.warmup:
            return
        held = hold_boards([(b.driver, b.rep, self._board_echo(b)) for b in live], self.cfg)
        for b, h in zip(live, held, strict=True):
            b.steps.samples_read += h.read
            b.steps.warmup_read = h.read  # the time budget's warm-up (time_budget.py)
            b.steps.warmup_s = h.held_s
        if not self.policy.single_board:
            sync_clocks([b.driver for b in live])
        for b, h in zip(live, held, strict=True):
            if h.error is not None:
                self._guarded(b, store, "warm-up", _raiser(h.error))

    def _board_echo(self, b: PanelBoard) -> Callable[[str], None]:
        """What a board says: a single board's own words, a panel's board's prefixed with its name."""
        return self.echo if self.policy.single_board else (lambda s: self.echo(f"  {b.name}: {s}"))

    def _self_test(self, b: PanelBoard, store: Store) -> None:
        """The board's self-test before the poses (self_test_step.py); a board that fails it takes no
        part in the poses."""
        if not b.active:
            return

        def step() -> None:
            if not b.steps.self_test_step(b.driver, b.rep) and not self.policy.single_board:
                self.echo(f"  {b.name}: {b.rep.reasons[-1]}")

        self._guarded(b, store, "self-test", step)

    def _guarded(self, b: PanelBoard, store: Store, what: str, step: Callable[[], None]) -> None:
        """A step before the poses (the warm-up, the self-test): a single board's device fault ends its run
        FAIL, any other error or Ctrl-C interrupts it; a panel's board that errs fails alone."""
        try:
            step()
        except AccelcalError as e:
            if not self.policy.device_fault_ends_run:
                b.fail(Stage.SELF_TEST, Reason(e.reason_code, f"during the {what}: {e}"))
                self.echo(f"  {b.name}: {b.rep.reasons[-1]}")
            elif is_station_fault(e):
                self._station_fault(store, [b], e)
                raise
            elif isinstance(e, DeviceError):
                b.rep.record(Stage.FAULT, Reason(e.reason_code, f"during the {what}: {e}"))
                self.echo(f"FAIL: {e} ({what})")
            else:
                self._interrupt_self_test(store, b, e, what)
                raise
        except KeyboardInterrupt as e:
            if self.policy.single_board:
                self._interrupt_self_test(store, b, e, what)
            raise

    def _interrupt_self_test(self, store: Store, b: PanelBoard, e: BaseException, what: str = "self-test") -> None:
        assert b.rep.run_id is not None, "the run is started before its self-test"
        ki = isinstance(e, KeyboardInterrupt)
        store.interrupt_run(b.rep.run_id, "interrupted (Ctrl-C)" if ki else f"{what}: {e}",
                            status="interrupted" if ki else "error")

    def _record(self, store: Store, b: PanelBoard) -> None:
        """Record one board's finished run (or keep it in the outbox: recording.py); a single board's store
        that fails ends the command, a panel's fails that board."""
        cfg, rep = self.cfg, b.rep
        assert rep.run_id is not None, "every board's run is started when it is opened"
        if rep.station_fault is not None:  # a panel board's instrument faulted: an error run, no verdict
            store.interrupt_run(rep.run_id, rep.station_fault, status="error", nvm_outcome=rep.nvm,
                                session=board_session(b) if b.records else None,
                                retries=b.retries if b.records else None)
            return
        summary = self.conditions.finish(self, b)
        session = board_session(b)
        single = self.policy.single_board
        start = start_args(cfg, rep, self.operator, self.lot, session.counts_per_g,
                           panel_id=self.panel_id, device_serial=rep.serial if single else rep.serial or b.path)
        finish: FinishArgs = {"session": session, "calibration": rep.calibration, "verdict": rep.verdict,
                  "reasons": rep.reasons, "nvm_outcome": rep.nvm, "fit_summary": summary, "model": cfg.model,
                  "retries": b.retries, "limits": cfg.limits.values, "site": rep.site,
                  "uncertainty": stored_uncertainty(rep)}
        try:
            record_result(store, rep.run_id, start, finish, cfg.outbox)
        except AccelcalError as e:
            if single:
                raise
            rep.record(Stage.STORE, Reason("store", str(e)))

    # -- ending ------------------------------------------------------------------------
    def _fault(self, boards: list[PanelBoard], e: AccelcalError) -> None:
        """A device or port fault that ends the flow: every board still in it fails with the typed reason
        (``port_lost``, ``device``, ``nvm``); each run is then recorded FAIL with the poses its board
        captured, so the command exits 1 and no run is left 'running'."""
        code = e.reason_code
        single = self.policy.single_board
        for b in boards:
            if single or b.active:
                why, as_event = self.conditions.fault_reason(self, b, e)
                b.rep.record(Stage.FAULT, Reason(code, why))
                b.cal = None  # nothing is burned after the fault
                if as_event:
                    b.rep.events.append(f"run ended by a {code} fault after {len(b.records)} poses: {e}")
        if single:
            self.echo(f"FAIL: {e} ({len(boards[0].records)} poses captured)")
        else:
            self.echo(f"FAIL: {e} (every board still in the flow)")

    def _station_fault(self, store: Store, boards: list[PanelBoard], e: DeviceError) -> None:
        """An instrument faulted mid-run (a lost port, a jig that stopped answering, a bus that NACKs):
        the station's error, never a board's verdict.  Every board still in the flow leaves it unjudged
        (a board already failed keeps its FAIL); a single board's run is closed at once as ``error`` with
        its poses (a panel's boards are recorded so by ``_record``).  What a board holds after a burn had
        begun is said (the writer's restore path has already run)."""
        single = self.policy.single_board
        for b in boards:
            if single or b.active:
                b.rep.station_fault = station_fault_reason(e, self.conditions.interruption(self, b, e)[0])
                b.cal = None  # nothing more is burned after the fault
                b.rep.events.append(f"run ended by a station fault after {len(b.records)} poses: {e}")
        self.echo(station_fault_line(e, before_board=False, poses=len(boards[0].records) if boards else 0))
        for b in boards:
            held = nvm_held_line(b.rep.nvm) if b.rep.station_fault else ""
            if held:
                self.echo(f"  {b.name}: {held}")
        if single and boards[0].rep.run_id is not None:
            self._record(store, boards[0])

    def _interrupted(self, store: Store, boards: list[PanelBoard], e: BaseException) -> None:
        """Each run closed with the poses its board captured so far (interrupted, or error)."""
        for b in boards:
            if b.rep.run_id is not None:
                why, status = self.conditions.interruption(self, b, e)
                store.interrupt_run(b.rep.run_id, why, status=status, nvm_outcome=b.rep.nvm,
                                    session=board_session(b) if b.records else None,
                                    retries=b.retries if b.records else None)


def make_flow(cfg: StationConfig, **options: Unpack[FlowOptions]) -> StationFlow:
    """The flow a config asks for: its boards (``device.boards``: a panel; else one board), its
    conditions (``thermal:`` and ``chamber:``: a thermal plan; else room temperature) and its policy;
    ``options`` as flow_options.FlowSetup says."""
    setup = FlowSetup(**options)
    conditions: Conditions = ThermalConditions(cfg) if cfg.is_thermal else RoomTemperature()
    drivers = setup.drivers
    if setup.driver is not None:
        drivers = [setup.driver]
    elif drivers is None and not cfg.is_panel:
        drivers = [make_driver(cfg.device)]
    return StationFlow(cfg, conditions, FlowPolicy.for_config(cfg, setup.panel_id), replace(setup, drivers=drivers))

"""Panel calibration: several boards on one jig, every pose captured on all of them at once.

The flow (DESIGN.md "Scale"): the panel is placed once; at each pose the jig presents the
whole panel and every board is captured at once (one thread per serial port or board;
boards that share a multiplexed I2C bus take turns on it, transaction by transaction,
within each sample period: drivers/tca9548a.py MuxBus.lock); then each board gets its own
fit, verdict, verification, NVM burn with read-back, and its own run in the store, all
sharing one ``panel_id``.  A board that fails (NACKs, sits on the wrong face, is beyond
its limits) is named with its own reason and dropped from the rest of the flow; it never
stops or taints the others.  With models 6/12/15 and enough boards the jig's per-pose
rotation is estimated from all of them (jig_pose.py).

The panel's ``device:`` section (``boards``, ``spread``, seats): panel_config.py.
"""
from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Literal, TypedDict

import numpy as np

from ..acceptance.reasons import Reason
from ..calibration import Calibration
from ..config.schema import JigSection
from ..drivers.base import Driver
from ..drivers.factory import make_driver
from ..errors import AccelcalError, ConfigError, DeviceError, NVMError
from ..fixtures.base import Jig, PoseSpec
from ..fixtures.designs import get_design
from ..fixtures.factory import board_seat, clock_of
from ..fixtures.factory import make_panel_jig as panel_jig
from ..fixtures.operator_jig import OperatorAbort
from ..fixtures.operator_ui import OperatorUI
from ..session import PoseRecord, Session
from ..store.outbox import open_store
from ..store.runs import Store
from .board import Check, Station
from .capture import GatedCapture, WrongPose, gated_capture
from .jig_pose import JigPoseEstimate, estimate_jig_poses
from .panel_config import group_of, panel_sections
from .recording import record_result, start_args
from .report import RunReport
from .settings import StationConfig
from .verdict import Stage


class PerBoardSplit(TypedDict):
    """A thermal panel's time split divided by its boards, s."""

    soak_s: float
    sampling_floor_s: float
    rest_s: float
    board_time_s: float


class PanelTiming(TypedDict, total=False):
    """A panel's time, s: its boards run at once, so its device time is the longest board's
    (a thermal panel's: the split of its shared soaks and captures, and that split per board)."""

    boards: int
    host_compute_s: float
    device_time_s: float
    panel_time_s: float
    per_board_s: float
    soak_s: float
    sampling_floor_s: float
    rest_s: float
    board_time_s: float
    per_board: PerBoardSplit
    clock: Literal["real", "virtual"]


@dataclass
class PanelBoard:
    """One board of the panel and everything the flow keeps for it."""

    index: int
    section: dict[str, Any]
    path: str
    group: str  # boards of one group (bus or port) are read in turn by one thread
    station: Station
    rep: RunReport
    driver: Driver
    records: list[PoseRecord] = field(default_factory=list)
    retries: list[int] = field(default_factory=list)
    floor: np.ndarray | None = None
    checks: list[Check] = field(default_factory=list)
    cal: Calibration | None = None
    clock0: float | None = None
    open_: bool = False
    seat: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def active(self) -> bool:
        """Still in the flow: opened and not failed yet."""
        return self.open_ and not self.rep.failed

    def fail(self, stage: Stage, reason: Reason) -> None:
        """This board fails at ``stage`` (it takes no further part in the panel's flow)."""
        self.rep.record(stage, reason)
        self.rep.events.append(reason)

    @property
    def name(self) -> str:
        return f"board {self.index + 1} ({self.rep.serial or self.path})"


def _quiet(_: str) -> None:
    """A board of a panel says nothing itself: the panel speaks for its boards."""


def new_panel_id(station_id: str) -> str:
    return f"{station_id}-{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{os.urandom(3).hex()}"


def make_panel_jig(cfg: JigSection, boards: list[PanelBoard], ui: OperatorUI | None) -> Jig:
    """The configured jig for the whole panel, from the jig factory."""
    live = [b for b in boards if b.driver is not None]
    return panel_jig(cfg, [b.driver for b in live], [b.seat for b in live], ui)


class PanelStation:
    """Runs the flow for every board of a panel at once (a single board is a panel of one)."""

    # each board's own station and report (thermal_panel.py uses its own)
    board_station: type[Station] = Station
    board_report: type[RunReport] = RunReport

    def __init__(self, config: StationConfig, *, operator: str | None = None, lot: str | None = None,
                 echo: Callable[[str], None] = print, drivers: list[Driver] | None = None,
                 panel_id: str | None = None, jig: Jig | None = None, ui: OperatorUI | None = None) -> None:
        self.cfg = config
        self.ui = ui  # the operator's front end, for an operator jig
        self.operator, self.lot, self.echo = operator, lot, echo
        self.drivers = drivers  # default: built from the config's device section
        self.panel_id = panel_id or new_panel_id(config.station_id)
        self.jig = jig  # default: built from the config's jig section
        self._buses: dict[Any, Any] = {}  # one MuxBus per (I2C bus, mux address), shared by its boards
        self.estimate: JigPoseEstimate | None = None
        self.timing: PanelTiming = {}
        self.boards: list[PanelBoard] = []

    # -- building -------------------------------------------------------------------
    def _boards(self) -> list[PanelBoard]:
        cfg = self.cfg
        sections = panel_sections(cfg.device)
        if self.drivers is not None and len(self.drivers) != len(sections):
            raise ConfigError(f"device: {len(sections)} boards configured, {len(self.drivers)} drivers given")
        out = []
        for i, (sec, path) in enumerate(sections):
            st = self.board_station(cfg, operator=self.operator, lot=self.lot, echo=_quiet)
            rep = self.board_report(station_id=cfg.station_id, model=cfg.model, design=cfg.design,
                                    store=str(cfg.store_file))
            rotation = board_seat(sec, path)
            driver = self.drivers[i] if self.drivers is not None else make_driver(sec, path, self._buses)
            out.append(PanelBoard(i, sec, path, group_of(sec, i), st, rep, driver, seat=rotation))
            st.driver = driver
            rep.serial = str(sec.get("serial") or "")
        return out

    def _open(self, b: PanelBoard, store: Store) -> None:
        """Open, identify, configure one board and start its run; a device error fails that board only."""
        try:
            b.driver.open()
            b.open_ = True
            ident = b.driver.identify()
            b.rep.serial = ident.serial or b.rep.serial
            b.rep.chip = ident.chip
            b.driver.configure(b.section.get("range_g"), b.section.get("odr_hz"))
            clock = clock_of(b.driver)
            b.clock0 = clock.now() if clock is not None else None
        except AccelcalError as e:
            b.fail(Stage.DEVICE, Reason("device", str(e)))
        b.rep.run_id = store.start_run(
            device_serial=b.rep.serial or b.path, chip=b.rep.chip or b.section.get("driver"),
            station_id=self.cfg.station_id, operator=self.operator, lot=self.lot, config_text=self.cfg.text,
            model=self.cfg.model, units="counts",
            counts_per_g=b.driver.counts_per_g if b.open_ else None, panel_id=self.panel_id)
        self._self_test(b)

    def _self_test(self, b: PanelBoard) -> None:
        """The board's own self-test, before the poses with the panel at rest (board.py self_test_step);
        a board that fails it, or whose bus fails during it, takes no part in the poses."""
        if not b.active:
            return
        try:
            if not b.station.self_test_step(b.driver, b.rep):
                self.echo(f"  {b.name}: {b.rep.reasons[-1]}")
        except AccelcalError as e:
            b.fail(Stage.SELF_TEST, Reason(e.reason_code, f"during the self-test: {e}"))
            self.echo(f"  {b.name}: {b.rep.reasons[-1]}")

    # -- capture ------------------------------------------------------------------------
    def _capture_one(self, b: PanelBoard, pose: PoseSpec, floor: np.ndarray | None
                     ) -> tuple[GatedCapture | None, AccelcalError | None]:
        try:
            return gated_capture(b.driver, self.cfg.capture, pose.reference_g, floor), None
        except AccelcalError as e:  # WrongPose, not still, NACK...: this board's, never the panel's
            return None, e

    def capture_all(self, boards: list[PanelBoard], pose: PoseSpec, floors: dict[int, np.ndarray | None] | None = None
                    ) -> tuple[dict[int, GatedCapture], dict[int, AccelcalError]]:
        """Capture ``pose`` on every active board at once: one thread per group, boards of a group in turn.

        Returns the captures and the errors, by board index; nothing is marked failed here.
        """
        groups: dict[str, list[PanelBoard]] = {}
        for b in boards:
            if b.active:
                groups.setdefault(b.group, []).append(b)
        caps: dict[int, GatedCapture] = {}
        errors: dict[int, AccelcalError] = {}
        lock = threading.Lock()

        def run(members: list[PanelBoard]) -> None:
            for b in members:
                gc, err = self._capture_one(b, pose, (floors or {}).get(b.index))
                with lock:
                    if gc is not None:
                        caps[b.index] = gc
                    elif err is not None:
                        errors[b.index] = err

        if len(groups) <= 1:
            for members in groups.values():
                run(members)
        else:
            with ThreadPoolExecutor(max_workers=len(groups)) as ex:
                list(ex.map(run, groups.values()))
        return caps, errors

    def _present_and_capture(self, boards: list[PanelBoard], jig: Jig, pose: PoseSpec,
                             floors: dict[int, np.ndarray | None] | None = None) -> dict[int, GatedCapture]:
        """Present ``pose`` and capture the panel; a board that could not be captured fails with its reason.

        The panel is placed once: when every board reads a wrong pose it is the panel that is
        misplaced, and an operator is asked to place it again (up to capture.max_recaptures).
        """
        for attempt in range(self.cfg.capture.max_recaptures + 1):
            jig.present(pose, None)
            caps, errors = self.capture_all(boards, pose, floors)
            misplaced = len(boards) > 1 and not caps and errors and all(
                isinstance(e, WrongPose) for e in errors.values())
            if not misplaced:
                break
            self.echo(f"  every board reads a wrong pose at {pose.name}: the panel is not in the planned pose")
            if not jig.places_again or attempt == self.cfg.capture.max_recaptures:
                break
        for b in boards:
            if b.index in errors:
                e = errors[b.index]
                b.fail(Stage.CAPTURE, Reason("pose", f"{pose.name}: {e}", sep=" ") if isinstance(e, WrongPose)
                       else Reason(e.reason_code, f"{pose.name}: {e}"))
                self.echo(f"  {b.name}: {b.rep.reasons[-1]}")
        return caps

    def _poses(self, boards: list[PanelBoard], jig: Jig, design: list[PoseSpec]) -> None:
        for i, pose in enumerate(design):
            self.echo(f"[{i + 1}/{len(design)}] {pose.name}")
            caps = self._present_and_capture(boards, jig, pose, {b.index: b.floor for b in boards})
            for b in boards:
                gc = caps.get(b.index)
                if gc is None:
                    continue
                b.floor = gc.floor_counts
                c = gc.capture
                b.records.append(PoseRecord(pose.name, c.mean_counts, c.std_counts, c.n, pose.reference_g,
                                            pose.pitch_deg, pose.roll_deg, c.temp_c, c.dropped, c.t_start, c.t_end))
                b.retries.append(gc.recaptures)
                b.station.samples_read += gc.samples_read
                b.station.samples_used += c.n
                sem_mg = c.sem_counts / b.driver.counts_per_g * 1e3
                b.rep.poses.append({"pose": pose.name, "n": c.n, "mean_counts": c.mean_counts.tolist(),
                                    "sem_mg": sem_mg.tolist(), "retries": gc.recaptures,
                                    "reached_target": gc.reached_target})
                b.rep.events += [f"{pose.name}: {ev}" for ev in gc.events + b.driver.take_events()]

    # -- the run ---------------------------------------------------------------------
    # the faults that end the flow as a recorded FAIL of every board still in it (anything else
    # interrupts every run); a thermal plan's panel narrows them (thermal_panel.py)
    ending_faults: tuple[type[AccelcalError], ...] = (DeviceError, NVMError)

    def run(self) -> list[RunReport]:
        """Open every board and start its run, calibrate them (``_calibrate``: at room temperature
        here, at each set point of a thermal plan in thermal_panel.py), then time and record each."""
        cfg = self.cfg
        wall0 = time.perf_counter()
        boards = self.boards = self._boards()
        with open_store(cfg.store_file, cfg.outbox, cfg.heartbeat_s) as store:
            store.mark_stale_interrupted()
            try:
                for b in boards:
                    self._open(b, store)
                self._calibrate(boards)
            except self.ending_faults as e:
                # a lost jig port, a NACK storm on the shared bus: FAIL, recorded below
                self.fault(boards, e)  # type: ignore[arg-type]
            except (AccelcalError, KeyboardInterrupt) as e:
                self._interrupted(store, boards, e)
                self._close(boards)
                raise
            self._close(boards)
            self._timing(boards, wall0)
            for b in boards:
                self._record(store, b)
        return [b.rep for b in boards]

    def _calibrate(self, boards: list[PanelBoard]) -> None:
        """Poses, fits and verification on the jig, then each passing board's burn."""
        live = [b for b in boards if b.active]
        if live:
            with (self.jig or make_panel_jig(self.cfg.jig, live, self.ui)) as jig:
                self._poses(boards, jig, get_design(self.cfg.design))
                self._fit_all(boards)
                self._verify_all(boards, jig)
        for b in boards:
            if b.active and b.cal is not None:
                b.station._burn(b.driver, b.cal, b.checks, b.rep)

    def _interrupted(self, store: Store, boards: list[PanelBoard], e: BaseException) -> None:
        """Each run closed with the poses its board captured so far."""
        why = "operator aborted" if isinstance(e, OperatorAbort) else (
            "interrupted" if isinstance(e, KeyboardInterrupt) else str(e))
        for b in boards:
            if b.rep.run_id is not None:
                store.interrupt_run(b.rep.run_id, why, status="interrupted" if isinstance(
                    e, (OperatorAbort, KeyboardInterrupt)) else "error", nvm_outcome=b.rep.nvm,
                    session=_session(b) if b.records else None, retries=b.retries if b.records else None)

    def fault(self, boards: list[PanelBoard], e: DeviceError | NVMError) -> None:
        """A device or port fault that ends the panel's flow: every board still in it fails with the typed
        reason (``port_lost``, ``device``, ``nvm``); each run is then recorded FAIL with the poses its board
        captured (``_record``), so the command exits 1 and no run is left 'running'."""
        code = e.reason_code
        for b in boards:
            if b.active:
                b.fail(Stage.FAULT, Reason(code, str(e)))
                b.cal = None  # nothing is burned after the fault
                b.rep.events.append(f"run ended by a {code} fault after {len(b.records)} poses: {e}")
        self.echo(f"FAIL: {e} (every board still in the flow)")

    def _close(self, boards: list[PanelBoard]) -> None:
        for b in boards:
            if b.open_:
                with contextlib.suppress(AccelcalError, OSError):
                    b.driver.close()
        for bus in self._buses.values():
            bus.close()
        self._buses.clear()

    def _fit_all(self, boards: list[PanelBoard]) -> None:
        """Joint jig-pose estimation over the boards with every pose, then each board's fit and verdict."""
        design = get_design(self.cfg.design)
        full = [b for b in boards if b.active and len(b.records) == len(design)]
        if full:
            gf = np.stack([np.stack([r.mean for r in b.records]) / b.driver.counts_per_g for b in full])
            self.estimate = est = estimate_jig_poses(gf, np.stack([p.reference_g for p in design]), self.cfg.model)
            if est.estimated:
                self.echo(f"jig pose error estimated from {len(full)} boards: {est.rms_deg:.3f} deg rms per pose")
                for b, refs in zip(full, est.references_g, strict=True):
                    for r, ref in zip(b.records, refs, strict=True):
                        r.reference_g = ref
            elif len(boards) > 1 or self.cfg.model in ("6", "12", "15"):
                self.echo(f"jig pose error not estimated: {est.note}")
        for b in boards:
            if not b.active:
                continue
            session = Session(b.records, units="counts", counts_per_g=b.driver.counts_per_g, device=b.rep.serial)
            b.cal = b.station._fit_judge(b.driver, session, b.rep)

    def _verify_all(self, boards: list[PanelBoard], jig: Jig) -> None:
        n = self.cfg.verify_poses
        todo = [b for b in boards if b.active and b.cal is not None]
        if n == 0 or not todo:
            for b in todo:
                if b.cal is not None:
                    b.station._judge_verified(b.cal, [], b.rep)
            return
        poses = get_design(self.cfg.verify_design or self.cfg.design)[:n]
        for pose in poses:
            self.echo(f"verify {pose.name}")
            caps = self._present_and_capture(todo, jig, pose)
            for b in todo:
                gc = caps.get(b.index)
                if gc is not None:
                    b.station.samples_read += gc.samples_read
                    b.station.samples_used += gc.capture.n
                    b.checks.append((gc.capture.mean_counts, pose.reference_g, gc.capture.temp_c))
        for b in todo:
            if b.active and b.cal is not None and not b.station._judge_verified(b.cal, b.checks, b.rep):
                b.cal = None

    def _timing(self, boards: list[PanelBoard], wall0: float) -> None:
        """Per board as a single station reports it, plus the panel's: boards run at once, so the
        panel's device time is the longest board's."""
        host = time.perf_counter() - wall0
        dev = []
        for b in boards:
            if b.driver is None or not b.open_:
                continue
            b.rep.timing = b.station._timing(b.driver, clock_of(b.driver), b.clock0, wall0)
            if "device_time_s" in b.rep.timing:
                dev.append(b.rep.timing["device_time_s"])
        self.timing = {"boards": len(boards), "host_compute_s": host}
        if dev:
            self.timing["device_time_s"] = max(dev)
            self.timing["panel_time_s"] = max(dev) + host
            self.timing["per_board_s"] = self.timing["panel_time_s"] / len(boards)

    def _record(self, store: Store, b: PanelBoard) -> None:
        rep = b.rep
        assert rep.run_id is not None, "every board's run is started when it is opened"
        session = _session(b)
        est = self.estimate
        summary = {"measured": rep.measured, "verify_error_max_mg": rep.verify_error_max_mg,
                   "offset_trim_lsb": rep.offset_trim_lsb, "offset_trim": rep.offset_trim, "self_test": rep.self_test,
                   "design": self.cfg.design, "skipped": rep.skipped,
                   "timing": rep.timing, "nvm_verified": rep.nvm_verified, "panel_id": self.panel_id,
                   "jig_pose": None if est is None else {"estimated": est.estimated, "note": est.note,
                                                         "rotvec_deg": est.rotvec_deg.tolist()}}
        thermal = rep.plan_summary()  # a thermal plan's (thermal_panel.py)
        if thermal is not None:
            summary["thermal"] = thermal
        finish = {"session": session, "calibration": rep.calibration, "verdict": rep.verdict,
                  "reasons": list(rep.reasons), "nvm_outcome": rep.nvm, "fit_summary": summary,
                  "model": self.cfg.model, "retries": b.retries,
                  "limits": self.cfg.limits.values}
        start = start_args(self.cfg, rep, self.operator, self.lot, session.counts_per_g, panel_id=self.panel_id)
        start["device_serial"] = rep.serial or b.path
        try:  # a store that fails: kept in the outbox, the reason says what was burned and recorded
            record_result(store, rep.run_id, start, finish, self.cfg.outbox)
        except AccelcalError as e:
            rep.record(Stage.STORE, Reason("store", str(e)))


def _session(b: PanelBoard) -> Session:
    """The poses one board of the panel captured, as a Session."""
    return Session(b.records, units="counts", counts_per_g=b.driver.counts_per_g if b.open_ else None,
                   device=b.rep.serial)


def panel_dict(panel_id: str, reports: list[RunReport], station: PanelStation | None = None) -> dict[str, Any]:
    """The `accelcal run --json` object of a panel: {"panel_id": ..., "boards": [...]}."""
    out: dict[str, Any] = {"panel_id": panel_id, "boards": [r.to_dict() for r in reports]}
    if station is not None:
        est = station.estimate
        out["timing"] = station.timing
        out["jig_pose"] = None if est is None else {"estimated": est.estimated, "note": est.note,
                                                    "rms_deg": est.rms_deg, "rotvec_deg": est.rotvec_deg.tolist()}
    return out

"""The boards of a run on one jig: a panel (1..N boards), every pose captured on all of them at once.

The flow (DESIGN.md "Scale"; flow.StationFlow runs it): the panel is placed once; at each
pose the jig presents the whole panel and every board is captured at once (one thread per
serial port or board; boards that share a multiplexed I2C bus take turns on it, transaction
by transaction, within each sample period: drivers/tca9548a.py MuxBus.lock); then each board
gets its own fit, verdict, verification, NVM burn with read-back, and its own run in the
store, all sharing one ``panel_id``.  A board that fails (NACKs, sits on the wrong face, is
beyond its limits) is named with its own reason and dropped from the rest of the flow; it
never stops or taints the others.  With models 6/12/15 and enough boards the jig's per-pose
rotation is estimated from all of them (jig_pose.py).  A single board is a panel of one
(its capture: board.BoardSteps, chosen by flow.FlowPolicy).

The panel's ``device:`` section (``boards``, ``spread``, seats): panel_config.py.  How each
board sits (``device.mount``, a board's own over it) and how a turned board is named: panel_mount.py.
"""
from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Literal, TypedDict

import numpy as np

from ..acceptance.reasons import Reason
from ..calibration import Calibration
from ..config.schema import DeviceSection, JigSection
from ..drivers.base import Clock, Driver
from ..drivers.factory import make_driver
from ..drivers.tca9548a import MuxBuses
from ..errors import AccelcalError, ConfigError, DeviceError
from ..fixtures.base import Jig, PoseSpec
from ..fixtures.designs import get_design
from ..fixtures.factory import board_seat, clock_of
from ..fixtures.factory import make_panel_jig as panel_jig
from ..fixtures.operator_ui import OperatorUI
from ..fixtures.pose_path import visit_order
from ..session import PoseRecord, Session
from .board import BoardSteps, Check, verify_settings
from .capture import CaptureSettings, GatedCapture, WrongPose, gated_capture
from .jig_pose import JigPoseEstimate, estimate_jig_poses
from .panel_config import configured_serial, group_of, own_mount, panel_sections
from .panel_mount import BoardMount, Failure, end_of_design, explained, sort_wrong_poses
from .report import RunReport, RunReportJson
from .sequential_capture import Needed, needed_at, plan_record
from .settings import StationConfig
from .station_fault import is_station_fault, station_fault_reason
from .time_budget import DEFAULT_BUS_HZ, TimeBudget, panel_budget
from .verdict import Stage
from .verification import verification_poses


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
    time_budget: TimeBudget  # the panel's (time_budget.panel_budget); each board's rep has its share
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
    section: DeviceSection  # this board's typed section (panel_config.panel_sections)
    path: str
    group: str  # boards of one group (bus or port) are read in turn by one thread
    steps: BoardSteps
    rep: RunReport
    driver: Driver
    records: list[PoseRecord] = field(default_factory=list)
    retries: list[int] = field(default_factory=list)
    floor: np.ndarray | None = None
    checks: list[Check] = field(default_factory=list)
    cal: Calibration | None = None
    clock: Clock | None = None  # the board's clock (conditions.clock) and its time at opening
    clock0: float | None = None
    open_: bool = False
    closed: bool = False
    seat: np.ndarray = field(default_factory=lambda: np.eye(3))
    mount: BoardMount = field(default_factory=lambda: BoardMount(np.eye(3), "device"))

    @property
    def active(self) -> bool:
        """Still in the flow: opened, not failed and no station fault yet."""
        return self.open_ and not self.rep.failed and self.rep.station_fault is None

    def station_fault(self, e: DeviceError) -> None:
        """An instrument of this board (its port, its bus) faulted: it leaves the flow unjudged."""
        self.rep.station_fault = station_fault_reason(e)
        self.rep.events.append(self.rep.station_fault)

    def fail(self, stage: Stage, reason: Reason) -> None:
        """This board fails at ``stage`` (it takes no further part in the panel's flow)."""
        self.rep.record(stage, reason)
        self.rep.events.append(reason)

    @property
    def name(self) -> str:
        return f"board {self.index + 1} ({self.rep.serial or self.path})"

    @property
    def driver_name(self) -> str | None:
        """The driver its section names (its run's chip until the chip answers)."""
        return self.section.driver


def make_panel_jig(cfg: JigSection, boards: list[PanelBoard], ui: OperatorUI | None) -> Jig:
    """The configured jig for the whole panel, from the jig factory."""
    live = [b for b in boards if b.driver is not None]
    return panel_jig(cfg, [b.driver for b in live], [b.seat for b in live], ui)


class Panel:
    """The boards of a run on one jig (module docstring): built from the config or given, opened
    and closed by the flow, captured at each pose all at once."""

    def __init__(self, config: StationConfig, echo: Callable[[str], None], drivers: list[Driver] | None = None,
                 jig: Jig | None = None, ui: OperatorUI | None = None) -> None:
        self.cfg = config
        self.echo = echo
        self.ui = ui  # the operator's front end, for an operator jig
        self.drivers = drivers  # default: built from the config's device section
        self.jig = jig  # default: built from the config's jig section
        self._buses: MuxBuses = {}  # one MuxBus per (I2C bus, mux address), shared by its boards
        self.estimate: JigPoseEstimate | None = None
        self.timing: PanelTiming = {}
        self.mounts: dict[int, BoardMount] = {}  # every board's mounting (panel_mount.py), by index
        self.design_taken: list[PoseSpec] | None = None  # the design's poses in the order taken (poses())
        self.verify_device_s = 0.0  # the verification's moves and captures: the fits run under them
        self.capture_wall_s = 0.0  # host wall time inside the panel's captures (time_budget.py)
        self.presented: list[PoseSpec] = []  # the design's poses the jig presented, in order

    # -- building -------------------------------------------------------------------
    def build(self, steps: Callable[[], BoardSteps], report: Callable[[], RunReport], single: bool
              ) -> list[PanelBoard]:
        """The boards, each with its own steps and report; ``single``: the config's one board (its
        device section as given), else device.boards (panel_config.py), each board with its own
        mounting (device.mount, its own device.boards[i].mount over it: panel_mount.py)."""
        cfg = self.cfg
        sections = [(cfg.device, "device")] if single else panel_sections(cfg.device)
        if self.drivers is not None and len(self.drivers) != len(sections):
            raise ConfigError(f"device: {len(sections)} boards configured, {len(self.drivers)} drivers given")
        out = []
        for i, (sec, path) in enumerate(sections):
            st, rep = steps(), report()
            seat = np.eye(3) if single else board_seat(sec, path)  # takes the seat's keys from the section
            driver = self.drivers[i] if self.drivers is not None else make_driver(sec, path, self._buses)
            if not single:  # the one-board run's steps read device.mount themselves
                st.mount = sec.mount_p()
            mount = BoardMount(st.mount, path, own=not single and own_mount(cfg.device, i))
            out.append(PanelBoard(i, sec, path, group_of(sec, i), st, rep, driver, seat=seat, mount=mount))
            rep.serial = "" if single else configured_serial(sec)
        self.mounts = {b.index: b.mount for b in out}
        return out

    def make_jig(self, live: list[PanelBoard]) -> Jig:
        """The jig given, or the configured one for the whole panel."""
        return self.jig or make_panel_jig(self.cfg.jig, live, self.ui)

    # -- capture ------------------------------------------------------------------------
    def _capture_one(self, b: PanelBoard, pose: PoseSpec, floor: np.ndarray | None,
                     settings: CaptureSettings | None = None, needed: Needed | None = None
                     ) -> tuple[GatedCapture | None, AccelcalError | None]:
        try:
            return gated_capture(b.driver, settings or self.cfg.capture, b.steps.mount @ pose.reference_g,
                                 floor, needed=needed), None
        except AccelcalError as e:  # WrongPose, not still, NACK...: this board's, never the panel's
            return None, e

    def capture_all(self, boards: list[PanelBoard], pose: PoseSpec,
                    floors: dict[int, np.ndarray | None] | None = None, settings: CaptureSettings | None = None,
                    needed: dict[int, Needed | None] | None = None
                    ) -> tuple[dict[int, GatedCapture], dict[int, AccelcalError]]:
        """Capture ``pose`` on every active board at once: one thread per group, boards of a group in turn;
        ``needed``: each board's sequential plan's count for it.

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
                gc, err = self._capture_one(b, pose, (floors or {}).get(b.index), settings,
                                            (needed or {}).get(b.index))
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

    def present_and_capture(self, boards: list[PanelBoard], jig: Jig, pose: PoseSpec,
                            floors: dict[int, np.ndarray | None] | None = None, read_on: bool = False,
                            settings: CaptureSettings | None = None, needed: dict[int, Needed | None] | None = None,
                            move: bool = True) -> dict[int, GatedCapture]:
        """Present ``pose`` and capture the panel; a board that could not be captured fails with its reason.

        The panel is placed once: when every board reads a wrong pose it is the panel that is
        misplaced (unless each board's readings single another mounting out: panel_mount.explained),
        and an operator is asked to place it again (up to capture.max_recaptures).
        ``read_on`` (the design's poses): a board whose wrong pose another mounting may explain is
        read on through the next poses (panel_mount.py; ``end_design`` ends it).  ``move`` False: the
        jig already holds ``pose`` (verification at the last fit pose).
        """
        for attempt in range(self.cfg.capture.max_recaptures + 1):
            if move or attempt > 0:
                jig.present(pose, None)
            t0 = time.perf_counter()
            caps, errors = self.capture_all(boards, pose, floors, settings, needed)
            self.capture_wall_s += time.perf_counter() - t0
            misplaced = len(boards) > 1 and not caps and errors and all(
                isinstance(e, WrongPose) for e in errors.values()) and not explained(
                self.mounts, pose.reference_g, errors, self.cfg.capture.pose_tolerance_deg)
            if not misplaced:
                break
            self.echo(f"  every board reads a wrong pose at {pose.name}: the panel is not in the planned pose")
            if not jig.places_again or attempt == self.cfg.capture.max_recaptures:
                break
        readings = {i: gc.capture.mean_counts for i, gc in caps.items()}
        self._fail(boards, sort_wrong_poses(self.mounts, list(self.mounts.values()), pose.name, pose.reference_g,
                                            readings, errors, read_on, self.cfg.capture.pose_tolerance_deg))
        return caps

    def end_design(self, boards: list[PanelBoard]) -> None:
        """The design's poses are done: a board still read on past a wrong pose fails with the mounting
        that fits what it read (panel_mount.end_of_design)."""
        live = {b.index: b.mount for b in boards if b.active}
        self._fail(boards, end_of_design(live, list(self.mounts.values()), self.cfg.capture.pose_tolerance_deg))

    def _fail(self, boards: list[PanelBoard], failures: dict[int, Failure]) -> None:
        """Each board of ``failures`` fails its capture at the pose named, with its error."""
        for b in boards:
            if b.index in failures:
                name, e = failures[b.index]
                b.mount.first_wrong = None
                if is_station_fault(e):
                    b.station_fault(e)
                    self.echo(f"  {b.name}: STATION FAULT at {name}: {e}; this board is not judged")
                    continue
                b.fail(Stage.CAPTURE, Reason("pose", f"{name}: {e}", sep=" ") if isinstance(e, WrongPose)
                       else Reason(e.reason_code, f"{name}: {e}"))
                self.echo(f"  {b.name}: {b.rep.reasons[-1]}")

    def poses(self, boards: list[PanelBoard], jig: Jig, design: list[PoseSpec]) -> None:
        """Every pose of ``design`` on every board still in the flow, each board to its own sequential plan."""
        self.design_taken = design  # the order the poses are taken in (the records' order; fit_all's)
        plans = {b.index: b.steps.sequential_plan(b.driver, design) for b in boards if b.active}
        self.presented = []
        for i, pose in enumerate(design):
            self.echo(f"[{i + 1}/{len(design)}] {pose.name}")
            caps = self.present_and_capture(boards, jig, pose, {b.index: b.floor for b in boards}, read_on=True,
                                            needed={k: needed_at(p, i) for k, p in plans.items()})
            self.presented.append(pose)
            for b in boards:
                gc = caps.get(b.index)
                if gc is None:
                    continue
                b.floor = gc.floor_counts
                c = gc.capture
                pose_record = plan_record(plans.get(b.index), i, c)
                b.records.append(PoseRecord(pose.name, c.mean_counts, c.std_counts, c.n,
                                            b.steps.expected_g(pose), *b.steps.chip_angles(pose),
                                            c.temp_c, c.dropped, c.t_start, c.t_end, c.n_eff))
                b.retries.append(gc.recaptures)
                b.steps.samples_read += gc.samples_read
                b.steps.samples_used += c.n
                sem_mg = c.sem_counts / b.driver.counts_per_g * 1e3
                b.rep.poses.append({"pose": pose.name, "n": c.n, "mean_counts": c.mean_counts.tolist(),
                                    "sem_mg": sem_mg.tolist(), "retries": gc.recaptures,
                                    "reached_target": gc.reached_target, **pose_record})
                b.rep.events += [f"{pose.name}: {ev}" for ev in gc.events + b.driver.take_events()]
        for b in boards:
            b.steps.mark_fit_done()
        self.end_design(boards)

    def close(self, boards: list[PanelBoard]) -> None:
        """Close every board that was opened (once) and the shared buses."""
        for b in boards:
            if b.open_ and not b.closed:
                b.closed = True
                with contextlib.suppress(AccelcalError, OSError):
                    b.driver.close()
        for bus in self._buses.values():
            bus.close()
        self._buses.clear()

    def fit_all(self, boards: list[PanelBoard]) -> None:
        """Joint jig-pose estimation over the boards with every pose, then each board's fit and verdict."""
        design = self.design_taken or get_design(self.cfg.design)
        full = [b for b in boards if b.active and len(b.records) == len(design)]
        if full:
            # in board axes (reading @ P = P^T reading): the jig turns every board alike there, and a
            # mounting (a signed permutation of the chip's axes) changes no board's fit
            gf = np.stack([np.stack([r.mean for r in b.records]) / b.driver.counts_per_g @ b.steps.mount
                           for b in full])
            self.estimate = est = estimate_jig_poses(gf, np.stack([p.reference_g for p in design]), self.cfg.model)
            if est.estimated:
                self.echo(f"jig pose error estimated from {len(full)} boards: {est.rms_deg:.3f} deg rms per pose")
                for b, refs in zip(full, est.references_g, strict=True):
                    for r, ref in zip(b.records, refs @ b.steps.mount.T, strict=True):
                        r.reference_g = ref * b.steps.g_site  # the site's gravity, as expected_g
            elif len(boards) > 1 or self.cfg.model in ("6", "12", "15"):
                self.echo(f"jig pose error not estimated: {est.note}")
        for b in boards:
            if not b.active:
                continue
            session = Session(b.records, units="counts", counts_per_g=b.driver.counts_per_g, device=b.rep.serial,
                              metadata=site_metadata(b))
            b.cal = b.steps.fit_judge(b.driver, session, b.rep)

    def verify_all(self, boards: list[PanelBoard], jig: Jig) -> None:
        n = self.cfg.verify_poses
        todo = [b for b in boards if b.active and b.cal is not None]
        if n == 0 or not todo:
            for b in todo:
                if b.cal is not None:
                    b.steps.judge_verified(b.cal, [], b.rep)
            return
        vp = verification_poses(self.cfg.verify_poses, self.cfg.schema.verify, self.cfg.design, self.presented)
        t0 = self._clock_now(todo)
        # fit-poses: back along the path the jig took; independent poses: the shortest path from the last fit pose
        for k, pose in enumerate(visit_order(jig, vp.poses) if vp.first_moves else vp.poses):
            self.echo(f"verify {pose.name}" + (" (where the jig stands)" if k == 0 and not vp.first_moves else ""))
            caps = self.present_and_capture(todo, jig, pose, settings=verify_settings(self.cfg),
                                            move=k > 0 or vp.first_moves)
            for b in todo:
                b.rep.verify_mode = vp.mode
                b.steps.presented, b.steps.verify_taken = self.presented, vp.poses  # the board's floor (time_budget)
                gc = caps.get(b.index)
                if gc is not None:
                    b.steps.samples_read += gc.samples_read
                    b.steps.samples_used += gc.capture.n
                    b.checks.append((gc.capture.mean_counts, b.steps.expected_g(pose), gc.capture.temp_c))
        self.verify_device_s = self._clock_now(todo) - t0
        for b in todo:
            if b.active and b.cal is not None and not b.steps.judge_verified(b.cal, b.checks, b.rep):
                b.cal = None

    def room_timing(self, boards: list[PanelBoard], wall0: float) -> None:
        """Per board as a single station reports it, plus the panel's: boards run at once, so the
        panel's device time is the longest board's."""
        host = time.perf_counter() - wall0
        dev = []
        for b in boards:
            if b.driver is None or not b.open_:
                continue
            b.rep.timing = b.steps.timing(b.driver, clock_of(b.driver), b.clock0, wall0)
            if "device_time_s" in b.rep.timing:
                dev.append(b.rep.timing["device_time_s"])
        self.timing = {"boards": len(boards), "host_compute_s": host}
        if dev:
            self.timing["device_time_s"] = max(dev)
            self.timing["panel_time_s"] = max(dev) + host
            self.timing["per_board_s"] = self.timing["panel_time_s"] / len(boards)
        self._budget(boards, host)

    @staticmethod
    def _clock_now(boards: list[PanelBoard]) -> float:
        """The latest of the boards' device clocks (0 when they run on the wall)."""
        return max((c.now() for c in (clock_of(b.driver) for b in boards) if c is not None), default=0.0)

    def _budget(self, boards: list[PanelBoard], host: float) -> None:
        """The panel's time budget (time_budget.panel_budget), and each board's share of it."""
        opened = [b for b in boards if b.driver is not None and b.open_ and "wall_s" in b.rep.timing]
        if not opened:
            return
        own = [b.steps.time_budget(b.driver, clock_of(b.driver), b.records, b.rep.timing) for b in opened]
        fits = sum(b.steps.fit_wall_s for b in opened)
        # the host's work inside sampling (every board's self-test, the panel's captures) is under the device's time
        inside = self.capture_wall_s + sum(b.steps.sampling_wall_s for b in opened)
        sampled = max(b.steps.samples_read for b in opened) / opened[0].driver.odr_hz
        host = max(0.0, host - min(inside, sampled))  # beyond the sampling time, the host sets the pace
        # the bus at I2C Fast-mode: a real bus's clock is the kernel's (device tree), not the station's config
        budget = panel_budget(own, host, min(fits, self.verify_device_s),
                              max(b.steps.samples_read for b in opened), opened[0].driver.odr_hz, DEFAULT_BUS_HZ)
        self.timing["time_budget"] = budget
        share: TimeBudget = {k: round(float(v) / len(boards), 6) for k, v in budget.items()
                             if k not in ("ratio_to_floor", "boards", "per_board_s")}
        share.update(ratio_to_floor=budget["ratio_to_floor"], boards=len(boards))
        for b in opened:
            b.rep.time_budget = share



def board_rate(b: PanelBoard) -> tuple[int | None, float | None]:
    """(range_g, odr_hz) a panel board's section set; None where it left the driver's own default."""
    given = b.section.model_fields_set
    return (b.section.range_g if "range_g" in given else None, b.section.odr_hz if "odr_hz" in given else None)


def board_session(b: PanelBoard) -> Session:
    """The poses one board captured, as a Session (at the station's site: model 9's norm)."""
    return Session(b.records, units="counts", counts_per_g=b.driver.counts_per_g if b.open_ else None,
                   device=b.rep.serial, metadata=site_metadata(b))


def site_metadata(b: PanelBoard) -> dict[str, Any]:
    """``site`` of a station session: the gravity the references were scaled to, which model 9's
    and the hand-placed fit's norm is too (models/site_norm.py)."""
    return {"site": dict(b.steps.cfg.site.to_json())}


class JigPoseJson(TypedDict):
    """The jig's per-pose rotation estimated from the panel's boards (jig_pose.JigPoseEstimate)."""

    estimated: bool
    note: str | None
    rms_deg: float
    rotvec_deg: list[list[float]]


class PanelJson(TypedDict, total=False):
    """A panel's run as `accelcal run --json` prints it: its id, each board's run, its time and the jig's pose."""

    panel_id: str
    boards: list[RunReportJson]
    timing: PanelTiming
    jig_pose: JigPoseJson | None


def panel_dict(panel_id: str, reports: list[RunReport], panel: Panel | None = None) -> PanelJson:
    """The `accelcal run --json` object of a panel: {"panel_id": ..., "boards": [...]}."""
    out: PanelJson = {"panel_id": panel_id, "boards": [r.to_dict() for r in reports]}
    if panel is not None:
        est = panel.estimate
        out["timing"] = panel.timing
        out["jig_pose"] = None if est is None else JigPoseJson(
            estimated=est.estimated, note=est.note, rms_deg=est.rms_deg, rotvec_deg=est.rotvec_deg.tolist())
    return out

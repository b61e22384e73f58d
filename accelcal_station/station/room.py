"""The room-temperature conditions of the station's flow: the pose design once, then each board's
fit, verdict, verification and burn (DESIGN.md "The flow of one board").

A single board (flow.FlowPolicy.wrong_pose_ends_run) is captured alone with its jig
(board.BoardSteps.run_poses: placed again on a wrong pose, its mounting checked); a panel's
boards are captured at once (panel.Panel.poses) and the jig's per-pose rotation is estimated
from all of them before each board's fit.
"""
from __future__ import annotations

from ..drivers.base import Clock, Driver
from ..errors import AccelcalError, DeviceError, NVMError
from ..fixtures.designs import get_design
from ..fixtures.factory import clock_of, make_jig
from ..fixtures.pose_path import visit_order
from .panel import PanelBoard, board_session
from .policy import FlowView, panel_why, stopped_by_operator
from .recording import RunSummary, board_summary, panel_summary
from .report import RunReport
from .settings import StationConfig


class RoomTemperature:
    """The boards calibrated once, at the room's temperature."""

    # a port that closed, a NACK storm, reads that do not settle: the run ends FAIL with the typed
    # reason and the poses captured so far, exit 1, never 'running'
    ending_faults: tuple[type[AccelcalError], ...] = (DeviceError, NVMError)

    def new_report(self, cfg: StationConfig) -> RunReport:
        return RunReport(station_id=cfg.station_id, model=cfg.model, design=cfg.design, store=str(cfg.store_file))

    def clock(self, driver: Driver) -> Clock | None:
        """The clock the device runs on (a simulated board's); None: the wall (hardware)."""
        return clock_of(driver)

    def calibrate(self, flow: FlowView, boards: list[PanelBoard]) -> None:
        """Poses, fits, verification and burns of the boards still in the flow."""
        if flow.policy.wrong_pose_ends_run:
            self._one_board(flow, boards[0])
            return
        panel = flow.panel
        live = [b for b in boards if b.active]
        if live:
            with panel.make_jig(live) as jig:
                panel.poses(boards, jig, visit_order(jig, get_design(flow.cfg.design), keep_first=True))
                panel.fit_all(boards)
                panel.verify_all(boards, jig)
            for b in boards:
                b.steps.jig_moves_s = jig.moves_s  # the panel's moves are every board's
        for b in boards:
            if b.active and b.cal is not None:
                b.steps.burn(b.driver, b.cal, b.checks, b.rep)

    def _one_board(self, flow: FlowView, b: PanelBoard) -> None:
        """A board alone with its jig: poses, fit, verdict, verification and burn (board.BoardSteps)."""
        if not b.active:
            return
        steps = b.steps
        with flow.panel.jig or make_jig(flow.cfg.jig, b.driver, flow.ui) as jig:
            jig.mount = steps.mount
            try:
                # the design is a set: its first pose, then the rest along the shortest path (fixtures/
                # pose_path.py); records keep the order taken, which diagnosis/order.py reads
                design = visit_order(jig, get_design(flow.cfg.design), keep_first=True)
                steps.run_poses(b.driver, jig, design, b.records, b.retries, b.rep)
                steps.fit_judge_write(b.driver, jig, board_session(b), b.rep)
            finally:
                steps.operator_wait_s = jig.wait_s
                steps.jig_moves_s = jig.moves_s

    def fault_reason(self, flow: FlowView, b: PanelBoard, e: AccelcalError) -> tuple[str, bool]:
        """The FAULT reason's words, and whether the run's events say it too."""
        return str(e), True

    def interruption(self, flow: FlowView, b: PanelBoard, e: BaseException) -> tuple[str, str]:
        """Why the run was closed early, as the store keeps it, and its status."""
        if flow.policy.single_board:
            why = "interrupted (Ctrl-C)" if isinstance(e, KeyboardInterrupt) else str(e)
        else:
            why = panel_why(e)
        return why, "interrupted" if stopped_by_operator(e) else "error"

    def timing(self, flow: FlowView, boards: list[PanelBoard], wall0: float) -> None:
        """Each board's time (board.BoardSteps.timing); a panel's too (panel.Panel.room_timing)."""
        if not flow.policy.single_board:
            flow.panel.room_timing(boards, wall0)
            return
        b = boards[0]
        b.rep.timing = b.steps.timing(b.driver, b.clock, b.clock0, wall0)
        b.rep.time_budget = b.steps.time_budget(b.driver, b.clock, b.records, b.rep.timing)

    def finish(self, flow: FlowView, b: PanelBoard) -> RunSummary:
        """What the store keeps of the run: a single board's fit figures, a panel board's panel and jig pose."""
        if flow.policy.single_board:
            return board_summary(flow.cfg, b.rep)
        return panel_summary(flow.cfg, b.rep, flow.panel_id, flow.panel.estimate)

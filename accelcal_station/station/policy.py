"""What the station's one flow (flow.StationFlow) is told and what it is given: its policy (what a
single board's run does that a panel's does not, chosen once from the config), the conditions'
interface (room temperature: room.py; a thermal plan: thermal.py) and the view of the flow the
conditions work with.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from ..drivers.base import Clock, Driver
from ..errors import AccelcalError
from ..fixtures.operator_jig import OperatorAbort
from ..fixtures.operator_ui import OperatorUI
from .panel import Panel, PanelBoard
from .recording import RunSummary
from .report import RunReport
from .settings import StationConfig


def new_panel_id(station_id: str) -> str:
    """A panel's id: the station, the UTC time and 6 random hex digits."""
    return f"{station_id}-{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{os.urandom(3).hex()}"


@dataclass(frozen=True)
class FlowPolicy:
    """What a single board's run does that a panel's does not (``for_config``: a config without
    ``device.boards`` is a single board; ``device.boards: 1`` is a panel of one)."""

    # a device fault at opening ends the run: recorded as an error run and raised (exit 3); at the
    # self-test it ends the run FAIL.  Otherwise (a panel) it fails that board and the others go on
    device_fault_ends_run: bool
    # the board is captured alone, placed again by a person on a wrong pose (capture.max_recaptures),
    # its mounting (device.mount) checked, a pose may be skipped, and a wrong pose that stays wrong
    # ends the run (recorded as an error).  Otherwise every board is captured at once and a wrong
    # pose fails that board (``pose``; one its own mounting may explain after reading on: panel_mount.py);
    # the panel is placed again when every board reads it wrong
    wrong_pose_ends_run: bool
    # an operator jig shows the live reading while the board is placed
    live_reading: bool
    # each burn step (burning, burned, failed, reverted) is recorded in the store as it happens
    burn_steps_recorded: bool
    # the safe default limits in use are said and kept with the run's events
    says_default_limits: bool
    # the boards are closed before their time is taken (closing, e.g. a mux's standby writes, is part of
    # a panel's device time); a single board is closed after its run is recorded
    closes_before_timing: bool
    # the id every run of a panel carries (start_run, fit_summary, --json); None: a single board
    panel_id: str | None

    @property
    def single_board(self) -> bool:
        return self.panel_id is None

    @classmethod
    def for_config(cls, cfg: StationConfig, panel_id: str | None = None) -> FlowPolicy:
        single = not cfg.is_panel
        return cls(device_fault_ends_run=single, wrong_pose_ends_run=single, live_reading=single,
                   burn_steps_recorded=single, says_default_limits=single and not cfg.is_thermal,
                   closes_before_timing=not single,
                   panel_id=None if single else panel_id or new_panel_id(cfg.station_id))


class Conditions(Protocol):
    """What the boards are calibrated at: room temperature (room.py) or a thermal plan (thermal.py)."""

    # the faults that end the flow as a recorded FAIL of every board still in it (anything else
    # interrupts every run)
    ending_faults: tuple[type[AccelcalError], ...]

    def new_report(self, cfg: StationConfig) -> RunReport:
        """A board's empty report (a thermal plan's carries its summary)."""
        ...

    def clock(self, driver: Driver) -> Clock | None:
        """The clock a board's time is taken on (None: the wall's, no device time)."""
        ...

    def calibrate(self, flow: FlowView, boards: list[PanelBoard]) -> None:
        """Poses, fits, verdicts and burns of the boards still in the flow."""
        ...

    def fault_reason(self, flow: FlowView, b: PanelBoard, e: AccelcalError) -> tuple[str, bool]:
        """An ending fault's words for the board's FAULT reason, and whether its events say it too."""
        ...

    def interruption(self, flow: FlowView, b: PanelBoard, e: BaseException) -> tuple[str, str]:
        """Why the board's run was closed early, as the store keeps it, and its status."""
        ...

    def timing(self, flow: FlowView, boards: list[PanelBoard], wall0: float) -> None:
        """Each board's time on its report (and the panel's: flow.panel.timing)."""
        ...

    def finish(self, flow: FlowView, b: PanelBoard) -> RunSummary:
        """The board's run finished: its last events and the summary the store keeps of it."""
        ...


class FlowView(Protocol):
    """What the conditions see of the flow (flow.StationFlow)."""

    @property
    def cfg(self) -> StationConfig: ...

    @property
    def policy(self) -> FlowPolicy: ...

    @property
    def panel(self) -> Panel: ...

    @property
    def boards(self) -> list[PanelBoard]: ...

    @property
    def panel_id(self) -> str | None: ...

    @property
    def ui(self) -> OperatorUI | None: ...

    def echo(self, text: str) -> None: ...

    @property
    def progress(self) -> Callable[[str, float], None] | None: ...


def stopped_by_operator(e: BaseException) -> bool:
    """Ctrl-C or the operator's abort: a run closed as interrupted (else: error)."""
    return isinstance(e, (OperatorAbort, KeyboardInterrupt))


def panel_why(e: BaseException) -> str:
    """Why a panel's runs were closed early, as the store keeps it."""
    return "operator aborted" if isinstance(e, OperatorAbort) else (
        "interrupted" if isinstance(e, KeyboardInterrupt) else str(e))

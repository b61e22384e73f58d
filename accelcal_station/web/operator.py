"""The operator jig's browser front end (an OperatorUI, fixtures/operator_ui.py) and its page.

The station runs in the `accelcal run --ui web` process as always; this object stands where
the terminal's prompts stood.  The station's thread blocks in ``ask`` until the page posts an
answer; meanwhile the page polls ``/operator/state``, whose live level reads the board only
while ``ask`` is waiting (under a lock, so the driver is never read by two threads at once
and never after the answer).  The run's verdict is shown full-screen at the end.
"""
from __future__ import annotations

import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, NotRequired, TypedDict

import numpy as np

from ..errors import AccelcalError
from ..fixtures.base import PoseSpec
from ..fixtures.operator_jig import OperatorAbort, pose_words
from ..fixtures.operator_ui import CaptureSink, LiveStatus, PosePrompt, PoseStatus, parse_answer
from ..i18n import Translate, reason_title
from ..station.shift import ShiftSummary
from ..station.station_fault import FAULT_TITLE, is_station_fault, operator_text
from .board_picture import Picture, level_xy, picture

if TYPE_CHECKING:
    from typing_extensions import Unpack

ANSWER_TEXT = {"accept": "", "replace": "r", "skip": "s", "abort": "a"}


class PoseView(TypedDict):
    """The pose being placed: its number in the run, name, words, place in the plan and picture."""

    number: int
    name: str
    words: str
    index: int | None
    verify: bool
    pitch_deg: float
    roll_deg: float
    expects_g: list[float]
    picture: Picture


class PlanItem(TypedDict):
    name: str
    verify: bool  # a verification pose (after the fit)
    picture: Picture


class CaptureView(TypedDict):
    label: str
    fraction: float


class ResultView(TypedDict):
    """The run's end: verdict (PASS, FAIL, ABORTED, ERROR), board, run, reasons with their titles, figures."""

    verdict: str
    serial: str | None
    run_id: int | None
    reasons: list[dict[str, str]]  # code, message, title
    figures: Mapping[str, float | str | None]


class BoardView(TypedDict):
    serial: str
    number: int


class Level(TypedDict):
    """The live level while a pose is asked (PoseStatus as the page shows it)."""

    still: bool
    direction_ok: bool
    off_deg: float
    face: str
    reads_g: list[float]
    bubble: list[float]
    ready: bool
    line: str


class ShiftView(ShiftSummary):
    """The shift's end as the page shows it: the summary and each failing reason's operator words."""

    reason_titles: dict[str, str]


class OperatorState(TypedDict):
    """What every operator page shows (``/operator/state``); ``seq`` counts the changes."""

    phase: str
    station: str
    total: int
    seq: int
    pose: PoseView | None
    capture: CaptureView | None
    result: ResultView | None
    shift: bool
    board: BoardView | None
    summary: ShiftView | None  # the shift's summary with its reasons' titles
    plan: list[PlanItem]
    question: NotRequired[str]
    notice: NotRequired[str]  # what the station said to the operator between boards (WebOperator.say)


class StateChange(TypedDict, total=False):
    """Some of OperatorState's fields, set at once (WebOperator.set)."""

    phase: str
    pose: PoseView | None
    capture: CaptureView | None
    result: ResultView | None
    board: BoardView | None
    summary: ShiftView | None
    question: str


class Snapshot(OperatorState):
    """The state for the page, with the lines said so far and the live level while a pose is asked."""

    lines: list[str]
    level: NotRequired[Level]


class Progress:
    """A capture's fraction, as the page shows it."""

    def __init__(self, ui: WebOperator, label: str) -> None:
        self.ui, self.label = ui, label.strip()

    def __call__(self, fraction: float) -> None:
        self.ui.set(capture={"label": self.label, "fraction": min(max(float(fraction), 0.0), 1.0)})

    def close(self) -> None:
        self.ui.set(capture=None)


class WebOperator:
    """An OperatorUI served to a browser; lines also go to ``echo`` (the terminal log)."""

    def __init__(self, echo: Callable[[str], object], station_id: str, total_poses: int, live_every_s: float = 0.25,
                 shift: bool = False, plan: list[tuple[PoseSpec, bool]] | None = None,
                 tr: Translate = str, language: str = "en") -> None:
        self.echo = echo
        self.tr = tr  # the operator's language (i18n/): the page's texts and the reasons' words
        self.language = language
        self._lock = threading.Lock()
        self._answers: queue.Queue[str | None] = queue.Queue()  # None: the operator aborted
        self._live: LiveStatus | None = None
        self._level: tuple[float, Level] | None = None
        self.live_every_s = live_every_s
        self.lines: deque[str] = deque(maxlen=12)
        self.final_seen = threading.Event()  # a page has shown the end (the run's verdict, or the shift's summary)
        self._end = threading.Event()  # End shift pressed on a station fault
        self._final_phase = "shift_over" if shift else "done"
        # the station holds the state; every page (tabs, reloads, a second screen) only shows it
        self.state: OperatorState = {"phase": "starting", "station": station_id, "total": total_poses,
                                      "seq": 0, "pose": None, "capture": None, "result": None,
                                      "shift": shift, "board": None, "summary": None,
                                      "plan": [{"name": p.name, "verify": v, "picture": picture(p.reference_g)}
                                               for p, v in plan or []]}

    # -- OperatorUI -----------------------------------------------------------------
    def say(self, text: str) -> None:
        self.echo(text)
        with self._lock:
            self.lines.append(text)
            # between boards (the serial scan, a device waited for) a line is for the operator: the notice
            if self.state["phase"] in ("serial", "working", "starting", "station_fault") and not self.state["pose"]:
                self.state["notice"] = text.strip()
            self.state["seq"] += 1

    def show_pose(self, prompt: PosePrompt) -> None:
        self.echo(f"Pose {prompt.pose.name}: put the board {prompt.words}")
        p = prompt.pose
        index = self._plan_index(p.name)
        verify = bool(self.state["plan"][index]["verify"]) if index is not None else False
        words = pose_words(p, self.tr)  # the operator's language (the echo above is the engineers' English)
        self.set(phase="place", pose={"number": prompt.number, "name": p.name, "words": words,
                                      "index": index, "verify": verify,
                                      "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg,
                                      "expects_g": [float(v) for v in p.reference_g],
                                      "picture": picture(p.reference_g)})

    def _plan_index(self, name: str) -> int | None:
        """Where this pose is in the plan: the current one again (re-placed), else the next of that name
        (the verification poses follow the design's, some with the same names)."""
        plan = self.state["plan"]
        pose = self.state.get("pose")
        cur = pose.get("index") if pose else None
        start = 0 if cur is None else cur
        if cur is not None and plan[cur]["name"] == name:
            return int(cur)
        return next((i for i in range(start, len(plan)) if plan[i]["name"] == name), None)

    def ask(self, prompt: PosePrompt, live: LiveStatus | None) -> str:
        with self._lock:
            self._live, self._level = live, None
            self.state.update({"phase": "ask", "capture": None})
            self.state["seq"] += 1
        try:
            return self._wait_answer()
        finally:
            with self._lock:  # the page's level never reads the board after this
                self._live = None
                self.state["phase"] = "working"

    def ask_serial(self, text: str) -> str:
        self.set(phase="serial", question=self.tr(text))
        try:
            return self._wait_answer()
        except OperatorAbort:
            raise OperatorAbort("operator aborted at the serial-number scan") from None
        finally:
            self.set(phase="working")

    def capture(self, label: str) -> CaptureSink:
        return Progress(self, label)

    def station_fault(self, text: str) -> None:
        """Full screen: the station's fault, what to check, no verdict (and in a shift, End shift)."""
        self.echo(f"STATION FAULT: {text}")
        self.set(phase="station_fault", pose=None, capture=None, result=self._fault_result(text))

    def _fault_result(self, text: str) -> ResultView:
        return {"verdict": "STATION FAULT", "serial": None, "run_id": None, "figures": {},
                "reasons": [{"code": "station", "message": text, "title": self.tr(FAULT_TITLE)}]}

    def end_requested(self) -> bool:
        return self._end.is_set()

    # -- the page's side --------------------------------------------------------------
    def _wait_answer(self) -> str:
        while True:  # a short timeout keeps Ctrl-C in the terminal working
            try:
                got = self._answers.get(timeout=0.2)
            except queue.Empty:
                continue
            except KeyboardInterrupt:
                raise OperatorAbort("Ctrl-C in the terminal") from None
            if got is None:
                raise OperatorAbort("Abort on the operator page")
            return got

    def set(self, **kw: Unpack[StateChange]) -> None:
        with self._lock:
            self.state.update(kw)
            self.state["seq"] += 1

    def answer(self, what: str, serial: str | None = None) -> bool:
        """An answer from the page; False when nothing is being asked that it answers."""
        with self._lock:
            phase = self.state["phase"]
        if phase == "serial" and what == "serial" and serial is not None:
            self._answers.put(serial)
            return True
        if phase == "serial" and what in ("abort", "end"):
            self._answers.put(None)  # as end of input at the terminal's scan prompt (a shift's End shift)
            return True
        if phase == "station_fault" and what == "end" and self.state["shift"]:
            self._end.set()  # the shift's wait for the instrument ends at its next look
            return True
        if phase == "ask" and what in ANSWER_TEXT and parse_answer(ANSWER_TEXT[what]) is not None:
            self._answers.put(ANSWER_TEXT[what])
            return True
        return False

    def snapshot(self) -> Snapshot:
        """The state for the page, with a fresh live level while a pose is being asked."""
        with self._lock:
            out: Snapshot = {**self.state, "lines": list(self.lines)}
            pose = out["pose"]
            if self._live is not None and pose:
                now = time.monotonic()
                if self._level is None or now - self._level[0] >= self.live_every_s:
                    self._level = (now, self._level_dict(self._live(), pose["expects_g"]))
                out["level"] = self._level[1]
        if out["phase"] == self._final_phase:
            self.final_seen.set()
        return out

    @staticmethod
    def _level_dict(st: PoseStatus, expects_g: list[float]) -> Level:
        x, y = level_xy(st.reading_g if st.board_g is None else st.board_g, np.asarray(expects_g, dtype=float))
        return {"still": st.still, "direction_ok": st.direction_ok, "off_deg": st.off_deg, "face": st.face,
                "reads_g": [float(v) for v in st.reading_g], "bubble": [x, y], "ready": st.accepted,
                "line": st.line()}

    # -- a shift: board after board -------------------------------------------------------
    def start_board(self, serial: str) -> None:
        """The next board begins: the last verdict leaves every screen now, not before."""
        with self._lock:
            board = self.state["board"]
            n = 1 + (board["number"] if board else 0)
            self.lines.clear()
            self.state.update({"phase": "working", "pose": None, "capture": None, "result": None,
                               "board": {"serial": serial, "number": n}, "notice": ""})
            self.state["seq"] += 1

    def end_shift(self, summary: ShiftSummary) -> None:
        """The shift's summary (station/shift.py, as its --json line), shown full-screen on every page."""
        titles = {c: reason_title(c, self.tr) for c in summary["reasons_by_code"]}
        self.set(phase="shift_over", pose=None, capture=None, summary=ShiftView(**summary, reason_titles=titles))

    # -- the end --------------------------------------------------------------------------
    def finish(self, verdict: str, serial: str | None, run_id: int | None, reasons: list[dict[str, str]],
               figures: Mapping[str, float | str | None]) -> None:
        reasons = [{**r, "title": reason_title(r["code"], self.tr)} for r in reasons]  # the operator's words
        self.set(phase="done", pose=None, capture=None,
                 result={"verdict": verdict, "serial": serial, "run_id": run_id, "reasons": reasons,
                         "figures": figures})

    def fail(self, err: BaseException) -> None:
        """The run stopped (operator abort, a station fault, device or config error): shown as such."""
        if is_station_fault(err):
            self.set(phase="done", pose=None, capture=None, result=self._fault_result(operator_text(err, self.tr)))
            return
        kind = "ABORTED" if isinstance(err, (OperatorAbort, KeyboardInterrupt)) else "ERROR"
        text = str(err) if isinstance(err, AccelcalError) else (
            "interrupted (Ctrl-C)" if isinstance(err, KeyboardInterrupt) else f"{type(err).__name__}: {err}")
        self.set(phase="done", pose=None, capture=None,
                 result={"verdict": kind, "serial": None, "run_id": None,
                         "reasons": [{"code": kind.lower(), "message": text,
                                      "title": reason_title(kind.lower(), self.tr)}], "figures": {}})

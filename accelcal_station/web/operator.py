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
from typing import Any

import numpy as np

from ..errors import AccelcalError
from ..fixtures.operator_jig import OperatorAbort
from ..fixtures.operator_ui import CaptureSink, LiveStatus, PosePrompt, PoseStatus, parse_answer
from .board_picture import level_xy, picture

ANSWER_TEXT = {"accept": "", "replace": "r", "skip": "s", "abort": "a"}


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

    def __init__(self, echo: Any, station_id: str, total_poses: int, live_every_s: float = 0.25) -> None:
        self.echo = echo
        self._lock = threading.Lock()
        self._answers: queue.Queue[str | None] = queue.Queue()  # None: the operator aborted
        self._live: LiveStatus | None = None
        self._level: tuple[float, dict[str, Any]] | None = None
        self.live_every_s = live_every_s
        self.lines: deque[str] = deque(maxlen=12)
        self.final_seen = threading.Event()
        self.state: dict[str, Any] = {"phase": "starting", "station": station_id, "total": total_poses,
                                      "seq": 0, "pose": None, "capture": None, "result": None}

    # -- OperatorUI -----------------------------------------------------------------
    def say(self, text: str) -> None:
        self.echo(text)
        with self._lock:
            self.lines.append(text)
            self.state["seq"] += 1

    def show_pose(self, prompt: PosePrompt) -> None:
        self.echo(f"Pose {prompt.pose.name}: put the board {prompt.words}")
        p = prompt.pose
        self.set(phase="place", pose={"number": prompt.number, "name": p.name, "words": prompt.words,
                                      "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg,
                                      "expects_g": [float(v) for v in p.reference_g],
                                      "picture": picture(p.reference_g)})

    def ask(self, prompt: PosePrompt, live: LiveStatus | None) -> str:
        with self._lock:
            self._live, self._level = live, None
            self.state.update(phase="ask", capture=None)
            self.state["seq"] += 1
        try:
            return self._wait_answer()
        finally:
            with self._lock:  # the page's level never reads the board after this
                self._live = None
                self.state["phase"] = "working"

    def ask_serial(self, text: str) -> str:
        self.set(phase="serial", question=text)
        try:
            return self._wait_answer()
        except OperatorAbort:
            raise OperatorAbort("operator aborted at the serial-number scan") from None
        finally:
            self.set(phase="working")

    def capture(self, label: str) -> CaptureSink:
        return Progress(self, label)

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

    def set(self, **kw: Any) -> None:
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
        if phase == "serial" and what == "abort":
            self._answers.put(None)  # as end of input at the terminal's scan prompt
            return True
        if phase == "ask" and what in ANSWER_TEXT and parse_answer(ANSWER_TEXT[what]) is not None:
            self._answers.put(ANSWER_TEXT[what])
            return True
        return False

    def snapshot(self) -> dict[str, Any]:
        """The state for the page, with a fresh live level while a pose is being asked."""
        with self._lock:
            out = dict(self.state, lines=list(self.lines))
            if self._live is not None and out.get("pose"):
                now = time.monotonic()
                if self._level is None or now - self._level[0] >= self.live_every_s:
                    self._level = (now, self._level_dict(self._live(), out["pose"]["expects_g"]))
                out["level"] = self._level[1]
        if out["phase"] == "done":
            self.final_seen.set()
        return out

    @staticmethod
    def _level_dict(st: PoseStatus, expects_g: list[float]) -> dict[str, Any]:
        x, y = level_xy(st.reading_g if st.board_g is None else st.board_g, np.asarray(expects_g, dtype=float))
        return {"still": st.still, "direction_ok": st.direction_ok, "off_deg": st.off_deg, "face": st.face,
                "reads_g": [float(v) for v in st.reading_g], "bubble": [x, y], "ready": st.accepted,
                "line": st.line()}

    # -- the end --------------------------------------------------------------------------
    def finish(self, verdict: str, serial: str | None, run_id: int | None, reasons: list[dict[str, str]],
               figures: dict[str, Any]) -> None:
        self.set(phase="done", pose=None, capture=None,
                 result={"verdict": verdict, "serial": serial, "run_id": run_id, "reasons": reasons,
                         "figures": figures})

    def fail(self, err: BaseException) -> None:
        """The run stopped (operator abort, device or config error): shown as such."""
        kind = "ABORTED" if isinstance(err, (OperatorAbort, KeyboardInterrupt)) else "ERROR"
        text = str(err) if isinstance(err, AccelcalError) else (
            "interrupted (Ctrl-C)" if isinstance(err, KeyboardInterrupt) else f"{type(err).__name__}: {err}")
        self.set(phase="done", pose=None, capture=None,
                 result={"verdict": kind, "serial": None, "run_id": None,
                         "reasons": [{"code": kind.lower(), "message": text}], "figures": {}})

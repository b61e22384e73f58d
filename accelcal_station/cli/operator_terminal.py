"""The operator jig's terminal front end (fixtures/operator_ui.py's OperatorUI): click prompts
on stderr (so `accelcal run --json` keeps stdout for its one JSON object), the live reading
redrawn in place with ANSI escapes while a prompt waits, and a progress bar for long captures."""
from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import click

from ..fixtures.operator_jig import OperatorAbort, pose_words
from ..fixtures.operator_ui import CaptureSink, LiveStatus, PosePrompt
from ..i18n import Translate


class CaptureProgress:
    """A progress bar (stderr) for any capture that takes longer than a moment of wall time.

    Virtual-clock captures finish in milliseconds and never show one; a real board at
    100 Hz averaging for seconds does.
    """

    def __init__(self, label: str, after_s: float = 0.5) -> None:
        self.label, self.after_s = label, after_s
        self.t0 = time.monotonic()
        self.bar: Any = None  # a click progress bar once shown
        self.done = 0

    def __call__(self, fraction: float) -> None:
        if self.bar is None:
            if time.monotonic() - self.t0 < self.after_s:
                return
            self.bar = click.progressbar(length=1000, label=self.label, file=sys.stderr)
            self.bar.__enter__()
        step = int(1000 * min(max(fraction, 0.0), 1.0)) - self.done
        if step > 0:
            self.bar.update(step)
            self.done += step

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None


def _prompt(text: str, **kw: Any) -> str:
    """One prompt; Ctrl-C or end of input is the operator aborting, not a failed board."""
    try:
        return str(click.prompt(text, err=True, **kw))
    except (click.exceptions.Abort, EOFError, KeyboardInterrupt):
        raise OperatorAbort("end of input or Ctrl-C at the prompt") from None


class TerminalOperator:
    """The OperatorUI of `accelcal run`: lines through ``echo``, answers typed at click prompts."""

    def __init__(self, echo: Callable[[str], None], tr: Translate = str) -> None:
        self.echo = echo
        self.tr = tr  # the operator's language (i18n): prompts and pose lines, never the engineers' output

    def say(self, text: str) -> None:
        self.echo(text)

    def show_pose(self, prompt: PosePrompt) -> None:
        words = pose_words(prompt.pose, self.tr)  # the operator's language; prompt.words stays English
        self.echo(self.tr("Pose {name}: put the board {words}").format(name=prompt.pose.name, words=words))

    def ask(self, prompt: PosePrompt, live: LiveStatus | None) -> str:
        if live is not None:  # the live reading while the board is placed, before Enter
            self.echo(f"  now {live().line()}")
        with _live_refresh(live):
            return _prompt("  " + self.tr("Enter=accept  r=re-place  s=skip  a=abort"), default="", show_default=False)

    def ask_serial(self, text: str) -> str:
        try:
            return _prompt(self.tr(text))
        except OperatorAbort:
            raise OperatorAbort("operator aborted at the serial-number scan") from None

    def station_fault(self, text: str) -> None:
        self.echo(f"{self.tr('STATION FAULT')}: {text}")

    def end_requested(self) -> bool:
        return False  # at the terminal a shift ends by end of input or Ctrl-C

    def capture(self, label: str) -> CaptureSink:
        return CaptureProgress(label)


@contextmanager
def _live_refresh(live: LiveStatus | None, every_s: float = 0.5) -> Iterator[None]:
    """While the prompt waits on a terminal, redraw the 'now [...]' line above it in place
    (ANSI save cursor, up one line, clear, restore), so the operator sees the board move.
    The reader thread is joined before the prompt returns: the driver is never read twice at once."""
    if live is None or not sys.stderr.isatty():
        yield
        return
    stop = threading.Event()

    def refresh() -> None:
        while not stop.wait(every_s):
            try:
                text = live().line()
            except Exception:
                return
            sys.stderr.write(f"\x1b7\x1b[1A\r\x1b[2K  now {text}\x1b8")
            sys.stderr.flush()

    t = threading.Thread(target=refresh, name="live-reading", daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join()

"""A shift at the station: one process calibrates board after board (`accelcal run --shift`).

Each board starts with its serial (scanned: a barcode reader types it and Enter; blank lines are
ignored), is calibrated exactly as `accelcal run` calibrates one board (the one flow:
flow.make_flow), and is a normal run in the store.  End of input at the serial prompt (or the
page's End shift) ends the shift with its tally.  A device that is gone between boards is one line
and a bounded wait for it to come back, never a traceback.
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypedDict

from ..config.serials import check_serial
from ..drivers.factory import make_driver
from ..errors import AccelcalError, ConfigError, DataError, DeviceError, NVMError
from ..fixtures.operator_jig import OperatorAbort
from ..fixtures.operator_ui import OperatorUI
from ..i18n import N_, Translate, reason_title
from .flow import StationFlow, make_flow
from .report import RunReport
from .settings import StationConfig
from .station_fault import is_station_fault, operator_text

DEVICE_WAIT_S = 120.0  # how long a shift waits for a device that is gone before it ends
POLL_S = 1.0


class ShiftEnded(Exception):
    """The operator ended the shift at the serial prompt (end of input, Ctrl-C or End shift)."""


class DeviceGone(DeviceError):
    """The device stayed away longer than the shift waits for it."""


class BoardOutcomeJson(TypedDict):
    """A board of the shift as `run --shift --json` prints one that did not finish, and as the summary lists it."""

    serial: str
    run_id: int | None
    verdict: str
    reason_codes: list[str]
    reasons: list[str]
    retest: bool


@dataclass(frozen=True)
class BoardOutcome:
    """One board of the shift: its serial, run, verdict (PASS, FAIL, ABORTED, ERROR) and reason codes."""

    serial: str
    run_id: int | None
    verdict: str
    reason_codes: tuple[str, ...]
    messages: tuple[str, ...]
    retest: bool  # this serial was already calibrated earlier in the shift

    def to_dict(self) -> BoardOutcomeJson:
        return {"serial": self.serial, "run_id": self.run_id, "verdict": self.verdict,
                "reason_codes": list(self.reason_codes), "reasons": list(self.messages), "retest": self.retest}


# The shift's end as `run --shift --json` prints it (kind "shift") and the operator page shows it: its
# boards by verdict (pass, fail, aborted, error), the first-pass yield (0..1), the failing reason codes
# (functional form: "pass" is a keyword)
ShiftSummary = TypedDict("ShiftSummary", {
    "kind": str, "station_id": str | None, "started_utc": str, "ended_utc": str, "ended_by": str, "boards": int,
    "serials": int, "pass": int, "fail": int, "aborted": int, "error": int, "first_pass_yield": float | None,
    "reasons_by_code": dict[str, int], "runs": list[BoardOutcomeJson]})


@dataclass
class ShiftTally:
    """The shift so far; ``summary`` is what its end prints.

    First-pass yield = serials that passed at their first run of the shift / distinct serials
    (a retest that passes later does not count as a first pass)."""

    station_id: str | None
    started_utc: float = field(default_factory=time.time)
    boards: list[BoardOutcome] = field(default_factory=list)
    ended_by: str = "end of input"

    def add(self, serial: str, run_id: int | None, verdict: str, reasons: list[tuple[str, str]]) -> BoardOutcome:
        seen = any(b.serial == serial for b in self.boards)
        b = BoardOutcome(serial, run_id, verdict, tuple(c for c, _ in reasons), tuple(m for _, m in reasons), seen)
        self.boards.append(b)
        return b

    def summary(self) -> ShiftSummary:
        verdicts = Counter(b.verdict for b in self.boards)
        firsts = [b for b in self.boards if not b.retest]
        fpy = None if not firsts else sum(b.verdict == "PASS" for b in firsts) / len(firsts)
        codes = Counter(c for b in self.boards if b.verdict != "PASS" for c in b.reason_codes)
        return {"kind": "shift", "station_id": self.station_id, "started_utc": _utc(self.started_utc),
                "ended_utc": _utc(time.time()), "ended_by": self.ended_by, "boards": len(self.boards),
                "serials": len(firsts), "pass": verdicts["PASS"], "fail": verdicts["FAIL"],
                "aborted": verdicts["ABORTED"], "error": verdicts["ERROR"], "first_pass_yield": fpy,
                "reasons_by_code": dict(codes.most_common()), "runs": [b.to_dict() for b in self.boards]}


def _utc(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


def summary_lines(s: ShiftSummary, tr: Translate = str) -> list[str]:
    """The shift's end for the operator's terminal, in the operator's language (``tr``)."""
    fpy = "-" if s["first_pass_yield"] is None else f"{100 * s['first_pass_yield']:.1f} %"
    out = [tr("shift {station} {start} to {end} (UTC), ended by {why}").format(
               station=s["station_id"] or "", start=s["started_utc"], end=s["ended_utc"], why=tr(s["ended_by"])),
           "  " + tr("boards {boards} ({serials} serials): PASS {passed}, FAIL {failed}, aborted {aborted}, "
                     "error {error}; first-pass yield {fpy}").format(
               boards=s["boards"], serials=s["serials"], passed=s["pass"], failed=s["fail"], aborted=s["aborted"],
               error=s["error"], fpy=fpy)]
    if s["reasons_by_code"]:
        out.append("  " + tr("reasons by code:") + " " + ", ".join(
            f"{reason_title(c, tr) if c else '-'} ({c}) {n}" for c, n in s["reasons_by_code"].items()))
    return out


def ask_serial(ui: OperatorUI, text: str, tr: Translate = str) -> str:
    """The next board's serial; blank answers are ignored, a bad one is said and asked again;
    ShiftEnded on end of input (OperatorAbort from the front end)."""
    while True:
        try:
            got = ui.ask_serial(text)
        except OperatorAbort:
            raise ShiftEnded() from None
        if not got.strip():
            continue
        try:
            return check_serial(got, "scanned serial")
        except DataError as e:
            ui.say("  " + tr("{error}; scan again").format(error=e))


def wait_for_device(cfg: StationConfig, say: Callable[[str], None], wait_s: float = DEVICE_WAIT_S,
                    poll_s: float = POLL_S, sleep: Callable[[float], None] = time.sleep, tr: Translate = str,
                    ui: OperatorUI | None = None) -> None:
    """Open and identify the configured device; while it does not answer, say so once (on ``ui``: as the
    station's fault, full screen) and retry every ``poll_s`` for at most ``wait_s`` (DeviceGone after
    that; ShiftEnded when the operator ends the shift meanwhile)."""
    t0 = time.monotonic()
    first: AccelcalError | None = None
    while True:
        if first is not None and ui is not None and ui.end_requested():
            raise ShiftEnded()
        try:
            with make_driver(cfg.device) as driver:
                driver.identify()
        except DeviceError as e:
            if first is None:
                first = e
                say(tr("device not answering ({error}); waiting up to {s} s for it to come back").format(
                    error=e, s=f"{wait_s:.0f}"))
                if ui is not None:
                    ui.station_fault(operator_text(e, tr))
            if time.monotonic() - t0 >= wait_s:
                raise DeviceGone(f"device still not answering after {wait_s:.0f} s ({e}); "
                                 "connect it and start the shift again") from None
            sleep(poll_s)
            continue
        if first is not None:
            say(tr("device back after {s} s").format(s=f"{time.monotonic() - t0:.0f}"))
        return


def board_station(cfg: StationConfig, operator: str | None, serial: str | None, lot: str | None,
                  echo: Callable[[str], None], ui: OperatorUI) -> StationFlow:
    """The flow that calibrates one board as `accelcal run` does (at each set point when the config
    plans temperatures)."""
    return make_flow(cfg, operator=operator, serial=serial, lot=lot, echo=echo, ui=ui)


# what the front end does with each board as it ends: its outcome, and its report when it finished
OnBoard = Callable[[BoardOutcome, RunReport | None], None]
SERIAL_PROMPT = N_("Board {n}: scan the serial number (end of input ends the shift)")
SERIAL_PROMPT_PAGE = N_("Board {n}: scan the serial number")
ENDED_BY = (N_("end of input"), N_("Ctrl-C"), N_("device gone"))  # ShiftTally.ended_by, English in --json


@dataclass(frozen=True)
class ShiftFrontEnd:
    """How a shift speaks with its operator: the front end that asks for serials (terminal or
    browser), where the boards' lines go, the serial prompt (``{n}``: the board's number) and the
    translation of what the operator reads."""

    ui: OperatorUI
    echo: Callable[[str], None]
    prompt: str = SERIAL_PROMPT
    tr: Translate = str


def run_shift(cfg: StationConfig, operator: str | None, lot: str | None, front: ShiftFrontEnd,
              on_board: OnBoard, device_wait_s: float = DEVICE_WAIT_S,
              on_start: Callable[[str], None] | None = None) -> tuple[ShiftTally, DeviceGone | None]:
    """Board after board until the operator ends the shift; returns the tally, and the DeviceGone
    that ended it early if the device never came back.  Ctrl-C ends the shift too (the board it
    interrupts is recorded interrupted, counted aborted)."""
    ui, echo, prompt, tr = front.ui, front.echo, front.prompt, front.tr
    tally = ShiftTally(cfg.station_id)
    while True:
        try:
            serial = ask_serial(ui, prompt.format(n=len(tally.boards) + 1), tr)
            wait_for_device(cfg, ui.say, device_wait_s, tr=tr, ui=ui)
        except ShiftEnded:
            return tally, None
        except KeyboardInterrupt:
            tally.ended_by = "Ctrl-C"
            return tally, None
        except DeviceGone as e:
            tally.ended_by = "device gone"
            return tally, e
        if on_start is not None:
            on_start(serial)
        station = board_station(cfg, operator, serial, lot, echo, ui)
        try:
            rep = station.run()[0]
        except KeyboardInterrupt:
            on_board(tally.add(serial, station.run_id, "ABORTED", [("aborted", "interrupted (Ctrl-C)")]), None)
            tally.ended_by = "Ctrl-C"
            return tally, None
        except OperatorAbort as e:
            on_board(tally.add(serial, station.run_id, "ABORTED", [("aborted", str(e))]), None)
            continue
        except (DeviceError, NVMError) as e:  # recorded as an error run: the next board waits for the device
            on_board(tally.add(serial, station.run_id, "ERROR", [(e.reason_code, str(e))]), None)
            if is_station_fault(e):
                ui.station_fault(operator_text(e, tr))
            continue
        final = rep.final
        on_board(tally.add(serial, rep.run_id, final.label, [(r.code, str(r)) for r in final.reasons]), rep)


def check_shift_config(cfg: StationConfig, serial: str | None) -> None:
    """A shift calibrates one board at a time, each with its scanned serial."""
    if serial is not None:
        raise ConfigError("--serial: a shift scans each board's serial; remove --serial")
    if cfg.is_panel:
        raise ConfigError("--shift: calibrates one board at a time; this config is a panel "
                          "(device.boards): run the panel without --shift")

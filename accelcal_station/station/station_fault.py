"""A fault of the station is never a board's verdict (DESIGN.md "A real measurement"; docs/station.md,
"Station faults").

An instrument the run needs (the device's port or bus, the jig, the chamber, the panel's mux, the
store) that is missing, lost, timing out or answering wrongly ends the run as ``error`` with a typed
station reason and exit 3: the board is neither passed nor failed and counts in no yield.  The jig is
opened and identified before any board's first step (``preflight_jig``), so a missing jig costs no
self-test.  What the board did decide stays a verdict: a self-test out of its limits, a fit, a wrong
pose or a board that never holds still (capture.WrongPose, capture.NotStill).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TypeGuard

from ..config.kinds import JigSection, MotorizedJigConfig
from ..config.schema import ChamberSection, VisaChamberConfig
from ..errors import DeviceError, JigError
from ..fixtures.base import Jig
from ..i18n import N_, Translate
from ..instruments.factory import make_chamber
from ..jsontypes import JsonObject
from .capture import NotStill, WrongPose

# what the operator checks for each instrument before the board is run again (the operator's catalog)
WHAT_TO_CHECK: dict[str, str] = {
    "device": N_("check the board's cable and connector and that the board sits in the jig"),
    "jig": N_("check the jig's cable, power and emergency stop"),
    "chamber": N_("check the chamber's cable, power and door"),
    "mux": N_("check the panel's I2C multiplexer and its cable"),
    "store": N_("check the results store (disk space, the line database's network)"),
}
FAULT_TITLE = N_("the station faulted: this board is not judged")


def is_station_fault(e: BaseException) -> TypeGuard[DeviceError]:
    """An instrument's fault (the station's), not something the board itself decided."""
    return isinstance(e, DeviceError) and not isinstance(e, (WrongPose, NotStill))


def instrument_of(e: DeviceError) -> str:
    """The instrument that faulted, as the error types it (errors.DeviceError.instrument)."""
    return e.instrument if e.instrument in WHAT_TO_CHECK else "device"


def station_fault_reason(e: DeviceError, why: str | None = None) -> str:
    """The run's status reason in the store: ``station fault (INSTRUMENT): what happened`` (``why``: the
    error in the words of the conditions, e.g. a thermal plan's set point; default the error's own)."""
    return f"station fault ({instrument_of(e)}): {why or e}"


def station_fault_line(e: DeviceError, *, before_board: bool, poses: int = 0) -> str:
    """What the terminal says: the fault, that the board is not judged, and what to check."""
    where = "before the board's first step" if before_board else f"after {poses} poses"
    return (f"STATION FAULT ({instrument_of(e)}, {where}): {e}; the board is not judged (no PASS, no FAIL); "
            f"{WHAT_TO_CHECK[instrument_of(e)]}, then run the board again")


def operator_text(e: DeviceError, tr: Translate) -> str:
    """The operator's words for a station fault: what to check, in the operator's language, then the
    instrument's own message (the engineers' English, as the log has it)."""
    return tr("{check}, then run the board again ({error})").format(check=tr(WHAT_TO_CHECK[instrument_of(e)]),
                                                                    error=e)


def nvm_held_line(nvm: JsonObject | None) -> str:
    """What a board holds when a fault came after its NVM burn had begun (the writer's restore path ran)."""
    if nvm is None:
        return ""
    if nvm.get("ok"):
        return f"the board holds the new calibration (slot {nvm.get('slot')}, verified)"
    return "the NVM burn did not complete; the board keeps its previous calibration (the writer restored it)"


def preflight_chamber(section: ChamberSection | None) -> None:
    """Open a real chamber and read its status before any board's first step (ChamberError when it cannot);
    an emulated chamber is built around the simulated boards' clock by the thermal flow, nothing to check."""
    if not isinstance(section, VisaChamberConfig):
        return
    with make_chamber(section) as chamber:
        chamber.status()


def preflight_jig(section: JigSection, given: Jig | None, build: Callable[[], Jig]) -> Jig | None:
    """Open and identify a jig that is an instrument of its own (a motorized jig on its port) before any
    board's first step; the jig the flow is to use (``given``, else ``build()``), or ``given`` untouched
    when the jig is built with the boards (simulated, operator).  JigError when it cannot be opened."""
    if not isinstance(section, MotorizedJigConfig):
        return given
    jig = given if given is not None else build()
    try:
        jig.open()
    except JigError:
        jig.close()
        raise
    except DeviceError as e:
        jig.close()
        raise JigError(f"jig: {e}") from None
    return jig

"""Instruments beside the device and the jig: the thermal chamber.

``make_chamber(chamber, board)`` builds the chamber a validated ``chamber:`` section names, like
``drivers.make_driver``: ``type: visa`` opens a real chamber through the VISA backend its
``visa_library`` names; ``type: emulated`` starts the chamber emulator on a pseudo-terminal around
the simulated board (its clock and its temperature) and hands the port to the real driver, so the
emulated station runs the real protocol code.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..config.schema import ChamberEmulatorSection, ChamberSection, VisaChamberConfig
from ..errors import ConfigError
from .chamber import AsciiChamber, Chamber, require_pyvisa

if TYPE_CHECKING:
    from ..drivers.simulated import SimulatedBoard
    from .chamber_emulator import ChamberEmulator

EMULATED_VISA = "@py"  # the emulator's pseudo-terminal is a serial port: pyvisa-py opens it


def make_chamber(chamber: ChamberSection, board: SimulatedBoard | None = None, path: str = "chamber",
                 others: Sequence[SimulatedBoard | None] = ()) -> Chamber:
    """The chamber of a validated ``chamber`` section (a station's; a test's mapping through
    config/schema.py's ``validate_chamber`` first).  The emulated one starts its emulator (stopped on
    close) around the simulated ``board`` (its clock) and the ``others`` of a panel: every board sits
    in the same chamber air."""
    c = chamber
    if isinstance(c, VisaChamberConfig):
        require_pyvisa(path, c.visa_library)  # an optional extra: said before a port is opened
        return AsciiChamber(c.port, c.baud, c.timeout_s, c.retries, c.min_c, c.max_c, c.visa_library)
    require_pyvisa(path, EMULATED_VISA)
    if board is None:
        raise ConfigError(f"{path}.type: emulated needs a simulated or emulated device (the board in the "
                          "chamber); allowed with real hardware: type: visa and its port")
    from .chamber_emulator import ChamberEmulator

    emu = ChamberEmulator.from_section(c.emulator or ChamberEmulatorSection(), board.clock, f"{path}.emulator")
    for b in (board, *others):
        if b is not None:
            couple(b, emu)
    out = AsciiChamber(emu.start(), timeout_s=c.timeout_s, retries=c.retries, min_c=c.min_c, max_c=c.max_c,
                       visa_library=EMULATED_VISA)
    out.on_close.append(emu.stop)
    return out


def couple(board: SimulatedBoard, emulator: ChamberEmulator) -> None:
    """Put the simulated board in the emulated chamber: its temperature follows the chamber's physics."""
    board.environment = emulator.physics

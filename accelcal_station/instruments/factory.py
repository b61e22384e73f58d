"""Instruments beside the device and the jig: the thermal chamber.

``make_chamber(config, board)`` builds the chamber named by a station config's ``chamber:``
section, like ``drivers.make_driver``; ``port: emulated`` starts the chamber emulator on
a pseudo-terminal around the simulated board (its clock and its temperature) and hands
the port to the real driver, so the emulated station runs the real protocol code.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..config.schema import ChamberSection, given
from ..errors import ConfigError
from .chamber import AsciiChamber, Chamber, require_pyvisa

DRIVERS = ("ascii",)


def make_chamber(config: ChamberSection | dict[str, Any], board: Any = None, path: str = "chamber",
                 others: Sequence[Any] = ()) -> Chamber:
    """The configured chamber (a station's validated ``chamber`` section, or a mapping); with
    ``port: emulated`` the emulator is started (stopped on close) around the simulated ``board``
    (its clock) and the ``others`` of a panel: every board sits in the same chamber air."""
    if isinstance(config, ChamberSection):
        config = given(config)
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: must be a mapping (driver, port, ...)")
    name = config.get("driver", "ascii")
    if name not in DRIVERS:
        raise ConfigError(f"{path}.driver: {name!r}; allowed: {', '.join(DRIVERS)}")
    # an optional extra: say so before an emulator or port is opened
    require_pyvisa(path, str(config.get("visa_library", "@py")))
    if config.get("port") != "emulated":
        if "emulator" in config:
            raise ConfigError(f"{path}.emulator: only used with port: emulated")
        return AsciiChamber.from_config(config, path)
    if board is None:
        raise ConfigError(f"{path}.port: emulated needs a simulated or emulated device (the board in the chamber)")
    from .chamber_emulator import ChamberEmulator

    emu = ChamberEmulator.from_config(config.get("emulator"), board.clock, f"{path}.emulator")
    for b in (board, *others):
        if b is not None:
            couple(b, emu)
    chamber = AsciiChamber.from_config(config, path, port=emu.start())
    chamber.on_close.append(emu.stop)
    return chamber


def couple(board: Any, emulator: Any) -> None:
    """Put the simulated board in the emulated chamber: its temperature follows the chamber's physics."""
    board.environment = emulator.physics


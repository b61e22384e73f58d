"""A panel's configuration: the per-board device sections of ``device.boards`` and which
thread reads each board (a simulated board's own spread of offsets and gains and how it sits
in its slot are the simulated panel's: fixtures/simulated_panel.py, through fixtures/factory.py).

A ``device:`` section without ``boards`` is a panel of one.  With ``boards``::

    device:
      driver: simulated          # every key here is shared by all boards ...
      simulator: {...}
      boards: 16                 # N boards: seed + i, serial SERIAL-01.., or a list of
                                 # mappings, each merged over the shared keys
      spread: {offset_mg: 20, gain: 0.01}   # simulated boards: each its own offsets/gains
"""
from __future__ import annotations

import copy

import numpy as np

from ..config.parts import PanelSeedSection, parse
from ..config.schema import DeviceSection
from ..config.schema import given as given_keys
from ..errors import ConfigError
from ..fixtures.factory import spread_board
from ..jsontypes import JsonObject

MAX_BOARDS = 64
def _simulated(section: JsonObject) -> bool:
    """A simulated board, or a driver on an emulated bus or port (these take a seed)."""
    return section.get("driver") == "simulated" or "emulated" in (section.get("bus"), section.get("port"))


def panel_sections(device: DeviceSection | JsonObject, path: str = "device") -> list[tuple[JsonObject, str]]:
    """Per-board device sections (the keys each board is given: the panel's shared keys under its
    own) and their key paths; a device without ``boards`` is a panel of one.  ``device``: a
    station's validated section, or a mapping (tests)."""
    if isinstance(device, DeviceSection):
        device = given_keys(device)
    if not isinstance(device, dict):
        raise ConfigError(f"{path}: must be a mapping with a 'driver' key")
    boards = device.get("boards")
    mounted = [f"{path}.mount"] if device.get("mount") is not None else []
    mounted += [f"{path}.boards[{i}].mount" for i, b in enumerate(boards if isinstance(boards, list) else [])
                if isinstance(b, dict) and b.get("mount") is not None]
    if mounted:  # said, not ignored: a panel's boards would be fitted against unturned references
        raise ConfigError(f"{mounted[0]}: a panel does not read device.mount yet; allowed: a one-board run "
                          "(accelcal run without device.boards), or the boards seated as the jig's axes")
    base = {k: v for k, v in device.items() if k not in ("boards", "spread")}
    if boards is None:
        if "spread" in device:
            raise ConfigError(f"{path}.spread: only used with {path}.boards")
        return [(base, path)]
    if isinstance(boards, bool) or not isinstance(boards, (int, list)):
        raise ConfigError(f"{path}.boards: {boards!r}; allowed: a count 1..{MAX_BOARDS} or a list of mappings")
    n = boards if isinstance(boards, int) else len(boards)
    if not 1 <= n <= MAX_BOARDS:
        raise ConfigError(f"{path}.boards: {n} boards; allowed: 1..{MAX_BOARDS}")
    given = {"seed": device["seed"]} if device.get("seed") is not None else {}
    seed = parse(given, PanelSeedSection, path).seed if _simulated(device) else 0
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        where = f"{path}.boards[{i}]"
        over = boards[i] if isinstance(boards, list) else {}
        if not isinstance(over, dict):
            raise ConfigError(f"{where}: {over!r}; allowed: a mapping of device keys")
        sec = copy.deepcopy(base)
        if _simulated(device) or _simulated(over):
            sec["seed"] = seed * 1000 + i  # each board its own draws unless its mapping says otherwise
        if device.get("driver") == "simulated":
            sec["serial"] = f"{device.get('serial') or 'PANEL'}-{i + 1:02d}"
        sec.update(copy.deepcopy(over))
        if device.get("spread") is not None:
            sec = spread_board(sec, device["spread"], rng, f"{path}.spread")
        out.append((sec, where))
    return out


def group_of(section: JsonObject, index: int) -> str:
    """The thread a board is read by: its serial port, else its own.

    Boards behind a multiplexer each have their own thread too: their transactions are
    serialised on the bus (MuxBus.lock), so they are read in turn, transaction by
    transaction, within each sample period rather than one whole capture after another.
    """
    if section.get("driver") == "mpu6050" and section.get("port") not in (None, "emulated"):
        return f"serial:{section['port']}"
    return f"board:{index}"

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
      mount: [y, -x, z]          # how every chip sits on its board; a board's own mount overrides it

How each board sits (``mount``) and how a board that looks turned is named: panel_mount.py.
"""
from __future__ import annotations

import numpy as np

from ..config.kinds import (
    DeviceSection,
    Mma8451PanelBoard,
    Mpu6050Device,
    Mpu6050PanelBoard,
    SimulatedDevice,
    SimulatedPanelBoard,
)
from ..errors import ConfigError
from ..fixtures.factory import spread_board

MAX_BOARDS = 64
MAX_PANEL_SEED = 2**32 - 1  # board i draws from seed * 1000 + i: within every driver's seed range
BoardKeys = SimulatedPanelBoard | Mma8451PanelBoard | Mpu6050PanelBoard


def _simulated(section: BoardKeys) -> bool:
    """A simulated board, or a driver on an emulated bus or port (these take a seed)."""
    if isinstance(section, Mma8451PanelBoard):
        return section.bus == "emulated"
    if isinstance(section, Mpu6050PanelBoard):
        return section.port == "emulated"
    return True


def panel_sections(device: DeviceSection, path: str = "device") -> list[tuple[DeviceSection, str]]:
    """Per-board device sections (the panel's shared keys, each board's own over them: typed copies of
    the validated section, ``boards`` and ``spread`` left out) and their key paths; a device without
    ``boards`` is a panel of one."""
    boards = device.boards
    shared = device.model_copy(update={"boards": None, "spread": None})
    if boards is None:
        if device.spread is not None:
            raise ConfigError(f"{path}.spread: only used with {path}.boards")
        return [(shared, path)]
    n = boards if isinstance(boards, int) else len(boards)
    if not 1 <= n <= MAX_BOARDS:
        raise ConfigError(f"{path}.boards: {n} boards; allowed: 1..{MAX_BOARDS}")
    seed = _panel_seed(device, path)
    rng = np.random.default_rng(seed)
    out: list[tuple[DeviceSection, str]] = []
    for i in range(n):
        over = boards[i] if isinstance(boards, list) else None
        update: dict[str, object] = {}
        if _simulated(device) or (over is not None and _simulated(over)):
            update["seed"] = seed * 1000 + i  # each board its own draws unless its mapping says otherwise
        if isinstance(device, SimulatedDevice):
            update["serial"] = f"{device.serial or 'PANEL'}-{i + 1:02d}"
        if over is not None:  # the keys this board's mapping gave, over the panel's
            update.update({k: v for k, v in over if k in over.model_fields_set})
        sec = shared.model_copy(update=update, deep=True)
        if device.spread is not None:
            sec = spread_board(sec, device.spread, rng, f"{path}.spread")
        out.append((sec, f"{path}.boards[{i}]"))
    return out


def own_mount(device: DeviceSection, index: int) -> bool:
    """Board ``index``'s own mapping sets ``mount`` (device.boards[i].mount: device.mount does not reach it)."""
    boards = device.boards
    return isinstance(boards, list) and index < len(boards) and "mount" in boards[index].model_fields_set


def _panel_seed(device: DeviceSection, path: str) -> int:
    """A simulated panel's seed (default 1): board i draws from seed * 1000 + i; 0 for real boards."""
    if not _simulated(device):
        return 0
    seed = 1 if device.seed is None else device.seed
    if seed > MAX_PANEL_SEED:
        raise ConfigError(f"{path}.seed: {seed} out of range; allowed: 0 to {MAX_PANEL_SEED} (a panel's seed)")
    return seed


def configured_serial(section: DeviceSection) -> str:
    """The serial a board's section gives ('' when it gives none; an MPU6050 bridge reports its own)."""
    return "" if isinstance(section, Mpu6050Device) or section.serial is None else str(section.serial)


def group_of(section: DeviceSection, index: int) -> str:
    """The thread a board is read by: its serial port, else its own.

    Boards behind a multiplexer each have their own thread too: their transactions are
    serialised on the bus (MuxBus.lock), so they are read in turn, transaction by
    transaction, within each sample period rather than one whole capture after another.
    """
    if isinstance(section, Mpu6050Device) and section.port not in (None, "emulated"):
        return f"serial:{section.port}"
    return f"board:{index}"

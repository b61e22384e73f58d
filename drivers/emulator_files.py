"""Reading an emulator's settings from a station config file (``accelcal emulate --config F``, an
emulated chip's ``simulator: FILE``): the simulated board a device section describes, and the
chip's faults from its ``device.emulator``.  A file is another input: validated once here,
against the same models as a station config (config/schema.py)."""
from __future__ import annotations

from typing import TypedDict

from numpy.typing import ArrayLike

from ..config.checks import load_yaml
from ..config.kinds import BridgeEmulatorSection, Mpu6050Device, SimulatedBoardSection
from ..config.parts import parse
from ..config.schema import validate_device
from ..errors import ConfigError
from .simulated import SimulatedBoard


class BridgeFaults(TypedDict, total=False):
    """The bridge emulator's chip and faults as keyword arguments of MPU6050BridgeEmulator and SimavrBridge."""

    self_test_codes: list[int]
    self_test_share: list[float]
    offset_step_scale: float
    chip_ppm: float
    who_am_i: int


class BridgeChip(BridgeFaults, total=False):
    """MPU6050BridgeEmulator's keywords (PEP 692): the chip's faults (``BridgeFaults``) and the part
    as wired: a chip on the bus at all, the bridge's serial (8 bytes), the chip's I2C address, its
    factory trim (XA/YA/ZA_OFFS; unset: a draw) and the UART's baud rate."""

    i2c_present: bool
    serial: str | None
    i2c_address: int
    factory_offsets: ArrayLike | None
    baud: int


def bridge_faults(e: BridgeEmulatorSection | None) -> BridgeFaults:
    """The keywords a ``device.emulator`` section gives (those it leaves unset: the emulator's draws)."""
    out = BridgeFaults()
    if e is None:
        return out
    if e.self_test_codes is not None:
        out["self_test_codes"] = e.self_test_codes
    if e.self_test_share is not None:
        out["self_test_share"] = e.self_test_share
    out["offset_step_scale"] = e.offset_step_scale
    out["chip_ppm"] = e.chip_ppm
    out["who_am_i"] = e.who_am_i
    return out


def emulator_options_from_file(path: str) -> BridgeFaults:
    """The bridge emulator's chip and faults (``device.emulator`` of a ``driver: mpu6050`` station config);
    {} when none."""
    data = load_yaml(path)
    dev = data.get("device", data)
    if not isinstance(dev, dict) or dev.get("driver") != "mpu6050" or dev.get("emulator") is None:
        return {}
    m = validate_device(dev, path)
    return bridge_faults(m.emulator if isinstance(m, Mpu6050Device) else None)


def board_config_from_file(path: str, nested: bool = False) -> tuple[SimulatedBoardSection | None, int | None]:
    """A simulated board section and seed from a YAML file (``accelcal emulate --config``, an
    emulated chip's ``simulator: FILE``).

    Accepts a station config whose ``device`` is ``driver: simulated`` (configs/sim.yaml) or
    ``driver: mpu6050`` (its ``simulator`` and ``seed``; a ``simulator`` file of its own is read
    once more, not further), or a bare board mapping.
    """
    data = load_yaml(path)
    dev = data.get("device", data)
    where = f"{path}: device" if "device" in data else str(path)
    if not isinstance(dev, dict):
        raise ConfigError(f"{where}: must be a mapping")
    if "device" not in data and "driver" not in dev:  # a bare board mapping
        return parse(dev, SimulatedBoardSection, where), None
    m = validate_device(dev, path)
    if isinstance(m, SimulatedBoardSection):
        return m, None
    if not isinstance(m, Mpu6050Device):
        raise ConfigError(f"{where}.driver: {m.driver!r}; --config takes a simulated board (driver: simulated, "
                          "e.g. configs/sim.yaml) or an mpu6050 device with a simulator section")
    if isinstance(m.simulator, str):
        if nested:  # a file naming a file naming a file: refused, not followed (a loop never ends)
            raise ConfigError(f"{where}.simulator: {m.simulator!r}; allowed: a board mapping here (this file is "
                              "already another config's simulator)")
        return board_config_from_file(m.simulator, nested=True)[0], m.seed
    return m.simulator, m.seed


def emulated_board(sim: SimulatedBoardSection | str | None, chip: str, seed: int | None, path: str) -> SimulatedBoard:
    """The simulated board behind an emulated chip (``bus: emulated``, ``port: emulated``): its
    ``simulator`` (a board section, or a file as :func:`board_config_from_file` takes; absent: an
    ideal chip of its data sheet) and ``seed`` (default: the file's)."""
    where, file_seed = f"{path}.simulator", None
    if isinstance(sim, str):
        where = f"{path}.simulator({sim})"
        sim, file_seed = board_config_from_file(sim)
    return SimulatedBoard.from_section(sim or SimulatedBoardSection(), chip=chip,
                                       seed=file_seed if seed is None else seed, path=where)

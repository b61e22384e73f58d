"""Reading an emulator's settings from a station config file (``accelcal emulate --config F``): the
simulated board a device section describes, and the chip's faults from its ``device.emulator``."""
from __future__ import annotations

from typing import Any

from ..config.checks import load_yaml
from ..config.parts import Mpu6050SimSection, parse
from ..errors import ConfigError


def emulator_options_from_file(path: str) -> dict[str, Any]:
    """The bridge emulator's chip and faults (``device.emulator`` of an ``driver: mpu6050`` station config,
    BridgeEmulatorSection) as keyword arguments of MPU6050BridgeEmulator and SimavrBridge; {} when none."""
    data = load_yaml(path)
    dev = data.get("device", data)
    if not isinstance(dev, dict) or dev.get("driver") != "mpu6050" or dev.get("emulator") is None:
        return {}
    where = f"{path}: device" if "device" in data else str(path)
    e = parse({"emulator": dev["emulator"]}, Mpu6050SimSection, where).emulator
    assert e is not None, "given above"
    return {k: v for k, v in e.model_dump().items() if v is not None}


def board_config_from_file(path: str) -> tuple[dict[str, Any] | None, int | None]:
    """A simulated board mapping and seed from a YAML file for ``accelcal emulate --config``.

    Accepts a station config whose ``device`` is ``driver: simulated`` (configs/sim.yaml) or
    ``driver: mpu6050`` (its ``simulator`` and ``seed``), or a bare board mapping.
    """
    data = load_yaml(path)
    dev = data.get("device", data)
    where = f"{path}: device" if "device" in data else str(path)
    if not isinstance(dev, dict):
        raise ConfigError(f"{where}: must be a mapping")
    driver = dev.get("driver")
    if driver == "mpu6050":
        m = parse({k: v for k, v in dev.items() if k in ("simulator", "seed")}, Mpu6050SimSection, where)
        sim = load_yaml(m.simulator) if isinstance(m.simulator, str) else m.simulator
        return sim, m.seed
    if driver not in (None, "simulated"):
        raise ConfigError(f"{where}.driver: {driver!r}; --config takes a simulated board (driver: simulated, "
                          "e.g. configs/sim.yaml) or an mpu6050 device with a simulator section")
    return {k: v for k, v in dev.items() if k != "driver"}, None

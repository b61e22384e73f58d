"""Station-config sections that the data commands read (the measurements themselves: loader.py)."""
from __future__ import annotations

from ..errors import ConfigError
from .checks import load_yaml
from .default_config import default_config_path as default_config_path  # its home before issue 51
from .kinds import DeviceSection, Mma8451Device, SimulatedDevice
from .schema import validate_device


def device_section(path: str) -> DeviceSection:
    """The ``device:`` section of a station config, or a file that is only a device section,
    validated once against its driver's model (config/schema.py)."""
    data = load_yaml(path)
    section = data.get("device", data if "driver" in data else None)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: no 'device' section; allowed: a mapping with 'driver: simulated, mma8451 "
                          "or mpu6050'")
    return validate_device(section)


def with_port(section: DeviceSection, port: str) -> DeviceSection:
    """--port overrides the serial port, or the I2C bus of an MMA8451 (a number or /dev/i2c-N)."""
    if isinstance(section, Mma8451Device):
        return section.model_copy(update={"bus": int(port) if port.isdigit() else port})
    if isinstance(section, SimulatedDevice):
        raise ConfigError(f"--port {port}: the simulated driver has no port")
    return section.model_copy(update={"port": port})

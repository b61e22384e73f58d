"""Station-config sections that the data commands read (the measurements themselves: loader.py)."""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from ..errors import ConfigError
from .checks import load_yaml
from .schema import validate_device


def default_config_path() -> Path:
    """configs/sim.yaml, wherever the package is installed (an editable checkout or site-packages).

    Resolved, so a checkout names the file where it lies (``configs/sim.yaml``), not through the
    package's link to that folder.
    """
    return Path(str(files("accelcal_station.configs").joinpath("sim.yaml"))).resolve()


def device_section(path: str) -> dict:
    """The ``device:`` section of a station config, or a file that is only a device section."""
    data = load_yaml(path)
    section = data.get("device", data if "driver" in data else None)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: no 'device' section; allowed: a mapping with 'driver: simulated, mma8451 "
                          "or mpu6050'")
    validate_device(section)  # its driver's keys, types and ranges: one validation (config/schema.py)
    return dict(section)


def with_port(section: dict, port: str) -> dict:
    """--port overrides the serial port, or the I2C bus of an MMA8451 (a number or /dev/i2c-N)."""
    if section.get("driver") == "mma8451":
        section["bus"] = int(port) if port.isdigit() else port
    elif section.get("driver") == "simulated":
        raise ConfigError(f"--port {port}: the simulated driver has no port")
    else:
        section["port"] = port
    return section

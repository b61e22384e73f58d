"""Station-config sections that the data commands read (the measurements themselves: loader.py)."""
from __future__ import annotations

from .config import load_yaml
from .errors import ConfigError


def device_section(path: str) -> dict:
    """The ``device:`` section of a station config, or a file that is only a device section."""
    data = load_yaml(path)
    section = data.get("device", data if "driver" in data else None)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: no 'device' section; allowed: a mapping with 'driver: simulated, mma8451 "
                          "or mpu6050'")
    return dict(section)

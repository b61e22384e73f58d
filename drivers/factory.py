"""Sensor drivers: MMA8451 (I2C, smbus2), MPU6050 (serial bridge), simulated board.

``make_driver(config)`` builds a driver by name, like python-can's
``Bus(interface=...)``; the ``simulated`` driver makes every test hardware-free.
"""
from __future__ import annotations

import importlib
from typing import Any

from ..config.schema import DeviceSection, given
from ..errors import ConfigError
from .base import Driver

# name -> "module:Class"; imported lazily so a missing optional library only
# matters for the driver that needs it
DRIVERS = {
    "simulated": "accelcal_station.drivers.simulated:SimulatedDriver",
    "mma8451": "accelcal_station.drivers.mma8451:MMA8451",
    "mpu6050": "accelcal_station.drivers.mpu6050:MPU6050Bridge",
}

# name -> (config key that says "emulated", "module:factory function")
EMULATED = {
    "mma8451": ("bus", "accelcal_station.drivers.emulated:emulated_mma8451"),
    "mpu6050": ("port", "accelcal_station.drivers.emulated:emulated_mpu6050"),
}


# a board behind a TCA9548A multiplexer: bus: emulated -> the emulated mux, else the real one
MUXED = {True: "accelcal_station.drivers.emulated:emulated_muxed_mma8451",
         False: "accelcal_station.drivers.tca9548a:muxed_mma8451"}


def make_driver(config: DeviceSection | dict[str, Any], path: str = "device",
                buses: dict[Any, Any] | None = None) -> Driver:
    """Build the driver named by ``config['driver']`` from the rest of the section.

    ``config``: a station's validated ``device`` section (StationConfig.device), or a mapping
    (a command's own device file, a test).  A section with ``mux`` is an MMA8451 behind a
    TCA9548A channel; ``buses`` (one per panel) shares one multiplexed bus among the boards on it."""
    if isinstance(config, DeviceSection):
        config = given(config)
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: must be a mapping with a 'driver' key")
    # device.mount is the station's (how the chip sits on the board: words, jig and fit use it), not the driver's
    config = {k: v for k, v in config.items() if k != "mount"}
    name = config.get("driver")
    if name not in DRIVERS:
        raise ConfigError(f"{path}.driver: {name!r}; allowed: {', '.join(DRIVERS)}")
    if config.get("mux") is not None:
        if name != "mma8451":
            raise ConfigError(f"{path}.mux: a TCA9548A multiplexer holds I2C boards (driver: mma8451)")
        module, fn = MUXED[config.get("bus") == "emulated"].split(":")
        return getattr(importlib.import_module(module), fn)(config, path, {} if buses is None else buses)
    rest = {k: v for k, v in config.items() if k != "driver"}
    if name in EMULATED and rest.get(EMULATED[name][0]) == "emulated":
        # the emulated bus/port is built here and handed to the driver (python-can's `virtual`)
        module, fn = EMULATED[name][1].split(":")
        return getattr(importlib.import_module(module), fn)(rest, path)
    module, cls = DRIVERS[name].split(":")
    driver_cls = getattr(importlib.import_module(module), cls)
    return driver_cls.from_config(rest, path=path)


"""Sensor drivers: MMA8451 (I2C, smbus2), MPU6050 (serial bridge), simulated board.

``make_driver(device)`` builds the driver a validated ``device`` section names, like python-can's
``Bus(interface=...)``: ``device.driver`` is looked up in the ``accelcal.drivers`` entry points
(drivers/registry.py), so a new chip needs no edit here. The ``simulated`` driver makes every test
hardware-free. The section is the typed model of config/schema.py (a station's ``cfg.device``, a
panel board's section from station/panel_config.py, or a command's or test's mapping put through
``validate_device`` first): the factory passes it to the registered factory and validates nothing again.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from .base import Driver
from .registry import EMULATED, driver_factory

if TYPE_CHECKING:
    from ..config.kinds import DeviceSection
    from .tca9548a import MuxBuses


def make_driver(device: DeviceSection, path: str = "device", buses: MuxBuses | None = None) -> Driver:
    """Build the driver of a validated ``device`` section (one board: a panel's boards come one by
    one from station/panel_config.py).

    ``bus: emulated`` / ``port: emulated`` pick the registry's ``NAME-emulated`` factory, which builds
    the emulated bus or port and hands it to the real driver (python-can's ``virtual``); a section
    with ``mux`` is an MMA8451 behind a TCA9548A channel, and ``buses`` (one per panel) shares one
    multiplexed bus among the boards on it. ``device.mount`` is the station's (how the chip sits on
    the board), never the driver's."""
    name = device.driver + (EMULATED if device.emulated else "")
    return driver_factory(name, f"{path}.driver")(device, path, {} if buses is None else buses)

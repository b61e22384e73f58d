"""Sensor drivers: MMA8451 (I2C, smbus2), MPU6050 (serial bridge), simulated board.

``make_driver(device)`` builds the driver a validated ``device`` section names, like python-can's
``Bus(interface=...)``; the ``simulated`` driver makes every test hardware-free.  The section is
the typed model of config/schema.py (a station's ``cfg.device``, a panel board's section from
station/panel_config.py, or a command's or test's mapping put through ``validate_device`` first):
the factory passes its typed fields to the constructors and validates nothing again.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..config.kinds import DeviceSection, Mma8451Device, Mpu6050Device, SimulatedDevice
from .base import Driver

if TYPE_CHECKING:
    from .tca9548a import MuxBuses


def make_driver(device: DeviceSection, path: str = "device", buses: MuxBuses | None = None) -> Driver:
    """Build the driver of a validated ``device`` section (one board: a panel's boards come one by
    one from station/panel_config.py).

    ``bus: emulated`` / ``port: emulated`` build the emulated bus or port here and hand it to the
    real driver (python-can's ``virtual``); a section with ``mux`` is an MMA8451 behind a TCA9548A
    channel, and ``buses`` (one per panel) shares one multiplexed bus among the boards on it.
    ``device.mount`` is the station's (how the chip sits on the board), never the driver's."""
    # imported lazily: a station loads only the driver (and emulator) it uses
    if isinstance(device, SimulatedDevice):
        from .simulated import SimulatedBoard, SimulatedDriver

        return SimulatedDriver(SimulatedBoard.from_section(device, path=path))
    if isinstance(device, Mma8451Device):
        return _mma8451(device, path, {} if buses is None else buses)
    return _mpu6050(device, path)


def _mma8451(device: Mma8451Device, path: str, buses: MuxBuses) -> Driver:
    emulated = device.bus == "emulated"
    if device.mux is not None:
        if emulated:
            from .emulated import emulated_muxed_mma8451

            return emulated_muxed_mma8451(device, path, buses)
        from .tca9548a import muxed_mma8451

        return muxed_mma8451(device, path, buses)
    if emulated:
        from .emulated import emulated_mma8451

        return emulated_mma8451(device, path)
    from .mma8451 import MMA8451, settings_of

    kw = settings_of(device, path)
    return MMA8451(device.bus, **kw)


def _mpu6050(device: Mpu6050Device, path: str) -> Driver:
    from .mpu6050 import MPU6050Bridge, settings_of

    port, kw = settings_of(device, path)
    if port == "emulated":
        from .emulated import emulated_mpu6050

        return emulated_mpu6050(device, path)
    return MPU6050Bridge(port, **kw)

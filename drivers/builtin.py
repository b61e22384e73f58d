"""The built-in drivers' factories, registered in pyproject.toml's ``accelcal.drivers`` entry points
(drivers/registry.py): the simulated board, the MMA8451 on I2C (alone or behind a TCA9548A channel)
and the MPU6050 serial bridge. Their emulated variants are in drivers/emulated.py: a driver never
imports its emulator. Each imports its driver when first asked for, so a station loads only its own.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

from ..config.kinds import Mma8451Device, Mpu6050Device, SimulatedDevice
from .base import Driver
from .registry import declares

if TYPE_CHECKING:
    from ..config.section import Section
    from .tca9548a import MuxBuses

S = TypeVar("S")


def section_as(device: Section, kind: type[S], name: str) -> S:
    """``device`` as the section model ``kind`` of driver ``name`` (the registry routed it by ``driver``, so
    another model is a wiring error, not bad input)."""
    if not isinstance(device, kind):
        raise TypeError(f"the {name} driver's factory got a {type(device).__name__}, not a {kind.__name__}")
    return device


@declares(SimulatedDevice)
def build_simulated(device: Section, path: str, buses: MuxBuses) -> Driver:
    """``driver: simulated``: a simulated board (forward physics) behind the Driver interface."""
    from .simulated import SimulatedBoard, SimulatedDriver

    return SimulatedDriver(SimulatedBoard.from_section(section_as(device, SimulatedDevice, "simulated"), path=path))


@declares(Mma8451Device)
def build_mma8451(device: Section, path: str, buses: MuxBuses) -> Driver:
    """``driver: mma8451``: on /dev/i2c-N, or behind channel ``channel`` of the TCA9548A at ``mux``."""
    m = section_as(device, Mma8451Device, "mma8451")
    if m.mux is not None:
        from .tca9548a import muxed_mma8451

        return muxed_mma8451(m, path, buses)
    from .mma8451 import MMA8451
    from .mma8451_settings import settings_of

    return MMA8451(m.bus, settings_of(m, path))


@declares(Mpu6050Device)
def build_mpu6050(device: Section, path: str, buses: MuxBuses) -> Driver:
    """``driver: mpu6050``: the serial bridge on a port."""
    from .mpu6050 import MPU6050Bridge
    from .mpu6050_settings import settings_of

    port, kw = settings_of(section_as(device, Mpu6050Device, "mpu6050"), path)
    return MPU6050Bridge(port, **kw)

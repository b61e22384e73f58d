"""Factories of emulated buses and ports (python-can's ``virtual`` interface in spirit).

A driver never imports its emulator: ``make_driver`` routes ``bus: emulated`` /
``port: emulated`` here through the registry's ``NAME-emulated`` entry points
(drivers/registry.py), and this module builds the register-level emulator and hands it
to the driver as its SMBus (MMA8451) or starts it on the pseudo-terminal the driver opens
(MPU6050 bridge).  The import graph is one way: emulated -> driver, emulated -> emulator.
The real drivers know nothing of emulation: the emulated ones below are the same drivers
with the emulator and its simulated board beside them (``board``, declared on Driver).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Unpack

from ..config.kinds import Mma8451Device, Mma8451Section, Mpu6050Device, Mpu6050Section
from ..config.section import Section
from ..errors import ConfigError
from .base import Clock, Driver
from .builtin import section_as
from .mma8451 import MMA8451
from .mma8451_emulator import MMA8451Emulator
from .mma8451_settings import Mma8451Settings, settings_of
from .mpu6050 import MPU6050Bridge
from .mpu6050_emulator import MPU6050BridgeEmulator
from .mpu6050_settings import Mpu6050Settings
from .mpu6050_settings import settings_of as mpu6050_settings
from .registry import declares
from .tca9548a import MuxBus, MuxBuses, MuxChannel, mux_settings
from .tca9548a_emulator import TCA9548AEmulator


class EmulatedMMA8451(MMA8451):
    """The MMA8451 driver on an emulated bus: the real driver code, the emulator kept beside it."""

    def __init__(self, emulator: MMA8451Emulator, settings: Mma8451Settings, bus: Any = None,
                 clock: Clock | None = None, bus_label: str = "emulated") -> None:
        super().__init__(emulator if bus is None else bus, settings, clock=clock or emulator.clock,
                         bus_label=bus_label)
        self.emulator = emulator
        self.board = emulator.board  # what a simulated jig moves


class EmulatedMPU6050Bridge(MPU6050Bridge):
    """The MPU6050 bridge driver on a pseudo-terminal answered by the bridge emulator, which
    starts when the driver opens and stops when it closes."""

    def __init__(self, emulator: MPU6050BridgeEmulator, **settings: Unpack[Mpu6050Settings]) -> None:
        super().__init__("emulated", **settings)
        self.emulator = emulator
        self.board = emulator.board

    def open(self) -> None:
        if self.link.is_open:
            return
        self.port = self.link.port = self.emulator.start()
        super().open()  # a port that fails to open closes the driver, which stops the emulator

    def close(self) -> None:
        super().close()
        self.emulator.stop()


def emulated_mma8451(m: Mma8451Section, path: str = "device", bus: Any = None,
                     bus_label: str = "emulated") -> EmulatedMMA8451:
    """An MMA8451 driver on an emulated smbus2 bus fed by a simulated board.

    ``bus``: the SMBus-like object the driver talks through (default: the chip's own
    emulator; a multiplexer channel for a panel); the driver waits on the emulator's clock.
    """
    kw = settings_of(m, path)
    eeprom = kw.eeprom
    emu = MMA8451Emulator.from_section(m, path, eeprom_address=eeprom.address if eeprom else None)
    if eeprom:  # the emulated EEPROM's geometry is the simulated board's
        kw = replace(kw, eeprom=eeprom.model_copy(update={"size": emu.eeprom_size, "page_size": emu.eeprom_page_size}))
    kw = replace(kw, serial=kw.serial or emu.board.serial)
    return EmulatedMMA8451(emu, kw, bus, bus_label=bus_label)


def emulated_mpu6050(m: Mpu6050Section, path: str = "device") -> MPU6050Bridge:
    """An MPU6050 bridge driver whose port is a pseudo-terminal answered by the bridge emulator."""
    _, kw = mpu6050_settings(m, path)
    return EmulatedMPU6050Bridge(MPU6050BridgeEmulator.from_section(m, path), **kw)


def emulated_muxed_mma8451(m: Mma8451Device, path: str, buses: MuxBuses) -> EmulatedMMA8451:
    """An emulated MMA8451 board behind channel ``m.channel`` of a TCA9548A emulator.

    ``buses`` shares one emulated bus (mux emulator, MuxBus) per mux address among a panel's
    boards: the driver talks smbus2 calls through a :class:`MuxChannel`, the mux emulator
    routes them to this board's MMA8451 emulator; the driver waits on that board's clock.
    """
    address, channel = mux_settings(m, path)
    key = ("emulated", address)
    if key not in buses:
        buses[key] = MuxBus(TCA9548AEmulator(address), address, "emulated")
    mux = buses[key]
    if mux.smbus.channels.get(channel) is not None:
        raise ConfigError(f"{path}.channel: {channel} already holds a board on the emulated bus's "
                          f"mux 0x{address:02x}; allowed: one board per channel")
    drv = emulated_mma8451(m, path, bus=MuxChannel(mux, channel), bus_label=f"emulated/mux0x{address:02x}.{channel}")
    mux.smbus.attach(channel, drv.emulator)
    if m.emulator is not None and m.emulator.mux_reset_after:
        mux.smbus.reset(after_transactions=m.emulator.mux_reset_after, channel=channel)
    return drv


@declares(Mma8451Device)
def build_mma8451(device: Section, path: str, buses: MuxBuses) -> Driver:
    """``mma8451-emulated`` (drivers/registry.py): ``bus: emulated``, alone or behind an emulated TCA9548A."""
    m = section_as(device, Mma8451Device, "mma8451-emulated")
    return emulated_mma8451(m, path) if m.mux is None else emulated_muxed_mma8451(m, path, buses)


@declares(Mpu6050Device)
def build_mpu6050(device: Section, path: str, buses: MuxBuses) -> Driver:
    """``mpu6050-emulated`` (drivers/registry.py): ``port: emulated``, the bridge emulator on a pseudo-terminal."""
    return emulated_mpu6050(section_as(device, Mpu6050Device, "mpu6050-emulated"), path)

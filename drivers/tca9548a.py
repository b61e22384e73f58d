"""TI TCA9548A 1-to-8 I2C multiplexer, host side: one channel as an SMBus-like object.

Data sheet (TCA9548A, SCPS207G): the mux answers at 0x70-0x77 (A2..A0); its one control
register is written and read without a register address (SMBus send/receive byte); bit n
set connects downstream channel n.  :class:`MuxChannel` selects its channel before every
transaction, so any number of identical boards (MMA8451 at 0x1d, EEPROM at 0x50) share
one bus, each behind its own channel.  It wraps a real ``smbus2.SMBus`` or the
register-level emulator (drivers/tca9548a_emulator.py) the same way.
"""
from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import smbus2

from ..config.kinds import Mma8451Device
from ..errors import ConfigError, DeviceError
from .mma8451 import MMA8451
from .mma8451_settings import settings_of

ADDRESSES = range(0x70, 0x78)
CHANNELS = range(8)


class MuxBus:
    """One I2C bus with a TCA9548A on it: remembers the selected channel; one transaction at a time."""

    def __init__(self, smbus: Any, address: int = 0x70, label: str = "") -> None:
        if address not in ADDRESSES:
            raise ConfigError(f"mux.address: 0x{address:02x}; allowed: 0x70..0x77")
        self.smbus, self.address, self.label = smbus, address, label
        self.selected: int | None = None
        self.lock = threading.RLock()
        self.events: list[tuple[int, str]] = []  # (channel, what happened): re-selections after a reset

    def select(self, channel: int, force: bool = False) -> None:
        if force or self.selected != channel:
            self.selected = None  # unknown until the write is acknowledged
            try:
                self.smbus.write_byte(self.address, 1 << channel)
            except OSError as e:
                raise DeviceError(f"TCA9548A at bus {self.label} address 0x{self.address:02x}: cannot select "
                                  f"channel {channel}: {e.strerror or e}") from None
            self.selected = channel

    def forgot(self, channel: int) -> int | None:
        """After a NACK: the control register (SMBus receive byte) if it no longer selects ``channel``
        (the mux was reset: brown-out, a glitch on RESET), else None (the NACK was the device's)."""
        try:
            control = int(self.smbus.read_byte(self.address))
        except OSError:
            return None  # the mux itself does not answer: nothing to re-select
        return None if control >> channel & 1 else control

    def close(self) -> None:
        if hasattr(self.smbus, "close"):
            self.smbus.close()


class MuxChannel:
    """The subset of ``smbus2.SMBus`` the MMA8451 driver uses, through one mux channel."""

    def __init__(self, mux: MuxBus, channel: int) -> None:
        if channel not in CHANNELS:
            raise ConfigError(f"channel: {channel!r}; allowed: 0..7")
        self.mux, self.channel = mux, channel

    def _call(self, name: str, *args: Any) -> Any:
        """One transaction through the channel.  The TCA9548A resets to no channel selected (data sheet:
        power-on, RESET pin), which the remembered selection cannot know: after a NACK, read the
        control register and, if the channel is gone, select it again and retry once (recorded)."""
        with self.mux.lock:
            self.mux.select(self.channel)
            try:
                return getattr(self.mux.smbus, name)(*args)
            except OSError:
                control = self.mux.forgot(self.channel)
                if control is None:
                    raise
            self.mux.select(self.channel, force=True)
            out = getattr(self.mux.smbus, name)(*args)
            self.mux.events.append((self.channel, f"TCA9548A 0x{self.mux.address:02x} had lost channel "
                                                  f"{self.channel} (control read 0x{control:02x}, reset?): "
                                                  "re-selected, transaction retried"))
            return out

    def take_events(self) -> list[str]:
        """The mux events of this channel since the last call (for the run record)."""
        with self.mux.lock:
            mine = [what for ch, what in self.mux.events if ch == self.channel]
            self.mux.events = [(ch, what) for ch, what in self.mux.events if ch != self.channel]
        return mine

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._call("read_byte_data", i2c_addr, register)

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._call("write_byte_data", i2c_addr, register, value)

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force: bool | None = None) -> list[int]:
        return self._call("read_i2c_block_data", i2c_addr, register, length)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int],
                             force: bool | None = None) -> None:
        self._call("write_i2c_block_data", i2c_addr, register, data)

    def i2c_rdwr(self, *msgs: Any) -> None:
        self._call("i2c_rdwr", *msgs)

    def close(self) -> None:
        pass  # the bus belongs to the MuxBus


MuxBuses = dict[tuple[int | str, int], MuxBus]
"""One MuxBus per (I2C bus, mux address), shared by the boards of a panel behind it."""


def mux_settings(m: Mma8451Device, path: str) -> tuple[int, int]:
    """(mux address, channel) of a board behind a mux."""
    if m.mux is None:
        raise ConfigError(f"{path}.mux: required behind a mux")
    if m.channel is None:
        raise ConfigError(f"{path}.channel: required behind a mux; allowed: 0..7")
    return m.mux.address, m.channel


def muxed_mma8451(m: Mma8451Device, path: str, buses: MuxBuses) -> MMA8451:
    """An MMA8451 behind a TCA9548A on a real bus; ``buses`` shares one MuxBus per (bus, mux address)."""
    address, channel = mux_settings(m, path)
    kw = settings_of(m, path)
    bus = m.bus
    key = (bus, address)
    if key not in buses:
        try:
            buses[key] = MuxBus(smbus2.SMBus(bus), address, str(bus))
        except OSError as e:
            raise DeviceError(f"i2c bus {bus}: cannot open: {e.strerror or e}") from None
    return MMA8451(MuxChannel(buses[key], channel), kw, bus_label=f"{bus}/mux0x{address:02x}.{channel}")

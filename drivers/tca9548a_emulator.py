"""Register-level TCA9548A emulator on an emulated smbus2 bus, with emulated boards behind its channels.

The mux at 0x70-0x77 takes SMBus send/receive byte (``write_byte``/``read_byte``) to its
control register; every other transaction goes to the devices of the channels whose bit
is set: a channel's device is a downstream emulated bus (an MMA8451Emulator with its
board's EEPROM).  No device at the address on any enabled channel NACKs; two enabled
channels both answering the address is a bus conflict and NACKs too (a real bus would
garble the data).

Time: one bus, one clock.  :attr:`clock` is the bus's virtual time; a downstream device
is brought up to it before each of its transactions (it latches the samples it produced
meanwhile), and the bus time moves on with each transaction's bus time.
"""
from __future__ import annotations

import errno
import os
from typing import Any


def _nack(addr: int, why: str = "") -> OSError:
    return OSError(errno.EREMOTEIO, f"{os.strerror(errno.EREMOTEIO)} (emulated NACK at 0x{addr:02x}{why})")


class _BusClock:
    def __init__(self, mux: "TCA9548AEmulator"):
        self.mux = mux
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(0.0, float(seconds))


class TCA9548AEmulator:
    """smbus2's ``SMBus`` API on an emulated bus: the mux plus what sits behind its channels."""

    def __init__(self, address: int = 0x70):
        self.address = address
        self.control = 0  # power-on: every channel disconnected
        self.channels: dict[int, Any] = {}
        self.clock = _BusClock(self)
        self.selects = 0

    def attach(self, channel: int, device: Any) -> None:
        """Put a downstream emulated bus (e.g. an MMA8451Emulator) behind ``channel``."""
        self.channels[channel] = device
        self.clock.t = max(self.clock.t, device.board.clock.now())

    def _route(self, addr: int) -> Any:
        hits = [d for ch, d in self.channels.items() if self.control >> ch & 1 and d._device(addr) is not None]
        if not hits:
            raise _nack(addr)
        if len(hits) > 1:
            raise _nack(addr, ": two enabled channels answer this address")
        dev = hits[0]
        lag = self.clock.t - dev.board.clock.now()
        if lag > 0:
            dev._advance(lag)  # the chip sampled while the bus talked to others
        return dev

    def _on(self, addr: int, name: str, *args):
        dev = self._route(addr)
        try:
            return getattr(dev, name)(addr, *args)
        finally:
            self.clock.t = max(self.clock.t, dev.board.clock.now())

    # --- smbus2.SMBus API subset ---------------------------------------------------------
    def open(self, bus=None) -> None:
        pass

    def close(self) -> None:
        pass

    def write_byte(self, i2c_addr: int, value: int, force=None) -> None:
        if i2c_addr != self.address:
            raise _nack(i2c_addr)
        self.control = value & 0xFF
        self.selects += 1

    def read_byte(self, i2c_addr: int, force=None) -> int:
        if i2c_addr != self.address:
            raise _nack(i2c_addr)
        return self.control

    def read_byte_data(self, i2c_addr: int, register: int, force=None) -> int:
        return self._on(i2c_addr, "read_byte_data", register)

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force=None) -> None:
        self._on(i2c_addr, "write_byte_data", register, value)

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force=None) -> list[int]:
        return self._on(i2c_addr, "read_i2c_block_data", register, length)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data, force=None) -> None:
        self._on(i2c_addr, "write_i2c_block_data", register, data)

    def i2c_rdwr(self, *msgs) -> None:
        addrs = {m.addr for m in msgs}
        if len(addrs) != 1:
            raise _nack(min(addrs), ": one target per combined transaction here")
        addr = addrs.pop()
        dev = self._route(addr)
        try:
            dev.i2c_rdwr(*msgs)
        finally:
            self.clock.t = max(self.clock.t, dev.board.clock.now())


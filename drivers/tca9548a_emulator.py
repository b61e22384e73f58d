"""Register-level TCA9548A emulator on an emulated smbus2 bus, with emulated boards behind its channels.

The mux at 0x70-0x77 takes SMBus send/receive byte (``write_byte``/``read_byte``) to its
control register; every other transaction goes to the devices of the channels whose bit
is set: a channel's device is a downstream emulated bus (an MMA8451Emulator with its
board's EEPROM).  No device at the address on any enabled channel NACKs; two enabled
channels both answering the address is a bus conflict and NACKs too (a real bus would
garble the data).

Time: each board keeps its own virtual clock (its emulator's), advanced by its own
driver's waits and by the bus time of its own transactions; the host serialises
transactions on the bus (MuxBus.lock), so boards are read in turn, transaction by
transaction, within each sample period.  Contention is not modelled in virtual time: at
400 kHz one 100 Hz MMA8451 sample (STATUS poll + 6-byte burst + channel select) takes
about 0.4 ms of the 10 ms period, so eight boards use about a third of the bus.
"""
from __future__ import annotations

import errno
import os
from collections.abc import Sequence
from typing import Any


def _nack(addr: int, why: str = "") -> OSError:
    return OSError(errno.EREMOTEIO, f"{os.strerror(errno.EREMOTEIO)} (emulated NACK at 0x{addr:02x}{why})")


class TCA9548AEmulator:
    """smbus2's ``SMBus`` API on an emulated bus: the mux plus what sits behind its channels."""

    def __init__(self, address: int = 0x70) -> None:
        self.address = address
        self.control = 0  # power-on: every channel disconnected
        self.channels: dict[int, Any] = {}
        self.selects = 0
        self.resets = 0
        self._reset_after: dict[int, int] = {}  # channel -> transactions to its device before a reset

    def attach(self, channel: int, device: Any) -> None:
        """Put a downstream emulated bus (e.g. an MMA8451Emulator) behind ``channel``."""
        self.channels[channel] = device

    def reset(self, after_transactions: int | None = None, channel: int | None = None) -> None:
        """Reset the mux (data sheet: the RESET pin, or power-on: no channel selected), now or after
        ``after_transactions`` more transactions to the device behind ``channel``."""
        if after_transactions is None:
            self.control = 0
            self.resets += 1
        elif channel is not None:
            self._reset_after[channel] = int(after_transactions)

    def _route(self, addr: int) -> Any:
        hits = [d for ch, d in self.channels.items() if self.control >> ch & 1 and d._device(addr) is not None]
        if not hits:
            raise _nack(addr)
        if len(hits) > 1:
            raise _nack(addr, ": two enabled channels answer this address")
        return hits[0]

    def _on(self, addr: int, name: str, *args: Any) -> Any:
        dev = self._route(addr)
        self._count(dev)
        return getattr(dev, name)(addr, *args)

    def _count(self, dev: Any) -> None:
        """A transaction to dev went through: a reset scheduled after it happens now (the next one NACKs)."""
        for ch, left in list(self._reset_after.items()):
            if self.channels.get(ch) is dev:
                if left <= 1:
                    del self._reset_after[ch]
                    self.reset()
                else:
                    self._reset_after[ch] = left - 1

    # --- smbus2.SMBus API subset ---------------------------------------------------------
    def open(self, bus: int | str | None = None) -> None:
        pass

    def close(self) -> None:
        pass

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        if i2c_addr != self.address:
            raise _nack(i2c_addr)  # no device modelled here takes a bare byte write
        self.control = value & 0xFF
        self.selects += 1

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        if i2c_addr != self.address:  # passed through to the enabled channels, as the part does
            return int(self._on(i2c_addr, "read_byte"))
        return self.control

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._on(i2c_addr, "read_byte_data", register)

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._on(i2c_addr, "write_byte_data", register, value)

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force: bool | None = None) -> list[int]:
        return self._on(i2c_addr, "read_i2c_block_data", register, length)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int],
                             force: bool | None = None) -> None:
        self._on(i2c_addr, "write_i2c_block_data", register, data)

    def i2c_rdwr(self, *msgs: Any) -> None:
        addrs = {m.addr for m in msgs}
        if len(addrs) != 1:
            raise _nack(min(addrs), ": one target per combined transaction here")
        dev = self._route(addrs.pop())
        self._count(dev)
        dev.i2c_rdwr(*msgs)


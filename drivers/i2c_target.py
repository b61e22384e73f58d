"""One I2C address on an SMBus-like object (smbus2's ``SMBus``, a mux channel, an emulator) with
bounded retries and errors that name bus, address and register; and a 24Cxx EEPROM on it as the
board's NVM.  Used by drivers/mma8451.py."""
from __future__ import annotations

import errno
import logging
import os
from collections.abc import Callable
from typing import Any, TypeVar

from smbus2 import i2c_msg

from ..errors import AccelcalError, DeviceError, NVMError
from .base import NVM, Clock

log = logging.getLogger("accelcal_station.drivers.mma8451")  # the driver's logger, as before the split
T = TypeVar("T")


def _os_reason(e: OSError) -> str:
    text = f"[Errno {e.errno}] {e.strerror or os.strerror(e.errno or 0)}" if e.errno else str(e)
    if e.errno == errno.EBUSY:
        text += " (a kernel driver owns this address; unbind it, e.g. the mma8452 module)"
    elif e.errno == errno.ENOTTY:
        text += " (not an I2C adapter)"
    elif e.errno in (errno.EREMOTEIO, errno.ENXIO):
        text += " (no ACK: nothing answers at this address, or it stopped answering: a loose contact, no power)"
    elif e.errno in (errno.ETIMEDOUT, errno.EAGAIN):
        text += (" (the bus timed out: SDA or SCL held low; a chip left mid-byte by a reset holds SDA until "
                 "clocked free: Linux recovers the bus only where the adapter driver supports bus recovery, "
                 "otherwise power-cycle the board)")
    return text


class I2CTarget:
    """One address on an SMBus-like object: bounded retries, errors naming bus, address, register."""

    def __init__(self, smbus: Any, bus_label: str, address: int, clock: Clock, retries: int = 3,
                 retry_delay_s: float = 0.001, register_names: dict[int, str] | None = None) -> None:
        self.smbus, self.bus_label, self.address = smbus, bus_label, address
        self.register_names = register_names or {}  # for the error lines: the chip's names of its registers
        self.clock, self.retries, self.retry_delay_s = clock, retries, retry_delay_s

    def where(self, register: int | None = None, what: str | None = None) -> str:
        w = f"i2c bus {self.bus_label} address 0x{self.address:02x}"
        if register is not None:
            w += f" register 0x{register:02X} ({self.register_names.get(register, 'reg')})"
        return w + (f" {what}" if what else "")

    def call(self, op: str, register: int | None, fn: Callable[..., T], *args: Any,
             error: type[AccelcalError] = DeviceError, what: str | None = None, hint: str = "") -> T:
        """``fn(*args)``; an OSError (NACK, bus fault) is retried ``retries`` times, then ``error``."""
        for attempt in range(self.retries + 1):
            try:
                return fn(*args)
            except OSError as e:
                last = e
                log.info("%s %s: %s (try %d)", op, self.where(register), _os_reason(e), attempt + 1)
                if attempt < self.retries:
                    self.clock.sleep(self.retry_delay_s)
        raise error(f"{op} {self.where(register, what)} failed after {self.retries + 1} attempts: "
                    f"{_os_reason(last)}{hint}")

    def read_byte(self, register: int, **kw: Any) -> int:
        return self.call("read", register, self.smbus.read_byte_data, self.address, register, **kw)

    def write_byte(self, register: int, value: int, **kw: Any) -> None:
        self.call("write", register, self.smbus.write_byte_data, self.address, register, value & 0xFF, **kw)

    def read_block(self, register: int, length: int, **kw: Any) -> list[int]:
        return self.call("read", register, self.smbus.read_i2c_block_data, self.address, register, length,
                         **kw)


class I2CEeprom(NVM):
    """24Cxx EEPROM with 2-byte word addresses (24C32 and up), through smbus2 ``i2c_rdwr``.

    Writes are split at page boundaries (a page write wraps inside its page otherwise) and each
    waits out the write cycle by ACK polling: the part NACKs its address until tWR is over.
    """

    READ_CHUNK = 256  # well under the kernel's 8192-byte i2c_msg limit

    def __init__(self, target: I2CTarget, size: int = 4096, page_size: int = 32,
                 write_cycle_s: float = 0.005) -> None:
        self.t, self.size, self.page_size, self.write_cycle_s = target, int(size), int(page_size), write_cycle_s

    def _msgs(self, *msgs: Any) -> None:
        self.t.smbus.i2c_rdwr(*msgs)

    def _where(self, addr: int, n: int) -> str:
        return f"EEPROM bytes {addr}..{addr + n - 1}"

    def read(self, addr: int, n: int) -> bytes:
        self._check_range(addr, n)
        out = bytearray()
        for a in range(addr, addr + n, self.READ_CHUNK):
            m = min(self.READ_CHUNK, addr + n - a)
            rd = i2c_msg.read(self.t.address, m)
            self.t.call("read", None, self._msgs, i2c_msg.write(self.t.address, [a >> 8, a & 0xFF]), rd,
                        error=NVMError, what=self._where(a, m))
            out += bytes(rd)
        return bytes(out)

    def write(self, addr: int, data: bytes) -> None:
        for a, chunk in self.page_chunks(addr, data):
            msg = i2c_msg.write(self.t.address, [a >> 8, a & 0xFF, *chunk])
            self.t.call("page write", None, self._msgs, msg, error=NVMError, what=self._where(a, len(chunk)))
            self._ready()

    def _ready(self) -> None:
        """ACK polling: address the part (setting its pointer, writing nothing) until it answers."""
        deadline = self.t.clock.now() + 4 * self.write_cycle_s
        while True:
            try:
                self._msgs(i2c_msg.write(self.t.address, [0, 0]))
                return
            except OSError as e:
                if self.t.clock.now() > deadline:
                    raise NVMError(f"EEPROM at {self.t.where()} did not answer within "
                                   f"{4 * self.write_cycle_s * 1e3:g} ms: {_os_reason(e)}") from None
                self.t.clock.sleep(self.write_cycle_s / 10)

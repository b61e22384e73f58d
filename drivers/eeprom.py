"""A 24Cxx I2C EEPROM (default 24C32: 4096 bytes, 32-byte pages, 5 ms write cycle).

Two faces on one byte array:

* :class:`NVM` (``read``/``write``): what a driver offers the calibration writer;
  ``write`` splits at page boundaries and waits out each write cycle.
* I2C transactions (``i2c_write``/``i2c_read``) for a register-level bus emulator:
  a write is a 2-byte big-endian word address then data; data past the end of the
  page rolls over to the start of the *same* page, and only the last ``page_size``
  bytes sent are kept (as real 24Cxx do).  A write with no data only sets the
  address pointer (the first half of a random read).  Reads are sequential from
  the pointer and roll over at the end of memory.  While a write cycle is in
  progress the chip NACKs everything: ``OSError(121, ...)`` (EREMOTEIO), which is
  what smbus2 raises for a NACK on Linux.

Erased cells read 0xFF.  Time is the board's virtual clock (``now()``, ``sleep()``).

Power-loss injection: ``fail_at_write=k`` makes the k-th page write (1-based,
counted over both faces since the injection was armed) lose power during its
write cycle: only the first ``fail_bytes`` bytes of that page write reach the
cells (default: half of them), the rest keep their old contents, and
:class:`PowerLossError` (an NVMError) is raised.  The injection is one-shot:
afterwards power is back and the EEPROM works normally, so a test can
"reboot" and inspect what a real part would hold.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np

from ..errors import NVMError
from ..fileguard.regular import read_bytes
from .base import NVM, Clock


class PowerLossError(NVMError):
    """Simulated power loss during an EEPROM write cycle (the page is partly written)."""


class _WallClock:
    """Fallback clock when the EEPROM is used on its own (virtual, starts at 0)."""

    realtime = False

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(0.0, dt)


class EEPROM24(NVM):
    """Byte/page model of a 24Cxx EEPROM with write-cycle timing and power-loss injection."""

    def __init__(self, size: int = 4096, page_size: int = 32, write_cycle_s: float = 0.005,
                 clock: Clock | None = None, fail_at_write: int | None = None, fail_bytes: int | None = None,
                 image_path: str | os.PathLike[str] | None = None) -> None:
        if size <= 0 or page_size <= 0 or size % page_size:
            raise NVMError(f"EEPROM size {size} must be a positive multiple of the page size {page_size}")
        self.size = int(size)
        self.page_size = int(page_size)
        self.write_cycle_s = float(write_cycle_s)
        self.clock: Clock = clock if clock is not None else _WallClock()
        self.cells = np.full(self.size, 0xFF, dtype=np.uint8)
        self.pointer = 0  # internal address counter
        self.busy_until = -np.inf
        self.page_writes = 0  # page write cycles completed or attempted since power-on
        self.fail_at_write = fail_at_write
        self.fail_bytes = fail_bytes
        self._armed_at = 0
        # a simulated board kept between commands: the cells live in a file, loaded
        # now and saved (whole, atomically) after every page write, as a real part keeps them
        self.image_path = None if image_path is None else Path(image_path)
        if self.image_path is not None and self.image_path.exists():
            data = read_bytes(self.image_path, "an EEPROM image", self.size, "the size of this EEPROM", NVMError)
            if len(data) != self.size:
                raise NVMError(f"{self.image_path}: EEPROM image is {len(data)} bytes; this EEPROM has {self.size}")
            self.cells[:] = np.frombuffer(data, dtype=np.uint8)

    def inject_power_loss(self, at_write: int = 1, fail_bytes: int | None = None) -> None:
        """Arm a power loss on the ``at_write``-th page write from now (1 = the next one)."""
        if at_write < 1:
            raise NVMError(f"fail_at_write {at_write}; allowed: 1 or more")
        self.fail_at_write, self.fail_bytes, self._armed_at = int(at_write), fail_bytes, self.page_writes

    @property
    def busy(self) -> bool:
        return self.clock.now() < self.busy_until

    def _program(self, addr: int, data: bytes) -> None:
        """One page write cycle of ``data`` at ``addr`` (already within one page)."""
        self.page_writes += 1
        self.busy_until = self.clock.now() + self.write_cycle_s
        n = len(data)
        if self.fail_at_write is not None and self.page_writes - self._armed_at == self.fail_at_write:
            k = n // 2 if self.fail_bytes is None else max(0, min(n, int(self.fail_bytes)))
            self.cells[addr:addr + k] = np.frombuffer(bytes(data[:k]), dtype=np.uint8)
            self.fail_at_write = None
            self.busy_until = -np.inf  # power comes back with the chip idle
            self._save()
            raise PowerLossError(f"simulated power loss during EEPROM page write {self.page_writes} "
                                 f"at 0x{addr:04x}: {k} of {n} bytes written")
        self.cells[addr:addr + n] = np.frombuffer(bytes(data), dtype=np.uint8)
        self._save()

    def _save(self) -> None:
        if self.image_path is not None:
            from ..atomic import atomic_write  # a planted <image>.tmp symlink is never followed

            atomic_write(self.image_path, self.cells.tobytes())

    # -- NVM face --------------------------------------------------------------------------
    def read(self, addr: int, n: int) -> bytes:
        self._check_range(addr, n)
        self._wait()
        return self.cells[addr:addr + n].tobytes()

    def write(self, addr: int, data: bytes) -> None:
        for a, chunk in self.page_chunks(addr, data):
            self._wait()
            self._program(a, chunk)
        self._wait()

    def _wait(self) -> None:
        """Wait out a write cycle in progress (ACK polling, on the board's clock)."""
        if self.busy:
            self.clock.sleep(self.busy_until - self.clock.now())

    # -- I2C face --------------------------------------------------------------------------
    def _nack_if_busy(self) -> None:
        if self.busy:
            raise OSError(errno.EREMOTEIO, "EEPROM busy in its write cycle (NACK)")

    def i2c_write(self, data: bytes) -> None:
        """An I2C write transaction: 2-byte word address, then 0 or more data bytes."""
        self._nack_if_busy()
        data = bytes(data)
        if len(data) < 2:
            raise OSError(errno.EREMOTEIO, "EEPROM write needs a 2-byte word address (NACK)")
        addr = ((data[0] << 8) | data[1]) % self.size
        payload = data[2:]
        if not payload:
            self.pointer = addr
            return
        page = addr - addr % self.page_size
        # bytes past the page end wrap within the page; the last page_size bytes sent win
        latch = {}
        for j, b in enumerate(payload):
            latch[page + (addr - page + j) % self.page_size] = b
        offs = sorted(latch)
        lo, hi = offs[0], offs[-1]
        block = bytearray(self.cells[lo:hi + 1].tobytes())
        for a, b in latch.items():
            block[a - lo] = b
        self.pointer = page + (addr - page + len(payload)) % self.page_size
        self._program(lo, bytes(block))

    def i2c_read(self, n: int) -> bytes:
        """An I2C read transaction: ``n`` bytes from the pointer, rolling over at the end."""
        self._nack_if_busy()
        idx = (self.pointer + np.arange(int(n))) % self.size
        self.pointer = int((self.pointer + n) % self.size)
        return self.cells[idx].tobytes()

"""The MPU6050 bridge MCU's EEPROM as the board's NVM: 32-byte pages through the bridge protocol's
NVM_READ / NVM_WRITE (docs/bridge-protocol.md), every page written read back."""
from __future__ import annotations

from typing import Protocol

from ..errors import DeviceError, NVMError
from . import bridge_protocol as bp
from .base import NVM


class BridgeCommands(Protocol):
    """What the NVM needs of the bridge driver (drivers/mpu6050.py MPU6050Bridge): its port and one command."""

    port: str

    def _call(self, cmd: int, payload: bytes = b"") -> bytes: ...


class BridgeNVM(NVM):
    """The bridge MCU's EEPROM in 32-byte pages (NVM_READ / NVM_WRITE), every write read back."""

    def __init__(self, dev: BridgeCommands, size: int, page_size: int) -> None:
        self.dev, self.size, self.page_size = dev, size, page_size

    def _page(self, page: int) -> bytes:
        data = self.dev._call(bp.CMD_NVM_READ, bytes([page]))
        if len(data) != 1 + self.page_size or data[0] != page:
            raise DeviceError(f"MPU6050 bridge on {self.dev.port}: NVM_READ page {page} answered "
                              f"{len(data)} bytes for page {data[:1].hex() or '?'}")
        return data[1:]

    def read(self, addr: int, n: int) -> bytes:
        self._check_range(addr, n)
        ps = self.page_size
        out = b"".join(self._page(p) for p in range(addr // ps, (addr + n + ps - 1) // ps))
        return out[addr % ps: addr % ps + n]

    def write(self, addr: int, data: bytes) -> None:
        data = bytes(data)
        self._check_range(addr, len(data))
        ps, i = self.page_size, 0
        while i < len(data):
            page, off = divmod(addr + i, ps)
            chunk = data[i:i + ps - off]
            # NVM_WRITE takes whole pages: merge a partial one with what is there
            new = self._page(page) if len(chunk) < ps else b""
            new = new[:off] + chunk + new[off + len(chunk):] if new else chunk
            try:
                self.dev._call(bp.CMD_NVM_WRITE, bytes([page]) + new)
            except DeviceError as e:
                raise NVMError(f"NVM write of page {page} (0x{page * ps:03x}) failed: {e}") from None
            back = self._page(page)
            if back != new:
                bad = next(k for k in range(ps) if back[k] != new[k])
                raise NVMError(f"NVM page {page} read back differs at 0x{page * ps + bad:03x}: wrote "
                               f"0x{new[bad]:02x}, read 0x{back[bad]:02x} (EEPROM worn or write interrupted)")
            i += len(chunk)

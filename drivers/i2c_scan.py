"""An I2C bus scan for a first bring-up (`accelcal probe --scan`): every address that answers, the chip
at the addresses an accelerometer can have (by its WHO_AM_I), and the buses behind a TCA9548A
multiplexer channel by channel.

Presence is a one-byte read (SMBus "receive byte", as ``i2cdetect -r``: a read never changes an EEPROM
or a sensor, where a quick write could), through smbus2's ``read_byte`` on any SMBus-like object:
smbus2's ``SMBus`` on /dev/i2c-N or an emulator.  The WHO_AM_I tables are the drivers' (mma8451_registers.py,
mpu6050_registers.py).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from . import mma8451_registers, mpu6050_registers

SCAN_RANGE = range(0x08, 0x78)  # 7-bit addresses outside the reserved 0x00-0x07 and 0x78-0x7F
MUX_RANGE = range(0x70, 0x78)  # TCA9548A: A2..A0 select 0x70..0x77
EEPROM_RANGE = range(0x50, 0x58)  # 24Cxx: A2..A0 select 0x50..0x57
# the accelerometers the station drives: address -> (WHO_AM_I register, the chip it names, known relatives)
CHIP_AT: dict[int, tuple[int, int, str, dict[int, str]]] = {
    0x1C: (mma8451_registers.WHO_AM_I, mma8451_registers.CHIP_ID, "MMA8451Q", mma8451_registers.KNOWN_CHIP_IDS),
    0x1D: (mma8451_registers.WHO_AM_I, mma8451_registers.CHIP_ID, "MMA8451Q", mma8451_registers.KNOWN_CHIP_IDS),
    0x68: (mpu6050_registers.WHO_AM_I, mpu6050_registers.CHIP_ID, "MPU-6050", mpu6050_registers.KNOWN_CHIP_IDS),
    0x69: (mpu6050_registers.WHO_AM_I, mpu6050_registers.CHIP_ID, "MPU-6050", mpu6050_registers.KNOWN_CHIP_IDS),
}


@dataclass(frozen=True)
class Found:
    """One address that answered: where (``mux`` and ``channel`` when behind a multiplexer), what it is."""

    address: int
    kind: str  # "accelerometer", "eeprom", "mux", "unknown"
    chip: str | None = None  # what its WHO_AM_I names
    who_am_i: int | None = None
    mux: int | None = None
    channel: int | None = None

    def to_json(self) -> dict[str, object]:
        return {"address": f"0x{self.address:02x}", "kind": self.kind, "chip": self.chip,
                "who_am_i": None if self.who_am_i is None else f"0x{self.who_am_i:02x}",
                "mux": None if self.mux is None else f"0x{self.mux:02x}", "channel": self.channel}

    def line(self) -> str:
        where = f"0x{self.address:02x}" + ("" if self.mux is None else f" behind mux 0x{self.mux:02x} channel "
                                                                          f"{self.channel}")
        what = self.chip or self.kind
        who = "" if self.who_am_i is None else f" (WHO_AM_I 0x{self.who_am_i:02x})"
        return f"{where:32s} {what}{who}"


def answers(smbus: Any, address: int) -> bool:
    """Does anything ACK a one-byte read at ``address``?"""
    try:
        smbus.read_byte(address)
    except OSError:
        return False
    return True


def _identify(smbus: Any, address: int) -> tuple[str, str | None, int | None]:
    """(kind, chip, WHO_AM_I) of an address that answered."""
    if address in CHIP_AT:
        reg, own, name, relatives = CHIP_AT[address]
        try:
            who = int(smbus.read_byte_data(address, reg))
        except OSError:
            return "unknown", None, None
        if who == own:
            return "accelerometer", name, who
        return ("accelerometer", relatives[who], who) if who in relatives else ("unknown", None, who)
    if address in EEPROM_RANGE:
        return "eeprom", "24Cxx EEPROM", None
    return "unknown", None, None


def scan(smbus: Any, addresses: Iterable[int] = SCAN_RANGE, *, mux: int | None = None,
         channel: int | None = None, skip: frozenset[int] = frozenset()) -> list[Found]:
    """Every address of ``addresses`` that answers (``skip``: seen on the bus above a mux channel)."""
    out = []
    for a in addresses:
        if a in skip or not answers(smbus, a):
            continue
        kind, chip, who = _identify(smbus, a)
        out.append(Found(a, kind, chip, who, mux, channel))
    return out


def _select(smbus: Any, mux: int, mask: int) -> bool:
    """Write a TCA9548A's control register and read it back; False when it is no such mux."""
    try:
        smbus.write_byte(mux, mask)
        return int(smbus.read_byte(mux)) == mask
    except OSError:
        return False


def scan_with_muxes(smbus: Any) -> list[Found]:
    """The bus, then behind each TCA9548A found on it, channel by channel (the mux is left deselected)."""
    top = scan(smbus)
    out = list(top)
    seen = frozenset(f.address for f in top)
    for f in top:
        if f.address not in MUX_RANGE or f.kind != "unknown" or not _select(smbus, f.address, 0):
            continue
        out[out.index(f)] = Found(f.address, "mux", "TCA9548A", None)
        for ch in range(8):
            if _select(smbus, f.address, 1 << ch):
                out += scan(smbus, mux=f.address, channel=ch, skip=seen)
        _select(smbus, f.address, 0)
    return out

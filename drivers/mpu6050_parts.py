"""MPU-6050 compatibles and clones by WHO_AM_I (register 0x75), named honestly (issue 49).

Most MPU-6050 breakout modules on the market (GY-521 and the like) carry clones or relabelled parts:
WHO_AM_I 0x98, 0x70 or 0x72 are reported by such modules.  A WHO_AM_I names the die a part claims to
be, not who made it: 0x98 is the ICM-20689's value, but on an MPU-6050 module it is almost always a
clone, so it is not called an ICM-20689 here.  The station accepts a part other than the MPU-6050 only
when the config lists its WHO_AM_I (``device.accept_who_am_i``); the accelerometer registers these parts
answer at are the MPU-6050's (0x3B..0x40, AFS_SEL, DLPF_CFG), but their self-test response is not the
MPU-6050 product specification's (6.1), so their self-test is skipped and the run says so.
"""
from __future__ import annotations

from dataclasses import dataclass

from .mpu6050_registers import CHIP_ID, KNOWN_CHIP_IDS


@dataclass(frozen=True)
class Part:
    """What a WHO_AM_I value says about the part behind it."""

    who_am_i: int
    name: str  # how the station names it
    note: str  # what is known about it
    genuine: bool  # the MPU-6050 itself (its self-test limits apply)


PARTS: dict[int, Part] = {p.who_am_i: p for p in (
    Part(CHIP_ID, "MPU-6050", "InvenSense MPU-6050 (MPU-6000 answers the same)", True),
    Part(0x98, "MPU-6050 compatible (WHO_AM_I 0x98)", "reports the ICM-20689's value; on MPU-6050 modules a "
         "clone or relabelled part", False),
    Part(0x70, "MPU-6050 compatible (WHO_AM_I 0x70)", "reports the MPU-6500's value; an MPU-6500 or a clone "
         "of one", False),
    Part(0x72, "MPU-6050 compatible (WHO_AM_I 0x72)", "a value no InvenSense data sheet lists; reported by "
         "clone parts on MPU-6050 modules", False),
    Part(0x71, "MPU-9250 (WHO_AM_I 0x71)", "an MPU-9250 (accelerometer registers as the MPU-6500's) or a clone",
         False),
    Part(0x73, "MPU-9255 (WHO_AM_I 0x73)", "an MPU-9255 or a clone", False),
)}


def part_of(who_am_i: int) -> Part | None:
    """The known part for a WHO_AM_I value, or None."""
    return PARTS.get(who_am_i)


def refusal(who_am_i: int, where: str) -> str:
    """The one line for a part the config did not accept: what it is and the line that accepts it."""
    p = part_of(who_am_i)
    what = f"{p.name}: {p.note}" if p is not None else KNOWN_CHIP_IDS.get(who_am_i, "an unknown part")
    how = (f"; to calibrate it as an MPU-6050 compatible (its self-test is skipped), set device.accept_who_am_i: "
           f"[0x{who_am_i:02x}]") if p is not None and not p.genuine else ""
    return (f"wrong chip behind the bridge on {where}: WHO_AM_I (0x75) reads 0x{who_am_i:02x} ({what}); "
            f"expected 0x{CHIP_ID:02x} (MPU-6050){how}")

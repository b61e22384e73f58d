"""The MMA8451Q's register map and data-sheet figures (data sheet Rev. 10.3, 02/2017, section 6), and the
codecs between its registers and numbers: burst counts, offset-trim LSBs, the data-rate code.

Shared by the driver (mma8451.py), its settings (mma8451_settings.py), its register-level emulator and
the bus scan; imports nothing of theirs.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError

# --- register map (data sheet table 11) -------------------------------------------------
STATUS = 0x00
OUT_X_MSB = 0x01
WHO_AM_I = 0x0D
XYZ_DATA_CFG = 0x0E
CTRL_REG1 = 0x2A
CTRL_REG2 = 0x2B
OFF_X, OFF_Y, OFF_Z = 0x2F, 0x30, 0x31

REGISTER_NAMES = {
    0x00: "STATUS", 0x01: "OUT_X_MSB", 0x02: "OUT_X_LSB", 0x03: "OUT_Y_MSB", 0x04: "OUT_Y_LSB",
    0x05: "OUT_Z_MSB", 0x06: "OUT_Z_LSB", 0x09: "F_SETUP", 0x0B: "SYSMOD", 0x0C: "INT_SOURCE",
    0x0D: "WHO_AM_I", 0x0E: "XYZ_DATA_CFG", 0x0F: "HP_FILTER_CUTOFF", 0x2A: "CTRL_REG1",
    0x2B: "CTRL_REG2", 0x2C: "CTRL_REG3", 0x2D: "CTRL_REG4", 0x2E: "CTRL_REG5",
    0x2F: "OFF_X", 0x30: "OFF_Y", 0x31: "OFF_Z",
}

CHIP_ID = 0x1A
# WHO_AM_I of the MMA8451's register-compatible relatives (Linux drivers/iio/accel/mma8452.c),
# so a wrong part on the jig is refused by name
KNOWN_CHIP_IDS = {0x2A: "MMA8452Q", 0x3A: "MMA8453Q", 0x4A: "MMA8652FC", 0x5A: "MMA8653FC",
                  0x6A: "FXLS8471Q"}
ADDRESSES = (0x1C, 0x1D)  # SA0 pin low / high

STATUS_ZYXDR = 0x08  # new X, Y, Z data ready
STATUS_ZYXOW = 0x80  # new data overwrote unread data
CTRL1_ACTIVE = 0x01
CTRL1_F_READ = 0x02  # 8-bit fast read: must stay clear for 14-bit bursts
CTRL1_DR_SHIFT, CTRL1_DR_MASK = 3, 0x38
CTRL2_ST = 0x80  # self-test enable (data sheet 6.8, CTRL_REG2 bit 7; STANDBY to change)
CTRL2_RST = 0x40
CTRL2_MODS_MASK = 0x03
FS_MASK = 0x03

ODR_HZ = (800.0, 400.0, 200.0, 100.0, 50.0, 12.5, 6.25, 1.5625)  # index = CTRL_REG1 DR bits
FS_BITS = {2: 0, 4: 1, 8: 2}  # XYZ_DATA_CFG FS1:FS0
COUNTS_PER_G = {2: 4096, 4: 2048, 8: 1024}  # 14-bit sensitivity, data sheet table 2
MODS = {"normal": 0, "low_noise_low_power": 1, "high_resolution": 2, "low_power": 3}
# Self-test (data sheet Rev. 10.3, Table 4): typical output change at +-4 g, 14-bit: X +181, Y +255,
# Z +1680 LSB (2048 LSB per g).  NXP's screen for it: at least 50 LSB on every axis, at most 1000 on X
# and Y, 6000 on Z, all positive (NXP community answer on the MMA8451Q self-test, see docs/self-test.md).
SELF_TEST_LOW_G = np.array([50.0, 50.0, 50.0]) / 2048.0
SELF_TEST_HIGH_G = np.array([1000.0, 1000.0, 6000.0]) / 2048.0
# The self-test runs at +-8 g whatever the run's range: the screen's z limit (6000 LSB at 4 g = 2.93 g)
# plus up to 1 g of gravity must be on scale to be seen, and at +-2 g NXP's measured ~1 g z response
# already sits at the rail (a 3.5 g response would read as a passing one); the run's range is restored
# and read back afterwards.
SELF_TEST_RANGE_G = 8
SELF_TEST_SOURCE = "MMA8451Q data sheet Rev. 10.3 Table 4 (typical +181/+255/+1680 LSB at 4 g); NXP screen 50..1000 " \
                   "(x, y), 50..6000 (z) LSB at 4 g"
# OFF_X/Y/Z: signed 8-bit, "2 mg/LSB" in the data sheet; the LSB is exactly 1/512 g, i.e. 8/4/2
# counts at 2/4/8 g (NXP AN4069 offset = -out_14bit/8 at 2 g; NXP's 8 g bare-metal example
# uses /2), independent of the range
OFF_LSB_G = 1.0 / 512.0
RESET_POLLS = 20  # CTRL_REG2 reads while the chip reboots (boot takes about 0.5 ms)

def decode_counts(raw: bytes | bytearray) -> np.ndarray:
    """Bursts of OUT_X_MSB..OUT_Z_LSB -> counts (n, 3) int64: 14-bit left-justified two's complement."""
    return (np.frombuffer(bytes(raw), dtype=">i2").astype(np.int64) >> 2).reshape(-1, 3)


def off_lsb_to_counts(lsb: ArrayLike, range_g: int) -> np.ndarray:
    """Offset-trim LSBs -> 14-bit counts at ``range_g`` (1 LSB = 1/512 g)."""
    return np.asarray(lsb, dtype=np.int64) * (COUNTS_PER_G[range_g] // 512)


def odr_index(odr_hz: float, path: str = "odr_hz") -> int:
    """CTRL_REG1 DR code of a data rate; 1.56 is accepted for 1.5625 Hz."""
    if isinstance(odr_hz, (int, float)) and not isinstance(odr_hz, bool):
        for i, f in enumerate(ODR_HZ):
            if abs(float(odr_hz) - f) <= 0.01 * f:
                return i
        raise ConfigError(f"{path}: {odr_hz:g} Hz; allowed: {', '.join(f'{f:g}' for f in ODR_HZ)}")
    raise ConfigError(f"{path}: {odr_hz!r} Hz; allowed: {', '.join(f'{f:g}' for f in ODR_HZ)}")

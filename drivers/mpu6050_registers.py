"""MPU-6050 registers and the pure functions on them (RM-MPU-6000A-00 rev 4.2; product
specification rev 3.4), and the bridge link's capacity: what drivers/mpu6050.py and the emulators
share without either importing the other's logic."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError
from . import bridge_protocol as bp

WHO_AM_I = 0x75
CHIP_ID = 0x68
KNOWN_CHIP_IDS = {0x70: "MPU-6500", 0x71: "MPU-9250", 0x73: "MPU-9255", 0x7C: "MPU-6555", 0x19: "MPU-6886",
                  0x12: "ICM-20602", 0x98: "ICM-20689", 0x00: "nothing (I2C read failed)",
                  0xFF: "nothing (bus idle high)"}
XA_OFFS_H = 0x06
SELF_TEST_X = 0x0D  # SELF_TEST_X, _Y, _Z, _A (register map 4.1)
SELF_TEST_TOLERANCE = 0.14  # product specification rev 3.4, 6.1: change from factory trim within +-14 %
SELF_TEST_SOURCE = ("MPU-6050 product specification rev 3.4, 6.1 (change from factory trim -14 % to +14 %); "
                    "register map rev 4.2, 4.1 (FT = 4096 * 0.34 * (0.92 / 0.34)^((A_TEST - 1) / 30) LSB at 8 g)")
SMPLRT_DIV = 0x19
CONFIG = 0x1A
ACCEL_CONFIG = 0x1C
ACCEL_XOUT_H = 0x3B
TEMP_OUT_H = 0x41
PWR_MGMT_1 = 0x6B
PWR_SLEEP = 0x40
PWR_CLKSEL_PLL_X = 0x01
AFS_SEL = {2: 0, 4: 1, 8: 2, 16: 3}
COUNTS_PER_G = {2: 16384, 4: 8192, 8: 4096, 16: 2048}
DLPF_BANDWIDTH_HZ = (260, 184, 94, 44, 21, 10, 5)  # accelerometer, per DLPF_CFG 0..6
ACCEL_RATE_HZ = 1000.0
OFFSET_LSB_PER_G = 2048.0
MAX_RESETS = 2

def temperature_from_raw(raw: ArrayLike) -> np.ndarray | float:
    """TEMP_OUT to C (register map 4.18: raw / 340 + 36.53)."""
    return np.asarray(raw, dtype=float) / 340.0 + 36.53


def rate_base_hz(dlpf: int) -> float:
    """Gyro output rate that SMPLRT_DIV divides: 8 kHz with the DLPF off (DLPF_CFG 0), else 1 kHz."""
    return 8000.0 if dlpf == 0 else 1000.0


def smplrt_div_for(odr_hz: float, dlpf: int, path: str = "odr_hz") -> int:
    """SMPLRT_DIV giving ``odr_hz``: 1000 / (1 + k) Hz, the rates the accelerometer really produces."""
    ok = isinstance(odr_hz, (int, float)) and not isinstance(odr_hz, bool) and 0 < odr_hz <= ACCEL_RATE_HZ
    div = rate_base_hz(dlpf) / odr_hz - 1.0 if ok else -1.0
    if not ok or abs(div - round(div)) > 1e-6 * (div + 1) or not 0 <= round(div) <= 255 \
            or abs(ACCEL_RATE_HZ / odr_hz - round(ACCEL_RATE_HZ / odr_hz)) > 1e-6 * ACCEL_RATE_HZ / odr_hz:
        lo = rate_base_hz(dlpf) / 256.0
        raise ConfigError(f"{path}: {odr_hz!r} Hz; allowed: 1000 / (1 + k) Hz down to {lo:g} Hz with dlpf {dlpf} "
                          "(e.g. 1000, 500, 200, 100, 50)")
    return int(round(div))


def factory_trim_counts(regs: bytes) -> np.ndarray:
    """The accelerometer's factory self-test trim FT per axis, LSB at +-8 g, from SELF_TEST_X/Y/Z/A
    (register map rev 4.2, 4.1): A_TEST = bits 7:5 of SELF_TEST_X/Y/Z (high three) and two bits of
    SELF_TEST_A (5:4 x, 3:2 y, 1:0 z); FT = 4096 * 0.34 * (0.92 / 0.34)^((A_TEST - 1) / 30), 0 when
    A_TEST is 0."""
    code = np.array([((regs[i] >> 5) & 7) << 2 | ((regs[3] >> (4 - 2 * i)) & 3) for i in range(3)], dtype=float)
    return np.where(code > 0, 4096.0 * 0.34 * (0.92 / 0.34) ** ((code - 1.0) / 30.0), 0.0)


def link_frames_per_s(baud: int) -> float:
    """SAMPLE frames per second the bridge's UART carries: 10 bit times a byte (8N1), one frame is
    SYNC(2) + header(8) + index(4) + data(8) + CRC(2) = 24 bytes (docs/bridge-protocol.md)."""
    return baud / 10.0 / (2 + bp.HEADER_LEN + 4 + bp.SAMPLE_BYTES + 2)


def link_max_rate_hz(baud: int, dlpf: int = 3) -> float:
    """The highest chip rate (1000 / (1 + k) Hz) whose every sample the link can carry."""
    k = int(np.ceil(ACCEL_RATE_HZ / link_frames_per_s(baud) - 1.0 - 1e-9))
    return ACCEL_RATE_HZ / (1 + max(k, 0))


def check_link_rate(odr_hz: float, baud: int, path: str = "odr_hz") -> None:
    """Refuse, before streaming, a sample rate the serial link cannot carry (the bridge would drop
    samples: gaps in the index); the firmware's 1 kHz ceiling is smplrt_div_for's."""
    if baud <= 0:
        return  # no link to measure: pyserial refuses such a baud rate when the port opens
    cap = link_frames_per_s(baud)
    if odr_hz > cap:
        raise ConfigError(f"{path}: {odr_hz:g} Hz; the bridge link at {baud} baud carries at most {cap:.0f} "
                          f"sample frames/s (24 bytes each, 10 bits a byte); allowed: at most "
                          f"{link_max_rate_hz(baud):g} Hz (1000 / (1 + k))")

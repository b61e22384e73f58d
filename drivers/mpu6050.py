"""MPU6050 behind a serial bridge MCU (docs/bridge-protocol.md), through pyserial.

The bridge (firmware/mpu6050_bridge) owns the chip on I2C; this driver speaks to it
through :class:`bridge_link.BridgeLink` (framing, retries, MCU clock) and knows the chip's
registers (RM-MPU-6000A-00 rev 4.2):

- WHO_AM_I (0x75) reads 0x68; PWR_MGMT_1 (0x6B) wakes it (SLEEP bit 6 clear, clock PLL X gyro);
- ACCEL_CONFIG (0x1C) AFS_SEL bits 4:3: 2/4/8/16 g = 16384/8192/4096/2048 counts per g;
- CONFIG (0x1A) DLPF_CFG bits 2:0; SMPLRT_DIV (0x19): rate = gyro rate / (1 + div), gyro
  rate 8 kHz with DLPF_CFG 0, else 1 kHz; the accelerometer itself is sampled at 1 kHz;
- ACCEL_XOUT_H (0x3B): big-endian int16 x, y, z, then TEMP_OUT: T = raw / 340 + 36.53 C;
- XA/YA/ZA_OFFS (0x06-0x0B): big-endian int16 trim in the +-16 g format (2048 LSB per g);
  bit 0 of each is reserved and kept on write (InvenSense offset-register app note).

Link behaviour (:mod:`bridge_link`): garbage and CRC failures are skipped (resync); a
gap in the bridge's sequence numbers counts lost frames, and lost SAMPLE frames are the
capture's ``dropped``; a command unanswered within ``timeout_s``, or NAKed for an I2C or
NVM fault, is resent up to ``retries`` times; a BOOT frame (the bridge reset) makes the
driver wake and reconfigure the chip and resume, at most ``MAX_RESETS`` times per operation.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ConfigError, DeviceError
from ..jsontypes import JsonObject
from . import bridge_protocol as bp
from .base import NVM, Capture, Driver, Identity
from .bridge_link import BridgeLink, BridgeRefused, BridgeReset, LinkStats
from .bridge_nvm import BridgeNVM
from .bridge_stream import Received, stream_once
from .mpu6050_parts import part_of, refusal
from .mpu6050_registers import (  # noqa: F401  (re-exported: the driver's public names)
    ACCEL_CONFIG,
    ACCEL_RATE_HZ,
    ACCEL_XOUT_H,
    AFS_SEL,
    CHIP_ID,
    CONFIG,
    COUNTS_PER_G,
    DLPF_BANDWIDTH_HZ,
    KNOWN_CHIP_IDS,
    MAX_RESETS,
    OFFSET_LSB_PER_G,
    PWR_CLKSEL_PLL_X,
    PWR_MGMT_1,
    PWR_SLEEP,
    SELF_TEST_SOURCE,
    SELF_TEST_TOLERANCE,
    SELF_TEST_X,
    SMPLRT_DIV,
    TEMP_OUT_H,
    WHO_AM_I,
    XA_OFFS_H,
    check_link_rate,
    factory_trim_counts,
    link_frames_per_s,
    link_max_rate_hz,
    rate_base_hz,
    smplrt_div_for,
    temperature_from_raw,
)
from .self_test import SelfTestResult, judge_against_trim

T = TypeVar("T")


@dataclass
class BridgeIdentity:
    protocol: int
    firmware: str
    i2c_address: int
    who_am_i: int
    nvm_size: int
    nvm_page_size: int
    serial: str


class MPU6050Bridge(Driver):
    """MPU6050 through the serial bridge.  ``port``: /dev/ttyUSB0, /dev/ttyACM0, a pty, COM3."""

    name = "mpu6050"

    def __init__(self, port: str, baud: int = bp.DEFAULT_BAUD, range_g: int = 2, odr_hz: float = 100.0,
                 dlpf: int = 3, timeout_s: float = 0.5, retries: int = 3, boot_wait_s: float = 2.0,
                 accept_who_am_i: tuple[int, ...] = ()) -> None:
        if range_g not in COUNTS_PER_G:
            raise ConfigError(f"range_g: {range_g!r}; allowed: 2, 4, 8, 16")
        if dlpf not in range(len(DLPF_BANDWIDTH_HZ)):
            raise ConfigError(f"dlpf: {dlpf!r}; allowed: 0..6 (DLPF_CFG)")
        smplrt_div_for(odr_hz, dlpf)
        check_link_rate(odr_hz, int(baud))
        self.port = port
        self.boot_wait_s = float(boot_wait_s)
        self.link = BridgeLink(port, int(baud), float(timeout_s), int(retries))
        self._want = (int(range_g), float(odr_hz), int(dlpf))
        self._range_g, self._odr_hz, self._dlpf, self._div = 2, ACCEL_RATE_HZ, 0, 0  # power-on
        self.accept_who_am_i = tuple(int(v) for v in accept_who_am_i)  # compatibles the config accepts
        self.part = "MPU-6050"
        self._offsets_set: np.ndarray | None = None
        self._bridge: BridgeIdentity | None = None
        self._nvm: BridgeNVM | None = None
        self._stream_temp_c: float | None = None

    # --- lifecycle ------------------------------------------------------------------------
    def open(self) -> None:
        if self.link.is_open:
            return
        try:
            self.link.open()  # inside: a port that fails to open is closed again
            self._bridge = self._hello()
            who = self._read(WHO_AM_I, 1)[0]
            if who != CHIP_ID and who not in self.accept_who_am_i:
                raise DeviceError(refusal(who, self.port))
            self._accept_part(who)
            self._nvm = BridgeNVM(self, self._bridge.nvm_size, self._bridge.nvm_page_size)
            self._with_recovery(self._init_chip)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self.link.close()

    def _accept_part(self, who: int) -> None:
        """A compatible the config accepts (drivers/mpu6050_parts.py): its self-test is not the MPU-6050's."""
        part = part_of(who)
        self.part = part.name if part is not None else f"part with WHO_AM_I 0x{who:02x}"
        genuine = part is not None and part.genuine
        self.self_test_skipped = None if genuine else (
            f"self-test skipped: the {self.part} is accepted by device.accept_who_am_i, and its self-test "
            "response is not the MPU-6050's (product specification 6.1)")

    def _hello(self) -> BridgeIdentity:
        """IDENTIFY until answered; an Arduino reboots when the port opens (DTR), so allow boot_wait_s."""
        deadline = time.monotonic() + self.boot_wait_s
        while True:
            try:
                d = self.link.command(bp.CMD_IDENTIFY)
                break
            except BridgeReset as e:
                if time.monotonic() >= deadline:
                    raise DeviceError(f"{e} again and again while opening; check its power supply") from None
            except BridgeRefused:
                raise
            except DeviceError:
                if time.monotonic() >= deadline:
                    raise
        if len(d) != bp.IDENTIFY_DATA.size:
            raise DeviceError(f"MPU6050 bridge on {self.port}: IDENTIFY answered {len(d)} bytes, expected "
                              f"{bp.IDENTIFY_DATA.size}; flash firmware/mpu6050_bridge")
        proto, major, minor, addr, who, size, page, serial_no = bp.IDENTIFY_DATA.unpack(d)
        if proto != bp.PROTOCOL_VERSION:
            raise DeviceError(f"MPU6050 bridge on {self.port} speaks protocol {proto}, this host "
                              f"{bp.PROTOCOL_VERSION}; flash firmware/mpu6050_bridge from this release")
        return BridgeIdentity(proto, f"{major}.{minor}", addr, who, size, page,
                              serial_no.rstrip(b"\0 ").decode("ascii", "replace"))

    def _init_chip(self) -> None:
        """Wake (PWR_MGMT_1: SLEEP off, PLL clock), then range, DLPF, rate, and any offsets set earlier."""
        self._write(PWR_MGMT_1, bytes([PWR_CLKSEL_PLL_X]))
        self._configure(*self._want)
        if self._offsets_set is not None:
            self._write_offsets(self._offsets_set)

    def _with_recovery(self, op: Callable[[], T]) -> T:
        """Run op; if the bridge resets meanwhile, re-initialise the chip and run op again."""
        for _ in range(MAX_RESETS + 1):
            try:
                return op()
            except BridgeReset as e:
                last = e
                self.link.stats.resets += 1
                try:
                    self._init_chip()
                except BridgeReset as e2:
                    last = e2
                    self.link.stats.resets += 1
        raise DeviceError(f"{last}; it reset {MAX_RESETS + 1} times during one operation: check its power "
                          "supply and USB cable")

    def _call(self, cmd: int, payload: bytes = b"") -> bytes:
        return self._with_recovery(lambda: self.link.command(cmd, payload))

    def reset(self) -> None:
        """RESET the bridge (the chip goes back to power-on), wait for BOOT, re-initialise."""
        self.link.command(bp.CMD_RESET)
        deadline = time.monotonic() + self.boot_wait_s + self.link.timeout_s
        while (got := self.link.next_frame(deadline)) is not None:
            if got[0].type == bp.RSP_BOOT:
                self._with_recovery(self._init_chip)
                return
        raise DeviceError(f"MPU6050 bridge on {self.port} did not come back (no BOOT) within "
                          f"{self.boot_wait_s + self.link.timeout_s:g} s of RESET")

    # --- registers ------------------------------------------------------------------------
    def _read(self, reg: int, n: int) -> bytes:
        d = self.link.command(bp.CMD_READ_REG, bytes([reg, n]))
        if len(d) != 1 + n or d[0] != reg:
            raise DeviceError(f"MPU6050 bridge on {self.port}: READ_REG 0x{reg:02x} answered {d.hex()}")
        return d[1:]

    def _write(self, reg: int, data: bytes) -> None:
        """WRITE_REG; the bridge reads the register back and the driver checks it."""
        d = self.link.command(bp.CMD_WRITE_REG, bytes([reg]) + bytes(data))
        if d[1:] != bytes(data):
            raise DeviceError(f"MPU6050 register 0x{reg:02x} via {self.port}: wrote {bytes(data).hex()}, "
                              f"read back {d[1:].hex() or 'nothing'}")

    def read_register(self, reg: int, n: int = 1) -> bytes:
        return self._with_recovery(lambda: self._read(reg, n))

    def write_register(self, reg: int, data: bytes) -> None:
        self._with_recovery(lambda: self._write(reg, data))

    def accel_offsets(self) -> np.ndarray:
        """XA/YA/ZA_OFFS as int16 (+-16 g format: 2048 LSB per g; bit 0 reserved)."""
        return np.frombuffer(self.read_register(XA_OFFS_H, 6), dtype=">i2").astype(np.int64)

    def set_accel_offsets(self, values: ArrayLike) -> None:
        """Write XA/YA/ZA_OFFS read-modify-write: bits 15:1 from ``values``, bit 0 kept as read."""
        try:
            v = np.asarray(values, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            v = np.full(1, np.nan)
        if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v != np.round(v)) \
                or np.any(v < -32768) or np.any(v > 32767):
            raise ConfigError(f"accel offsets {np.asarray(values).tolist()!r}; allowed: three whole numbers "
                              "-32768..32767 (2048 per g)")
        self._with_recovery(lambda: self._write_offsets(v.astype(np.int64)))
        self._offsets_set = v.astype(np.int64)

    def _write_offsets(self, values: np.ndarray) -> None:
        cur = np.frombuffer(self._read(XA_OFFS_H, 6), dtype=">u2").astype(np.int64)
        new = (values.astype(np.int64) & 0xFFFE) | (cur & 1)
        self._write(XA_OFFS_H, new.astype(">u2").tobytes())

    # --- configuration --------------------------------------------------------------------
    def configure(self, range_g: int | None = None, odr_hz: float | None = None, **options: Any) -> None:
        unknown = set(options) - {"dlpf"}
        if unknown:
            raise ConfigError(f"configure: unknown option {sorted(unknown)[0]!r}; allowed: dlpf")
        r = self._want[0] if range_g is None else range_g
        o = self._want[1] if odr_hz is None else odr_hz
        d = options.get("dlpf")
        d = self._want[2] if d is None else d
        if r not in COUNTS_PER_G:
            raise ConfigError(f"range_g: {r!r}; allowed: 2, 4, 8, 16")
        if d not in range(len(DLPF_BANDWIDTH_HZ)):
            raise ConfigError(f"dlpf: {d!r}; allowed: 0..6 (DLPF_CFG)")
        smplrt_div_for(o, d)
        check_link_rate(o, self.link.baud)
        self._want = (int(r), float(o), int(d))
        self._with_recovery(lambda: self._configure(*self._want))

    def _configure(self, range_g: int, odr_hz: float, dlpf: int) -> None:
        div = smplrt_div_for(odr_hz, dlpf)
        d = self.link.command(bp.CMD_CONFIGURE, bp.CONFIGURE.pack(AFS_SEL[range_g], dlpf, div))
        if len(d) != bp.CONFIGURE_DATA.size:
            raise DeviceError(f"MPU6050 bridge on {self.port}: CONFIGURE answered {len(d)} bytes")
        accel_config, config, got_div, _ = bp.CONFIGURE_DATA.unpack(d)
        if (accel_config >> 3) & 3 != AFS_SEL[range_g] or config & 7 != dlpf or got_div != div:
            raise DeviceError(f"MPU6050 via {self.port} did not take the configuration: "
                              f"ACCEL_CONFIG 0x{accel_config:02x}, CONFIG 0x{config:02x}, SMPLRT_DIV {got_div} "
                              f"(wanted AFS_SEL {AFS_SEL[range_g]}, "
                              f"DLPF_CFG {dlpf}, SMPLRT_DIV {div})")
        self._range_g, self._dlpf, self._div = range_g, dlpf, div
        self._odr_hz = rate_base_hz(dlpf) / (1 + div)

    @property
    def range_g(self) -> int:
        return self._range_g

    @property
    def odr_hz(self) -> float:
        return self._odr_hz

    @property
    def dlpf(self) -> int:
        return self._dlpf

    @property
    def counts_per_g(self) -> float:
        return float(COUNTS_PER_G[self._range_g])

    @property
    def nvm(self) -> NVM | None:
        return self._nvm

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def identify(self) -> Identity:
        if self._bridge is None:
            raise DeviceError(f"MPU6050 bridge on {self.port} is not open; use `with driver:` or open()")
        b = self._bridge
        return Identity(chip="mpu6050", chip_id=b.who_am_i, serial=b.serial, interface=f"serial:{self.port}",
                        firmware=f"mpu6050-bridge {b.firmware} (protocol {b.protocol})")

    def settings(self) -> JsonObject:
        """Chip-specific settings for display (``accelcal probe``)."""
        b = self._bridge
        return {"dlpf": self._dlpf, "accel_bandwidth_hz": DLPF_BANDWIDTH_HZ[self._dlpf],
                "smplrt_div": self._div, "accel_offsets_lsb": self.accel_offsets().tolist(),
                "i2c_address": f"0x{b.i2c_address:02x}" if b else None,
                "nvm": f"bridge EEPROM, {b.nvm_size} bytes, {b.nvm_page_size}-byte pages" if b else None}

    # --- self-test --------------------------------------------------------------------------
    supports_self_test = True

    def self_test(self, n: int = 64) -> SelfTestResult:
        """The accelerometer self-test through the bridge's SELF_TEST command (register map 4.1): n
        samples at +-8 g with XA/YA/ZA_ST off, n with them on; STR = on - off per axis, compared with
        the factory trim FT from SELF_TEST_X/Y/Z/A: (STR - FT) / FT within +-14 % (product spec 6.1)."""
        if not 4 <= int(n) <= bp.SELF_TEST_MAX_N:
            raise ConfigError(f"self-test samples {n!r}; allowed: 4 to {bp.SELF_TEST_MAX_N}")
        try:  # ACCEL_CONFIG read back afterwards, also on an error
            (off, var_off, regs), (on, var_on, _) = (self._self_test_phase(v, int(n)) for v in (False, True))
        finally:
            self._check_range_restored()
        ft = factory_trim_counts(regs)
        sem = np.sqrt((var_off + var_on) / int(n))
        return judge_against_trim("mpu6050", on - off, sem, COUNTS_PER_G[8], ft, SELF_TEST_TOLERANCE, int(n), 8,
                                  SELF_TEST_SOURCE)

    def noise_lag1(self) -> float:  # the DLPF: a one-pole low-pass of its CONFIG-table bandwidth at the ODR
        return float(np.exp(-2.0 * np.pi * DLPF_BANDWIDTH_HZ[self._dlpf] / self._odr_hz))

    def _check_range_restored(self) -> None:  # the firmware restores ACCEL_CONFIG: the run's range, no ST bits
        got = self.read_register(ACCEL_CONFIG)[0]
        want = AFS_SEL[self._range_g] << 3
        if got & 0xF8 != want:
            raise DeviceError(f"MPU6050 bridge on {self.port}: ACCEL_CONFIG 0x{got:02x} after the self-test, "
                              f"the run's +-{self._range_g} g is 0x{want:02x}")

    def _self_test_phase(self, on: bool, n: int) -> tuple[np.ndarray, np.ndarray, bytes]:
        """One SELF_TEST phase: mean and variance per axis (counts at +-8 g), the SELF_TEST registers."""
        try:
            d = self._call(bp.CMD_SELF_TEST, bp.SELF_TEST.pack(int(on), n))
        except BridgeRefused as e:
            if e.code != bp.ERR_UNKNOWN_CMD:
                raise
            raise DeviceError(f"{e}; the bridge firmware has no SELF_TEST: flash firmware/mpu6050_bridge "
                              "from this release") from None
        if len(d) != bp.SELF_TEST_DATA.size:
            raise DeviceError(f"MPU6050 bridge on {self.port}: SELF_TEST answered {len(d)} bytes, expected "
                              f"{bp.SELF_TEST_DATA.size}")
        got = bp.SELF_TEST_DATA.unpack(d)
        m, s, sq, first, regs = got[0], np.array(got[1:4], float), np.array(got[4:7], float), \
            np.array(got[7:10], float), got[10]
        mean = s / m
        dev = mean - first  # mean deviation from the first sample: var = E[d^2] - E[d]^2
        var = np.maximum(sq / m - dev * dev, 0.0) * m / max(m - 1, 1)
        return mean, var, regs

    # --- data -----------------------------------------------------------------------------
    def temperature_c(self) -> float | None:
        raw = np.frombuffer(self.read_register(TEMP_OUT_H, 2), dtype=">i2")[0]
        return float(temperature_from_raw(raw))

    def capture(self, n: int | None = None, seconds: float | None = None, keep: bool = False) -> Capture:
        """As Driver.capture; temp_c is the mean TEMP_OUT over the captured samples."""
        cap = super().capture(n, seconds, keep)
        return replace(cap, temp_c=self._stream_temp_c) if self._stream_temp_c is not None else cap

    def read_samples(self, n: int) -> tuple[np.ndarray, np.ndarray, int]:
        """Stream n samples: counts (m, 3) int64, MCU times (m,) s, dropped = n - m lost frames.

        A stall (no frame for timeout_s plus two periods) stops the stream and asks for the
        rest, at most ``retries`` times; a bridge reset re-initialises the chip and asks for
        the rest, at most MAX_RESETS times.
        """
        n = int(n)
        if n < 1:
            raise DeviceError(f"read of {n} samples; need at least 1")
        raw = bytearray()
        times: list[float] = []
        dropped = [0]
        stalls = resets = 0
        while (rest := n - len(times) - dropped[0]) > 0:
            try:
                status = self._stream(rest, raw, times, dropped)
                if status == "done":
                    continue
            except BridgeReset as e:
                resets += 1
                self.link.stats.resets += 1
                if resets > MAX_RESETS:
                    raise DeviceError(f"{e} {resets} times during one capture; check its power supply "
                                      "and USB cable") from None
                self._with_recovery(self._init_chip)
                continue
            stalls += 1
            if stalls > self.link.retries:
                why = f"no sample for {self._inactivity_s():g} s" if status == "stalled" else \
                    "it ended the stream early (I2C read failed)"
                raise DeviceError(f"MPU6050 bridge on {self.port} broke off streaming {stalls} times in one "
                                  f"capture ({why}); got {len(times)} of {n} samples")
            self.link.stats.retries += 1
            if status == "stalled":
                self._call(bp.CMD_STOP)
        self.link.stats.dropped_samples += dropped[0]
        if not times:
            raise DeviceError(f"MPU6050 bridge on {self.port}: all {n} samples of the capture were lost")
        data = np.frombuffer(bytes(raw), dtype=">i2").reshape(-1, 4).astype(np.int64)
        self._stream_temp_c = float(temperature_from_raw(data[:, 3].mean()))
        return data[:, :3], np.asarray(times), dropped[0]

    def _inactivity_s(self) -> float:
        return self.link.timeout_s + 2.0 / self._odr_hz

    def _stream(self, m: int, raw: bytearray, times: list[float], dropped: list[int]) -> str:
        """One STREAM of m samples into raw/times: "done", "short" (STREAM_END before m) or "stalled"."""
        return stream_once(self.link, self.port, m, Received(raw, times, dropped), self._inactivity_s())

"""NXP MMA8451Q three-axis accelerometer on I2C through smbus2, with a 24Cxx EEPROM on the same bus.

Register map and behaviour from the MMA8451Q data sheet (Rev. 10.3, 02/2017, section 6):
WHO_AM_I 0x0D reads 0x1A; configuration registers only change in STANDBY (CTRL_REG1 0x2A
bit 0 ACTIVE clear); data are 14-bit, left-justified, two's complement, MSB first in 0x01-0x06.

The driver only calls smbus2's ``SMBus`` methods, so the same code runs against a real
``/dev/i2c-N`` and against :class:`~accelcal_station.drivers.mma8451_emulator.MMA8451Emulator`
(``bus: emulated``, built by drivers/emulated.py and handed in); the only other thing
injected is the clock it waits on.  This module never imports the emulator.

Faults and what the driver does:
  NACK or bus error (OSError)  retried ``retries`` times (1 ms apart), then DeviceError naming the bus,
                               address and register (NVMError for the EEPROM)
  wrong chip                   refused by name before anything is written to it
  no data ready                DeviceError after ``timeout_s`` plus two sample periods of STATUS polling
  overrun (ZYXOW)              the stream goes on; lost samples are counted in ``dropped``
  NACKs during reset or an EEPROM write cycle are expected and waited out (bounded).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any, TypedDict, TypeVar

import numpy as np
import smbus2
from numpy.typing import ArrayLike

from ..config.kinds import I2cEepromSection, Mma8451Section
from ..errors import ConfigError, DeviceError
from ..jsontypes import JsonObject
from .base import NVM, Clock, Driver, Identity, ReportsEvents
from .i2c_target import I2CEeprom, I2CTarget, _os_reason
from .self_test import SelfTestResult, judge_in_g

log = logging.getLogger(__name__)

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

T = TypeVar("T")


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


class Wanted(TypedDict):
    """The settings ``open()`` configures the chip with."""

    range_g: int
    odr_hz: float
    oversampling: str


class Mma8451Settings(TypedDict):
    """The constructor keywords a ``device:`` section gives (besides its bus): :func:`settings_of`."""

    address: int
    range_g: int
    odr_hz: float
    oversampling: str
    retries: int
    timeout_s: float
    serial: str
    offset_trim_lsb: list[int] | None
    eeprom: I2cEepromSection | None


def settings_of(m: Mma8451Section, path: str = "device") -> Mma8451Settings:
    """The driver's keywords from a validated ``device:`` section, after the checks across its keys
    that the model alone does not make (the bus's form, the emulator's keys only with ``bus: emulated``,
    the address among the chip's two, the data rate among its eight).

    ``bus: emulated`` is checked here but built by the factory (drivers/emulated.py), which hands the
    emulated bus in: this module never imports its emulator.
    """
    bus = m.bus
    emulated = bus == "emulated"
    if not emulated and not (isinstance(bus, int) and bus >= 0) \
            and not (isinstance(bus, str) and bus.startswith("/dev/")):
        raise ConfigError(f"{path}.bus: {bus!r}; allowed: a bus number (1 for /dev/i2c-1), "
                          "a /dev/i2c-N path, or 'emulated'")
    extra = [k for k, v in (("simulator", m.simulator), ("seed", m.seed), ("emulator", m.emulator)) if v is not None]
    if extra and not emulated:
        raise ConfigError(f"{path}.{extra[0]}: only used with bus: emulated")
    if m.address not in ADDRESSES:
        raise ConfigError(f"{path}.address: 0x{m.address:02x}; allowed: 0x1c (SA0 low), 0x1d (SA0 high)")
    trim = m.offset_trim_lsb
    if trim is not None and (len(trim) != 3 or not all(-128 <= v <= 127 for v in trim)):
        raise ConfigError(f"{path}.offset_trim_lsb: {trim!r}; allowed: [x, y, z] whole numbers -128..127")
    odr_index(m.odr_hz, f"{path}.odr_hz")
    # absent: the default EEPROM; false or null: none
    eeprom = I2cEepromSection() if "eeprom" not in m.model_fields_set else (m.eeprom or None)
    return Mma8451Settings(address=m.address, range_g=m.range_g, odr_hz=m.odr_hz, oversampling=m.oversampling,
                           retries=m.retries, timeout_s=m.timeout_s, serial=str(m.serial or ""),
                           offset_trim_lsb=trim, eeprom=eeprom)


class SystemClock:
    """Wall-clock time for real hardware (the emulator supplies a virtual one)."""

    realtime = True

    @staticmethod
    def now() -> float:
        return time.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        time.sleep(seconds)


class MMA8451(Driver):
    """MMA8451Q over smbus2.  ``bus`` is a bus number or /dev path, or an SMBus-like object."""

    name = "mma8451"
    supports_offset_trim = True  # OFF_X/Y/Z: the station's optional offset-register trim
    offset_trim_lsb_g = OFF_LSB_G

    def __init__(self, bus: int | str | Any = 1, address: int = 0x1D, range_g: int = 2, odr_hz: float = 100.0,
                 oversampling: str = "high_resolution", retries: int = 3, timeout_s: float = 1.0,
                 serial: str = "", offset_trim_lsb: Sequence[int] | None = None,
                 eeprom: I2cEepromSection | None = None, clock: Clock | None = None,
                 bus_label: str | None = None) -> None:
        if address not in ADDRESSES:
            raise ConfigError(f"address {address!r}; allowed: 0x1c (SA0 low), 0x1d (SA0 high)")
        self._bus_spec = bus
        self._owns_bus = isinstance(bus, (int, str))
        self.bus_label = bus_label or (str(bus) if self._owns_bus else type(bus).__name__)
        self.address = address
        self.clock = clock or SystemClock()
        self.retries, self.timeout_s, self.serial = int(retries), float(timeout_s), serial
        self._want = Wanted(range_g=range_g, odr_hz=odr_hz, oversampling=oversampling)
        self._trim0 = offset_trim_lsb
        self._eeprom_cfg = eeprom
        self._smbus: Any = None if self._owns_bus else bus
        self._dev: I2CTarget | None = None
        self._identified = False  # never write to a chip that is not an MMA8451
        self._nvm: I2CEeprom | None = None
        self._range_g, self._odr_hz, self._mods = 2, 800.0, "normal"  # power-on defaults

    # --- lifecycle ------------------------------------------------------------------------
    def _open_bus(self) -> Any:
        bus = self._bus_spec
        node = bus if isinstance(bus, str) else f"/dev/i2c-{bus}"
        try:
            return smbus2.SMBus(bus)
        except FileNotFoundError:
            raise DeviceError(f"i2c bus {bus}: {node} does not exist; enable I2C (raspi-config > Interface "
                              "Options > I2C) or list buses with `i2cdetect -l`") from None
        except PermissionError:
            raise DeviceError(f"i2c bus {bus}: permission denied on {node}; add the user to the i2c group "
                              "(sudo usermod -aG i2c $USER) and log in again") from None
        except OSError as e:
            raise DeviceError(f"i2c bus {bus}: cannot open {node}: {_os_reason(e)}") from None

    def open(self) -> None:
        if self._dev is not None:
            return
        if self._owns_bus:
            self._smbus = self._open_bus()
        self._dev = I2CTarget(self._smbus, self.bus_label, self.address, self.clock, self.retries,
                              register_names=REGISTER_NAMES)
        try:
            self._check_identity()
            self._identified = True
            self.reset()
            self.configure(**self._want)
            if self._trim0 is not None:
                self.set_offset_trim(self._trim0)
        except BaseException:
            self.close()
            raise
        if self._eeprom_cfg:
            e = self._eeprom_cfg
            self._nvm = I2CEeprom(I2CTarget(self._smbus, self.bus_label, e.address, self.clock, self.retries,
                                            register_names=REGISTER_NAMES),
                                  e.size, e.page_size, e.write_cycle_ms / 1e3)

    def close(self) -> None:
        if self._identified and self._smbus is not None:
            with suppress(OSError):  # leave the part in STANDBY (lowest power); a dead bus must not mask the real error
                self._smbus.write_byte_data(self.address, CTRL_REG1, 0)
        if self._owns_bus and self._smbus is not None:
            self._smbus.close()
            self._smbus = None
        self._dev = self._nvm = None
        self._identified = False

    @property
    def dev(self) -> I2CTarget:
        if self._dev is None:
            raise DeviceError(f"MMA8451 on i2c bus {self.bus_label} is not open; use `with driver:` or open()")
        return self._dev

    def _check_identity(self) -> None:
        hint = "; check wiring, power and the address (SA0 pin: 0x1c low, 0x1d high)"
        who = self.dev.call("read", WHO_AM_I, self.dev.smbus.read_byte_data, self.address, WHO_AM_I, hint=hint)
        if who != CHIP_ID:
            name = f" ({KNOWN_CHIP_IDS[who]})" if who in KNOWN_CHIP_IDS else ""
            raise DeviceError(f"found chip id 0x{who:02x}{name} at bus {self.bus_label} address 0x{self.address:02x}: "
                              f"not an MMA8451 (expects WHO_AM_I 0x{CHIP_ID:02X})")

    def reset(self) -> None:
        """Software reset (CTRL_REG2 RST) and wait for it to self-clear.

        The part reboots at once and may not ACK meanwhile, so NACKs are expected here
        (as in Linux mma8452_reset()); all registers return to their defaults (STANDBY, 2 g, 800 Hz).
        """
        with suppress(OSError):
            self.dev.smbus.write_byte_data(self.address, CTRL_REG2, CTRL2_RST)
        last: Any = "RST bit still set"
        for _ in range(RESET_POLLS):
            self.clock.sleep(0.0002)
            try:
                if not self.dev.smbus.read_byte_data(self.address, CTRL_REG2) & CTRL2_RST:
                    self._range_g, self._odr_hz, self._mods = 2, 800.0, "normal"
                    return
            except OSError as e:
                last = _os_reason(e)
        raise DeviceError(f"software reset of {self.dev.where(CTRL_REG2)} did not complete: {last}")

    # --- configuration --------------------------------------------------------------------
    @contextmanager
    def _standby(self) -> Iterator[int]:
        """STANDBY for the duration (configuration writes are ignored while ACTIVE), then ACTIVE."""
        ctrl1 = self.dev.read_byte(CTRL_REG1) & ~CTRL1_ACTIVE
        self._write_checked(CTRL_REG1, ctrl1)
        yield ctrl1
        self.dev.write_byte(CTRL_REG1, self.dev.read_byte(CTRL_REG1) | CTRL1_ACTIVE)

    def _write_checked(self, register: int, value: int, mask: int = 0xFF) -> None:
        """Write and read back: a chip still ACTIVE silently ignores configuration writes."""
        self.dev.write_byte(register, value)
        got = self.dev.read_byte(register)
        if (got ^ value) & mask:
            raise DeviceError(f"{self.dev.where(register)}: wrote 0x{value & 0xFF:02x}, read back 0x{got:02x} "
                              "(configuration registers only change in STANDBY)")

    def configure(self, range_g: int | None = None, odr_hz: float | None = None, **options: Any) -> None:
        """Full scale (2/4/8 g), data rate (1.56-800 Hz), ``oversampling`` (CTRL_REG2 MODS), in STANDBY."""
        mods = options.pop("oversampling", None)
        if options:
            raise ConfigError(f"mma8451 options {', '.join(map(str, options))}: unknown; allowed: oversampling")
        range_g = self._range_g if range_g is None else range_g
        if range_g not in FS_BITS:
            raise ConfigError(f"range_g: {range_g!r}; allowed: 2, 4, 8")
        dr = odr_index(self._odr_hz if odr_hz is None else odr_hz)
        mods = self._mods if mods is None else mods
        if mods not in MODS:
            raise ConfigError(f"oversampling: {mods!r}; allowed: {', '.join(MODS)}")
        with self._standby() as ctrl1:
            self._write_checked(XYZ_DATA_CFG, FS_BITS[range_g], FS_MASK)
            ctrl2 = self.dev.read_byte(CTRL_REG2)
            self._write_checked(CTRL_REG2, (ctrl2 & ~CTRL2_MODS_MASK & ~CTRL2_RST) | MODS[mods], CTRL2_MODS_MASK)
            self._write_checked(CTRL_REG1, (ctrl1 & ~(CTRL1_DR_MASK | CTRL1_F_READ)) | (dr << CTRL1_DR_SHIFT))
        self._range_g, self._odr_hz, self._mods = range_g, ODR_HZ[dr], mods

    def set_offset_trim(self, lsb: Sequence[int] | np.ndarray) -> None:
        """Write OFF_X/Y/Z (signed 8-bit, 1/512 g = "2 mg" per LSB) in STANDBY and verify by read-back."""
        vals = [int(v) for v in lsb]
        if len(vals) != 3 or any(not -128 <= v <= 127 for v in vals):
            raise ConfigError(f"offset trim {list(lsb)!r}; allowed: three whole numbers -128..127 (1/512 g each)")
        with self._standby():
            for reg, v in zip((OFF_X, OFF_Y, OFF_Z), vals, strict=True):
                self._write_checked(reg, v & 0xFF)

    supports_self_test = True

    def self_test(self, n: int = 64) -> SelfTestResult:
        """The chip's self-test (CTRL_REG2 ST) at +-8 g (SELF_TEST_RANGE_G): n samples with it off, n with it
        on, the change per axis judged against the data sheet's limits (drivers/self_test.py).  ST is
        cleared and the run's range restored and read back afterwards, also on an error."""
        if not 4 <= int(n) <= 100_000:
            raise ConfigError(f"self-test samples {n!r}; allowed: 4 to 100000")
        n = int(n)
        run_range = self._range_g
        settle = max(4, int(np.ceil(0.02 * self._odr_hz)))  # the output filter's transient, discarded
        try:
            if run_range != SELF_TEST_RANGE_G:
                self.configure(range_g=SELF_TEST_RANGE_G)
            per_g = self.counts_per_g
            self._set_self_test(False)
            self.read_samples(settle)
            off = self.read_samples(n)[0].astype(float)
            self._set_self_test(True)
            self.read_samples(settle)
            on = self.read_samples(n)[0].astype(float)
        finally:
            self._set_self_test(False)
            self._restore_range(run_range)
        change = on.mean(axis=0) - off.mean(axis=0)
        sem = np.sqrt(on.var(axis=0, ddof=1) / n + off.var(axis=0, ddof=1) / n)
        return judge_in_g("mma8451", change, sem, per_g, SELF_TEST_LOW_G, SELF_TEST_HIGH_G, n,
                          SELF_TEST_RANGE_G, SELF_TEST_SOURCE)

    def _restore_range(self, range_g: int) -> None:
        """Back to the run's range after the self-test, verified by reading XYZ_DATA_CFG back."""
        if self._range_g != range_g:
            self.configure(range_g=range_g)
        got = self.dev.read_byte(XYZ_DATA_CFG) & FS_MASK
        if got != FS_BITS[range_g]:
            raise DeviceError(f"{self.dev.where(XYZ_DATA_CFG)}: range not restored after the self-test: "
                              f"FS bits {got}, the run's +-{range_g} g is {FS_BITS[range_g]}")

    def _set_self_test(self, on: bool) -> None:
        with self._standby():
            ctrl2 = self.dev.read_byte(CTRL_REG2) & ~CTRL2_RST
            self._write_checked(CTRL_REG2, (ctrl2 | CTRL2_ST) if on else (ctrl2 & ~CTRL2_ST), CTRL2_ST)

    def get_offset_trim(self) -> tuple[int, int, int]:
        raw = self.dev.read_block(OFF_X, 3)
        x, y, z = (int(v) for v in np.array(raw, dtype=np.uint8).view(np.int8))
        return x, y, z

    # --- properties -----------------------------------------------------------------------
    @property
    def range_g(self) -> int:
        return self._range_g

    @property
    def odr_hz(self) -> float:
        return self._odr_hz

    @property
    def counts_per_g(self) -> float:
        return float(COUNTS_PER_G[self._range_g])

    @property
    def oversampling(self) -> str:
        return self._mods

    @property
    def nvm(self) -> NVM | None:
        return self._nvm

    def take_events(self) -> list[str]:
        """The bus's events (a multiplexer channel re-selected after the mux reset) since the last call."""
        return self._bus_spec.take_events() if isinstance(self._bus_spec, ReportsEvents) else []

    def identify(self) -> Identity:
        return Identity(chip="mma8451", chip_id=CHIP_ID, serial=self.serial,
                        interface=f"i2c:{self.bus_label}@0x{self.address:02x}")

    def settings(self) -> JsonObject:
        """Chip-specific settings for display (``accelcal probe``)."""
        s: JsonObject = {"oversampling": self._mods, "offset_trim_lsb": list(self.get_offset_trim())}
        if self._nvm is not None:
            s["eeprom"] = (f"24Cxx at 0x{self._nvm.t.address:02x}, {self._nvm.size} bytes, "
                           f"{self._nvm.page_size}-byte pages")
        return s

    # --- data -----------------------------------------------------------------------------
    def _wait_ready(self, deadline: float) -> tuple[int, float]:
        """Poll STATUS until ZYXDR, sleeping a quarter period between polls."""
        poll = 0.25 / self._odr_hz
        while True:
            status = self.dev.read_byte(STATUS)
            now = self.clock.now()
            if status & STATUS_ZYXDR:
                return status, now
            if now > deadline:
                raise DeviceError(f"{self.dev.where(STATUS)}: no data ready (ZYXDR) within "
                                  f"{self.timeout_s:g} s + 2 samples at {self._odr_hz:g} Hz; the chip is not "
                                  "sampling (power, ACTIVE bit)")
            self.clock.sleep(poll)

    def read_samples(self, n: int) -> tuple[np.ndarray, np.ndarray, int]:
        """Next n samples: counts (n, 3) int64 in 14-bit units, data-ready times (s), dropped count.

        ZYXOW means at least one sample was overwritten unread; how many is estimated from the
        gap between data-ready instants (``round(gap * odr) - 1``, at least 1).
        """
        period = 1.0 / self._odr_hz
        self.dev.read_block(OUT_X_MSB, 6)  # reading the MSBs clears stale ZYXDR/ZYXOW
        t_prev = self.clock.now()
        raw = bytearray()
        t = np.empty(n)
        dropped = 0
        for i in range(n):
            status, t[i] = self._wait_ready(self.clock.now() + self.timeout_s + 2 * period)
            raw += bytes(self.dev.read_block(OUT_X_MSB, 6))
            if status & STATUS_ZYXOW:
                dropped += max(1, int(round((t[i] - t_prev) * self._odr_hz)) - 1)
            t_prev = t[i]
        return decode_counts(raw), t, dropped

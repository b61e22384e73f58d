"""NXP MMA8451Q three-axis accelerometer on I2C through smbus2, with a 24Cxx EEPROM on the same bus.

Behaviour from the MMA8451Q data sheet (Rev. 10.3, 02/2017, section 6):
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

from ..errors import ConfigError, DeviceError
from ..jsontypes import JsonObject
from .base import NVM, Clock, Driver, Identity, ReportsEvents
from .i2c_target import I2CEeprom, I2CTarget, _os_reason
from .mma8451_registers import (
    ADDRESSES,
    CHIP_ID,
    COUNTS_PER_G,
    CTRL1_ACTIVE,
    CTRL1_DR_MASK,
    CTRL1_DR_SHIFT,
    CTRL1_F_READ,
    CTRL2_MODS_MASK,
    CTRL2_RST,
    CTRL2_ST,
    CTRL_REG1,
    CTRL_REG2,
    FS_BITS,
    FS_MASK,
    KNOWN_CHIP_IDS,
    MODS,
    ODR_HZ,
    OFF_LSB_G,
    OFF_X,
    OFF_Y,
    OFF_Z,
    OUT_X_MSB,
    REGISTER_NAMES,
    RESET_POLLS,
    SELF_TEST_HIGH_G,
    SELF_TEST_LOW_G,
    SELF_TEST_RANGE_G,
    SELF_TEST_SOURCE,
    STATUS,
    STATUS_ZYXDR,
    STATUS_ZYXOW,
    WHO_AM_I,
    XYZ_DATA_CFG,
    decode_counts,
    odr_index,
)
from .mma8451_settings import Mma8451Settings
from .self_test import SelfTestResult, judge_in_g

log = logging.getLogger(__name__)
T = TypeVar("T")

class Wanted(TypedDict):
    """The settings ``open()`` configures the chip with."""

    range_g: int
    odr_hz: float
    oversampling: str


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

    def __init__(self, bus: int | str | Any = 1, settings: Mma8451Settings | None = None, *,
                 clock: Clock | None = None, bus_label: str | None = None) -> None:
        st = settings or Mma8451Settings()
        if st.address not in ADDRESSES:
            raise ConfigError(f"address {st.address!r}; allowed: 0x1c (SA0 low), 0x1d (SA0 high)")
        self._bus_spec = bus
        self._owns_bus = isinstance(bus, (int, str))
        self.bus_label = bus_label or (str(bus) if self._owns_bus else type(bus).__name__)
        self.address = st.address
        self.clock = clock or SystemClock()
        self.retries, self.timeout_s, self.serial = int(st.retries), float(st.timeout_s), st.serial
        self._want = Wanted(range_g=st.range_g, odr_hz=st.odr_hz, oversampling=st.oversampling)
        self._trim0 = st.offset_trim_lsb
        self._eeprom_cfg = st.eeprom
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

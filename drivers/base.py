"""The driver interface every sensor implements (python-can's BusABC in spirit).

Counts cross this boundary: a driver returns raw integer counts and says how many
counts make 1 g at its current range; everything after that is in g.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DeviceError
from ..jsontypes import JsonObject
from ..models.effective_samples import effective_n
from .self_test import SelfTestResult


@runtime_checkable
class ReportsEvents(Protocol):
    """A bus that keeps events for the run record (drivers/tca9548a.py MuxChannel: re-selections)."""

    def take_events(self) -> list[str]: ...


class Clock(Protocol):
    """What a driver or a part waits on: the wall clock, or a simulated board's virtual one."""

    @property
    def realtime(self) -> bool:
        """True when its time is the wall's (a station's board time then counts no host compute on top)."""

    def now(self) -> float: ...

    def sleep(self, dt: float) -> None: ...


@dataclass(frozen=True)
class Identity:
    chip: str  # "mma8451", "mpu6050", ...
    chip_id: int  # WHO_AM_I value
    serial: str  # board serial number ("" when the board has none)
    interface: str  # "i2c:1@0x1d", "serial:/dev/ttyUSB0", "simulated"
    firmware: str | None = None


@dataclass
class Capture:
    """Averaged counts of one static capture.

    mean_counts, std_counts: per axis (3,), std is the sample standard deviation;
    n: samples averaged; dropped: samples the device lost (overrun, sequence gap);
    temp_c: chip temperature (None when the chip has no sensor);
    t_start, t_end: timestamps (s) of the first and last sample;
    samples, timestamps: the raw stream when kept;
    n_eff: (3,) effective sample count per axis, n / tau_int from the samples' own autocorrelation
    (accelcal_station/models/effective_samples.py); None: taken as n (independent samples).
    """

    mean_counts: np.ndarray
    std_counts: np.ndarray
    n: int
    dropped: int = 0
    temp_c: float | None = None
    t_start: float = 0.0
    t_end: float = 0.0
    samples: np.ndarray | None = field(default=None, repr=False)
    timestamps: np.ndarray | None = field(default=None, repr=False)
    n_eff: np.ndarray | None = None

    @property
    def sem_counts(self) -> np.ndarray:
        """Standard error of the mean per axis, in counts: std / sqrt(n_eff)."""
        if self.n_eff is None:
            return self.std_counts / np.sqrt(max(self.n, 1))
        return self.std_counts / np.sqrt(np.maximum(self.n_eff, 1.0))

    @classmethod
    def from_samples(cls, samples: ArrayLike, timestamps: ArrayLike, dropped: int = 0, temp_c: float | None = None,
                     keep: bool = False) -> Capture:
        s = np.asarray(samples, dtype=float)
        t = np.asarray(timestamps, dtype=float)
        if s.ndim != 2 or s.shape[1] != 3 or len(s) == 0:
            raise DeviceError(f"capture returned no usable samples (shape {s.shape})")
        return cls(
            mean_counts=s.mean(axis=0),
            std_counts=s.std(axis=0, ddof=1) if len(s) > 1 else np.zeros(3),
            n=len(s), dropped=int(dropped), temp_c=temp_c,
            t_start=float(t[0]), t_end=float(t[-1]),
            samples=np.asarray(samples) if keep else None,
            timestamps=t if keep else None,
            n_eff=effective_n(s),
        )


class NVM(ABC):
    """Byte-addressed non-volatile memory on the board (EEPROM, bridge flash, simulated)."""

    size: int
    page_size: int

    @abstractmethod
    def read(self, addr: int, n: int) -> bytes:
        """Read n bytes from addr."""

    @abstractmethod
    def write(self, addr: int, data: bytes) -> None:
        """Write data at addr; splits at page boundaries and waits for each write cycle."""

    def page_chunks(self, addr: int, data: bytes) -> Iterator[tuple[int, bytes]]:
        """(address, bytes) pieces of a write that each stay inside one page (24Cxx page
        writes wrap within their page, so a write must never cross a page boundary)."""
        data = bytes(data)
        self._check_range(addr, len(data))
        i = 0
        while i < len(data):
            a = addr + i
            chunk = data[i:i + self.page_size - a % self.page_size]
            yield a, chunk
            i += len(chunk)

    def _check_range(self, addr: int, n: int) -> None:
        if addr < 0 or n < 0 or addr + n > self.size:
            raise DeviceError(f"NVM access {addr}..{addr + n} outside 0..{self.size}")


class VirtualBench(Protocol):
    """What stands behind a simulated or emulated driver (drivers/simulated.py SimulatedBoard):
    a board with its own virtual clock, which a simulated jig moves and a chamber warms."""

    clock: Any


class Driver(ABC):
    """One sensor.  Use as a context manager: ``with make_driver(cfg) as dev: ...``.

    What a driver can do beyond reading is declared here, and the station asks through these
    (never by probing attributes): ``supports_offset_trim`` (offset registers the station may
    trim: ``offset_trim_lsb_g``, ``get_offset_trim``, ``set_offset_trim``) and ``board`` (the
    simulated board a simulated or emulated driver reads; None for hardware).
    """

    name: str = "abstract"
    supports_offset_trim: bool = False
    offset_trim_lsb_g: float = 0.0  # g per offset-register LSB, when supports_offset_trim
    board: VirtualBench | None = None

    def get_offset_trim(self) -> tuple[int, int, int]:
        """The offset registers [x, y, z] in LSB (supports_offset_trim)."""
        raise DeviceError(f"the {self.name} driver has no offset-trim registers")

    def set_offset_trim(self, lsb: Any) -> None:
        """Write the offset registers [x, y, z] in LSB (supports_offset_trim)."""
        raise DeviceError(f"the {self.name} driver has no offset-trim registers")

    def __enter__(self) -> Driver:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @abstractmethod
    def open(self) -> None:
        """Connect, check the chip's identity, bring it to a known state."""

    @abstractmethod
    def close(self) -> None:
        """Release the bus or port; safe to call twice."""

    @abstractmethod
    def identify(self) -> Identity:
        """Chip and board identity."""

    @abstractmethod
    def configure(self, range_g: int | None = None, odr_hz: float | None = None, **options: Any) -> None:
        """Set full scale (g) and output data rate (Hz); chip-specific options by name."""

    @property
    @abstractmethod
    def range_g(self) -> int:
        """Current full scale in g."""

    @property
    @abstractmethod
    def odr_hz(self) -> float:
        """Current output data rate in Hz."""

    @property
    @abstractmethod
    def counts_per_g(self) -> float:
        """Nominal counts per g at the current range (e.g. 4096 for MMA8451 at 2 g)."""

    @abstractmethod
    def read_samples(self, n: int) -> tuple[np.ndarray, np.ndarray, int]:
        """The next n samples: counts (n, 3) int64, timestamps (n,) in s, dropped count."""

    def temperature_c(self) -> float | None:
        """Chip temperature in C, or None when the chip has no sensor."""
        return None

    def noise_lag1(self) -> float:
        """Lag-1 autocorrelation of the output noise its configured filter gives (a one-pole low-pass
        of the data sheet's bandwidth f_c at the ODR: exp(-2 pi f_c / ODR)); 0: independent samples."""
        return 0.0

    def settings(self) -> JsonObject:
        """Chip-specific settings for display (``accelcal probe``); none by default."""
        return {}

    @property
    def nvm(self) -> NVM | None:
        """The board's non-volatile memory, or None when it has none."""
        return None

    #: whether :meth:`self_test` runs the chip's built-in self-test (declared, not probed)
    supports_self_test: bool = False
    #: why this part's self-test is not run although the driver has one (an accepted compatible), else None
    self_test_skipped: str | None = None

    def self_test(self, n: int = 64) -> SelfTestResult:
        """The chip's self-test: output change per axis against the data sheet (drivers/self_test.py)."""
        raise DeviceError(f"the {self.name} driver has no self-test")

    def take_events(self) -> list[str]:
        """Link events since the last call that the run record should keep (e.g. a multiplexer that
        had to be re-selected); none by default."""
        return []

    def capture(self, n: int | None = None, seconds: float | None = None, keep: bool = False) -> Capture:
        """Average n samples (or ``seconds`` worth at the current data rate)."""
        if n is None:
            if seconds is None:
                raise DeviceError("capture needs n samples or a duration in seconds")
            n = max(1, int(round(seconds * self.odr_hz)))
        if n < 1:
            raise DeviceError(f"capture of {n} samples; need at least 1")
        counts, t, dropped = self.read_samples(int(n))
        return Capture.from_samples(counts, t, dropped, self.temperature_c(), keep)

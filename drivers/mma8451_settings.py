"""The MMA8451 driver's settings besides its bus (``Mma8451Settings``), and ``settings_of``: them from a
validated ``device:`` section, with the checks across its keys the schema alone does not make."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..config.kinds import I2cEepromSection, Mma8451Section
from ..errors import ConfigError
from .mma8451_registers import ADDRESSES, odr_index


@dataclass(frozen=True)
class Mma8451Settings:
    """The driver's settings besides its bus (a ``device:`` section's, :func:`settings_of`): the chip's I2C
    address and link (retries, timeout), what ``open()`` configures (range, data rate, oversampling), the
    board's serial, its offset-register trim and its calibration EEPROM (None: none)."""

    address: int = 0x1D
    range_g: int = 2
    odr_hz: float = 100.0
    oversampling: str = "high_resolution"
    retries: int = 3
    timeout_s: float = 1.0
    serial: str = ""
    offset_trim_lsb: Sequence[int] | None = None
    eeprom: I2cEepromSection | None = None


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

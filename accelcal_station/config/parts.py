"""The sections each driver, jig and instrument accepts (pydantic models, as schema.py).

The station schema (schema.py) declares every key any driver or jig may take; a section's own
code then validates its section against the model of its driver or jig type below
(``parse(section, Mma8451Section, "device")``): which keys that driver accepts, its defaults
and ranges.  Both give their errors through ``schema.error_line``, so a key valid for one
driver but not another is the same one line (``device.dlpf: unknown key; allowed: ...``)
wherever it is found.  docs/config.md lists these tables too.
"""
from __future__ import annotations

from typing import Annotated, Any, Literal, TypeVar

from pydantic import BaseModel, Field, StrictBool, field_validator

from .schema import BridgeEmulatorSection, BusEmulatorSection, HandSection, Section, _check_mount, _f, validate

M = TypeVar("M", bound=BaseModel)


def parse(data: Any, model: type[M], where: str) -> M:
    """``data`` (None: an empty mapping) checked against ``model``: ConfigError, one line."""
    return validate({} if data is None else data, model, where)  # type: ignore[return-value]


class SimEepromSection(Section):
    """A simulated board's EEPROM (``device.eeprom``, driver: simulated)."""

    size_bytes: int = _f(4096, "EEPROM size, bytes (a multiple of page_bytes)", ge=1, le=2**20)
    page_bytes: int = _f(32, "page size, bytes", ge=1, le=4096)
    write_cycle_ms: float = _f(5.0, "write cycle time, ms", ge=0, le=1000)
    fail_at_write: int | None = _f(None, "fail at this write (power-loss tests)", ge=1, le=2**31)
    image: str | None = _f(None, "keep the EEPROM in this file between commands")


class SimulatedBoardSection(Section):
    """``device`` with ``driver: simulated`` (and an emulated chip's ``simulator`` board mapping)."""

    chip: str | None = _f(None, "chip (mma8451, mpu6050)")
    range_g: int | None = _f(None, "full scale, g (the chip's: 2, 4, 8 or 16)")
    odr_hz: float | None = _f(None, "output data rate, Hz (one of the chip's rates)")
    dlpf: int | None = _f(None, "mpu6050: digital low-pass filter setting", ge=0, le=6)
    seed: int | None = _f(None, "random seed (default: fresh, recorded)", ge=0, le=2**63 - 1)
    serial: str | int | None = _f(None, "board serial number")
    realtime: StrictBool = _f(False, "sleep the wall time as the virtual clock runs")
    ambient_c: float = _f(25.0, "board temperature, C", ge=-60, le=150)
    self_heating_c: float = _f(0.0, "warm-up of the board, C", ge=0, le=50)
    eeprom: SimEepromSection | None = _f(None, "the board's calibration EEPROM")
    simulator: dict[str, Any] | str | None = _f(None, "the forward sensor model ({effects: ...}) or a YAML file")
    effects: dict[str, Any] | None = _f(None, "effects (as simulator.effects)")
    true_mount: list[str] | None = _f(None, "how the chip really sits on the board: the chip axes along the "
                                      "board's x, y, z, e.g. [y, -x, z] (default [x, y, z])")

    @field_validator("true_mount")
    @classmethod
    def _proper_turn(cls, v: list[str] | None) -> list[str] | None:
        return _check_mount(v)


class SimulatorFileSection(Section):
    """A simulator file or mapping: ``{effects: ...}``."""

    effects: dict[str, Any] | None = _f(None, "effects of the catalog (sim/sensor_model.py EFFECTS)")
    population: dict[str, Any] | None = _f(None, "the population boards are drawn from (sim/population.py)")
    physics: Literal["implicit", "forward"] = _f("implicit", "the cubic's physics (sim/sensor_model.py PHYSICS)")


class I2cEepromSection(Section):
    """An MMA8451 board's 24Cxx EEPROM (``device.eeprom``, driver: mma8451)."""

    address: int = _f(0x50, "EEPROM I2C address", ge=0x50, le=0x57)
    # 24C32 and up: smaller 24Cxx take a 1-byte word address, which the driver does not send
    size: int = _f(4096, "EEPROM size, bytes", ge=4096, le=65536)
    page_size: int = _f(32, "page size, bytes", ge=8, le=256)
    write_cycle_ms: float = _f(5.0, "write cycle time, ms", ge=0.1, le=100)


class Mma8451Section(Section):
    """``device`` with ``driver: mma8451`` (the driver key and a panel's mux keys removed)."""

    bus: int | str = _f(1, "I2C bus number, /dev/i2c-N or 'emulated'")
    address: int = _f(0x1D, "I2C address: 0x1c (SA0 low) or 0x1d (SA0 high)")
    range_g: Literal[2, 4, 8] = _f(2, "full scale, g")
    odr_hz: float = _f(100.0, "output data rate, Hz (one of the chip's rates)")
    oversampling: Literal["normal", "low_noise_low_power", "high_resolution", "low_power"] = _f(
        "high_resolution", "oversampling mode")
    retries: int = _f(3, "retries of a bus transaction", ge=0, le=20)
    timeout_s: float = _f(1.0, "transaction timeout, s", ge=0.001, le=60)
    serial: str | int | None = _f(None, "board serial number")
    offset_trim_lsb: list[int] | None = _f(None, "offset registers [x, y, z], whole numbers -128..127")
    eeprom: I2cEepromSection | Literal[False] | None = _f(None, "the board's EEPROM (false: none)")
    simulator: dict[str, Any] | str | None = _f(None, "bus: emulated: the simulated board (a mapping or a file)")
    seed: int | None = _f(None, "bus: emulated: random seed", ge=0, le=2**63 - 1)
    emulator: BusEmulatorSection | None = _f(None, "bus: emulated: the emulator's faults")


class Mpu6050Section(Section):
    """``device`` with ``driver: mpu6050`` (the serial bridge; the driver key removed)."""

    port: str | None = _f(None, "serial port of the bridge (or 'emulated'); required")
    baud: int = _f(115200, "serial baud rate", ge=1200, le=4_000_000)
    range_g: Literal[2, 4, 8, 16] = _f(2, "full scale, g")
    odr_hz: float = _f(100.0, "output data rate, Hz", ge=0, le=1000)
    dlpf: int = _f(3, "digital low-pass filter setting", ge=0, le=6)
    timeout_s: float = _f(0.5, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(3, "retries of a serial transaction", ge=0, le=20)
    boot_wait_s: float = _f(2.0, "wait for the bridge to boot, s", ge=0, le=30)
    simulator: dict[str, Any] | str | None = _f(None, "port: emulated: the simulated board (a mapping or a file)")
    seed: int | None = _f(None, "port: emulated: random seed", ge=0, le=2**32 - 1)
    emulator: BridgeEmulatorSection | None = _f(None, "port: emulated: the bridge emulator's chip and faults")


class Mpu6050SimSection(Section):
    """The ``simulator``, ``seed`` and ``emulator`` of an emulated mpu6050 (other device keys are ignored)."""

    simulator: dict[str, Any] | str | None = None
    seed: int | None = _f(None, "random seed", ge=0, le=2**32 - 1)
    emulator: BridgeEmulatorSection | None = None


class EmulatedSeedSection(Section):
    """An emulated chip's seed."""

    seed: int | None = _f(None, "random seed", ge=0, le=2**63 - 1)


class MuxChannelSection(Section):
    """A board behind a TCA9548A: its channel."""

    channel: int = _f(..., "multiplexer channel; required behind a mux", ge=0, le=7)


class PanelSeedSection(Section):
    """A simulated panel's seed: board i draws from seed * 1000 + i."""

    seed: int = _f(1, "panel seed", ge=0, le=2**32 - 1)


class SimulatedJigSection(Section):
    """``jig`` with ``type: simulated``."""

    move_time_s: float = _f(2.0, "time between poses on the virtual clock, s", ge=0, le=120)


class OperatorJigSection(Section):
    """``jig`` with ``type: operator``."""

    tolerance_deg: float = _f(12.0, "pose tolerance, deg", ge=1, le=45)
    hand: HandSection | Literal[True] | None = _f(None, "a simulated hand instead of a person (CI)")


class MotorizedJigSection(Section):
    """``jig`` with ``type: motorized``."""

    port: str | None = _f(None, "serial port (or 'emulated'); required")
    baud: int = _f(115200, "serial baud rate", ge=300, le=4_000_000)
    timeout_s: float = _f(0.5, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(2, "retries of a command", ge=0, le=10)
    speed_deg_s: float | None = _f(None, "axis speed, deg/s (default: the controller's)", ge=1e-6, le=1e4)
    accel_deg_s2: float | None = _f(None, "axis acceleration, deg/s^2 (default: the controller's)", ge=1e-6,
                                    le=1e6)
    home_on_open: StrictBool = _f(True, "home the axes when the port opens")
    tolerance_deg: float = _f(0.02, "position tolerance, deg", ge=1e-4, le=5)
    move_margin_s: float = _f(2.0, "extra time allowed for a move, s", ge=0, le=600)
    settle_s: float = _f(0.0, "wait after a move, s", ge=0, le=60)
    poll_s: float = _f(0.01, "status poll interval, s", ge=0.001, le=5)
    axis_sign: Annotated[list[Literal[1, -1]], Field(min_length=2, max_length=2)] = _f(
        [1, 1], "sign of each axis [pitch, roll]: 1 or -1")
    axis_offset_deg: Annotated[list[float], Field(min_length=2, max_length=2)] = _f(
        [0.0, 0.0], "zero offset of each axis [pitch, roll], deg")


DEVICE_MODELS: dict[str, type[Section]] = {"simulated": SimulatedBoardSection, "mma8451": Mma8451Section,
                                            "mpu6050": Mpu6050Section}
JIG_MODELS: dict[str, type[Section]] = {"simulated": SimulatedJigSection, "operator": OperatorJigSection,
                                        "motorized": MotorizedJigSection}
PANEL_KEYS = ("driver", "boards", "spread", "mux", "channel", "seated_deg")  # the panel's, not the driver's
STATION_DEVICE_KEYS = ("mount",)  # the station's (how the chip sits on the board), every driver's board has one


def check_kinds(raw: dict[str, Any]) -> None:
    """The ``device`` keys its driver accepts and the ``jig`` keys its type accepts (after
    validate_station): a key of another driver or jig type is one line naming the allowed keys."""
    device = raw.get("device")
    if isinstance(device, dict):
        parse({k: v for k, v in device.items() if k not in PANEL_KEYS + STATION_DEVICE_KEYS},
              DEVICE_MODELS[device.get("driver", "simulated")], "device")
    jig = raw.get("jig")
    if isinstance(jig, dict):
        parse({k: v for k, v in jig.items() if k != "type"}, JIG_MODELS[jig.get("type", "simulated")], "jig")


PARTS: list[tuple[str, type[BaseModel]]] = [
    ("device (driver: simulated)", SimulatedBoardSection), ("device.eeprom (driver: simulated)", SimEepromSection),
    ("device (driver: mma8451)", Mma8451Section), ("device.eeprom (driver: mma8451)", I2cEepromSection),
    ("device (driver: mpu6050)", Mpu6050Section),
    ("jig (type: simulated)", SimulatedJigSection), ("jig (type: operator)", OperatorJigSection),
    ("jig (type: motorized)", MotorizedJigSection),
]

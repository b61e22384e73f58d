"""The sections whose keys depend on a kind: ``device`` by ``driver`` (simulated, mma8451,
mpu6050) and ``jig`` by ``type`` (simulated, operator, motorized), each a pydantic discriminated
union of models with only that driver's or jig type's keys, and the sections nested in them.

One validation of a station config (schema.py) picks the member and checks its keys; an error
inside a member carries its tag (``driver=mma8451``) in its location, which ``TAGGED`` maps
back to the member (schema.error_line names the key path and this member's allowed keys).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import Discriminator, Field, JsonValue, StrictBool, Tag, field_validator

from ..errors import DataError
from .section import MAX_BOARDS, Section, Triple, _f

if TYPE_CHECKING:
    import numpy as np


class HandSection(Section):
    """A simulated operator's hand (operator jig in CI)."""

    wrong_face: list[str | int] = _f([], "poses (names or 1-based numbers) first presented on a wrong face")
    bump: list[str | int] = _f([], "poses (names or 1-based numbers) bumped during the capture")
    bump_after_s: float = _f(1.5, "bump this long into the capture, s", ge=0, le=60)
    bump_s: float = _f(0.5, "bump length, s", ge=0.01, le=10)
    bump_deg: float = _f(15.0, "bump tilt, deg", ge=0.1, le=90)
    move_time_s: float = _f(2.0, "time the hand takes between poses, s", ge=0, le=60)


# an effect's parameters (sim/sensor_model.py parse_effects checks each against its effect) and a
# population (sim/population.py parse_population): open JSON, validated by the simulator's own parsers
EffectSpec = dict[str, JsonValue]
Effects = dict[str, EffectSpec | StrictBool | None]
PopulationSpec = dict[str, JsonValue]


class SimulatorSection(Section):
    """A simulated board's forward sensor model (``simulator``: inline, or the file it names)."""

    effects: Effects | None = _f(
        None, "effects of the catalog (sim/sensor_model.py EFFECTS), each with its parameters")
    population: PopulationSpec | None = _f(
        None, "the population boards are drawn from: quantities, components, changes "
        "(validated by sim/population.py parse_population, one-line errors)")
    physics: Literal["implicit", "forward"] = _f(
        "implicit", "the cubic/quadratic nonlinearity: implicit (the reading G solves f = K^-1 (G - o) - q G^2 - "
        "c G^3, which model 15 inverts exactly) or forward (G = o + u + q u^2 + c u^3, u = K f: a sensor's own "
        "response, which model 15 only approximates)")


class CorruptReadsSection(Section):
    """A lying bus: read messages to one address come back with one bit flipped."""

    rate: float = _f(0.0, "probability that a read message is corrupted", ge=0, le=1)
    seed: int = _f(0, "seed of the corruption's random draws", ge=0, le=2**63 - 1)
    address: int = _f(0x50, "I2C address whose reads are corrupted (the EEPROM's)", ge=0, le=0x7F, hexadecimal=True)


class BusEmulatorSection(Section):
    """mma8451 ``bus: emulated``: the register-level emulator's faults."""

    chip_id: int = _f(0x1A, "WHO_AM_I value the emulated chip answers", ge=0, le=255, hexadecimal=True)
    nack_every: int = _f(0, "NACK every Nth bus transaction (0: never)", ge=0, le=1000)
    never_ready: StrictBool = _f(False, "the data-ready flag never sets")
    present: StrictBool = _f(True, "the chip answers on the bus at all")
    sda_held: StrictBool = _f(False, "a chip holds SDA low (left mid-byte by a reset): every transfer times out")
    bus_hz: float = _f(400_000.0, "I2C clock of the emulated bus, Hz", ge=10_000, le=3_400_000)
    corrupt_reads: CorruptReadsSection | None = _f(None, "a lying bus: reads corrupted at random (tests)")
    self_test_scale: Triple = _f(
        [1.0, 1.0, 1.0], "self-test response per axis as a share of this chip's own (a weak axis: e.g. 0.05)")
    self_test_dead: StrictBool = _f(False, "the self-test bit does nothing (a broken self-test circuit)")
    trim_step_scale: float = _f(1.0, "OFF_X/Y/Z step as a share of the data sheet's 1/512 g (a chip whose "
                                     "trim unit differs from the driver's assumption)", ge=0.5, le=2.0)
    trim_sign: Literal[1, -1] = _f(1, "sign with which OFF_X/Y/Z act on the output (-1: a part that subtracts)")
    mux_reset_after: int = _f(0, "panel behind an emulated TCA9548A: the mux resets (no channel selected, as "
                                 "after a brown-out) after this many transactions to this board (0: never)",
                              ge=0, le=10**9)


class BridgeEmulatorSection(Section):
    """mpu6050 ``port: emulated``: the bridge emulator's chip (drivers/mpu6050_emulator.py) and its faults."""

    self_test_share: Triple | None = _f(
        None, "self-test response per axis as a share of the factory trim FT (default: drawn per chip, 1 +- 4 %; "
        "a weak axis: e.g. 0.5; 0: a self-test that does nothing)")
    self_test_codes: Annotated[list[Annotated[int, Field(ge=1, le=31)]], Field(min_length=3, max_length=3)] | None = \
        _f(None, "factory self-test codes XA/YA/ZA_TEST in SELF_TEST_X/Y/Z/A, 1..31 (default: drawn per chip)")
    offset_step_scale: float = _f(1.0, "XA/YA/ZA_OFFS step as a share of 1/2048 g (a part whose offset-register "
                                       "unit differs from the driver's assumption)", ge=0.5, le=2.0)
    chip_ppm: float = _f(0.0, "the chip's clock against the bridge MCU's, ppm (positive: the chip is fast)",
                         ge=-1e4, le=1e4)
    who_am_i: int = _f(0x68, "WHO_AM_I the emulated chip answers (a clone or relative: 0x98, 0x70, 0x72, ...)",
                       ge=0, le=255)


class MuxSection(Section):
    address: int = _f(0x70, "TCA9548A I2C address", ge=0x70, le=0x77, hexadecimal=True)


class SpreadSection(Section):
    offset_mg: float = _f(0.0, "panel: per-board offset spread (standard deviation), mg", ge=0, le=1000)
    gain: float = _f(0.0, "panel: per-board gain spread (standard deviation), fraction", ge=0, le=0.5)


# --- the board: one model per driver (``device.driver`` picks it), each with only its own keys -----------

def _check_mount(v: list[str] | None) -> list[str] | None:
    """A mounting must be one of the 24 proper rotations: its matrix (mount_p, the one place text becomes
    a matrix) written back as text (conventions.mount_label, the one place a matrix is written)."""
    if v is not None:
        from ..conventions import mount_label

        return mount_label(mount_p(v))
    return v


def _check_board_serial(v: str | int | None) -> str | int | None:
    """A configured board serial follows the one serial rule (serials.py), checked when the config is read."""
    if v is None or not str(v).strip():  # absent or "": the device's own serial
        return v
    from .serials import BOARD_SERIAL_MAX, check_serial

    try:
        check_serial(str(v), "serial")
    except DataError:
        raise ValueError(f"a serial number: 1-{BOARD_SERIAL_MAX} letters, digits and . _ : / -, starting with a "
                         "letter or digit") from None
    return v


def mount_p(v: list[str] | None) -> np.ndarray:
    """P (chip = P @ board) of a validated mounting, the identity when none is given: the one place a
    mount's text becomes its matrix (``device.mount``, a panel board's ``mount``, ``true_mount``)."""
    import numpy

    from ..conventions import mount_matrix

    return mount_matrix(v) if v else numpy.eye(3)


class SimEepromSection(Section):
    """A simulated board's EEPROM (``device.eeprom``, driver: simulated)."""

    size_bytes: int = _f(4096, "EEPROM size, bytes (a multiple of page_bytes)", ge=1, le=2**20)
    page_bytes: int = _f(32, "page size, bytes", ge=1, le=4096)
    write_cycle_ms: float = _f(5.0, "write cycle time, ms", ge=0, le=1000)
    fail_at_write: int | None = _f(None, "fail at this write (power-loss tests)", ge=1, le=2**31)
    image: str | None = _f(None, "keep the EEPROM in this file between commands")


class SimulatedBoardSection(Section):
    """A simulated board's own keys (``device`` with ``driver: simulated``; an emulated chip's
    ``simulator`` board mapping)."""

    chip: str | None = _f(None, "chip (mma8451, mpu6050)")
    range_g: int | None = _f(None, "full scale, g (the chip's: 2, 4, 8 or 16)")
    odr_hz: float | None = _f(None, "output data rate, Hz (one of the chip's rates)", gt=0, le=10_000)
    dlpf: int | None = _f(None, "mpu6050: digital low-pass filter setting", ge=0, le=6)
    seed: int | None = _f(None, "random seed (default: fresh, recorded)", ge=0, le=2**63 - 1)
    serial: str | int | None = _f(None, "board serial number (1-32 letters, digits and . _ : / -)")
    realtime: StrictBool = _f(False, "sleep the wall time as the virtual clock runs")
    ambient_c: float = _f(25.0, "board temperature, C", ge=-60, le=150)
    self_heating_c: float = _f(0.0, "warm-up of the board, C", ge=0, le=50)
    eeprom: SimEepromSection | None = _f(None, "the board's calibration EEPROM")
    simulator: SimulatorSection | str | None = _f(
        None, "the forward sensor model ({effects: ...}) or the path of a simulator YAML file")
    effects: Effects | None = _f(None, "effects (as simulator.effects)")
    true_mount: list[str] | None = _f(None, "how the chip really sits on the board: the chip axes along the "
                                      "board's x, y, z, e.g. [y, -x, z] (default [x, y, z]); the station's belief "
                                      "is device.mount")

    @field_validator("true_mount")
    @classmethod
    def _proper_true_mount(cls, v: list[str] | None) -> list[str] | None:
        return _check_mount(v)

    @field_validator("serial")
    @classmethod
    def _serial_rule(cls, v: str | int | None) -> str | int | None:
        return _check_board_serial(v)

    @property
    def emulated(self) -> bool:
        """A simulated board is not an emulated bus (drivers/registry.py: no ``simulated-emulated``)."""
        return False

    def true_mount_p(self) -> np.ndarray:
        """P of ``true_mount`` (identity when absent): how the chip really sits (mount_p)."""
        return mount_p(self.true_mount)


class I2cEepromSection(Section):
    """An MMA8451 board's 24Cxx EEPROM (``device.eeprom``, driver: mma8451)."""

    address: int = _f(0x50, "EEPROM I2C address", ge=0x50, le=0x57, hexadecimal=True)
    # 24C32 and up: smaller 24Cxx take a 1-byte word address, which the driver does not send
    size: int = _f(4096, "EEPROM size, bytes", ge=4096, le=65536)
    page_size: int = _f(32, "page size, bytes", ge=8, le=256)
    write_cycle_ms: float = _f(5.0, "write cycle time, ms", ge=0.1, le=100)


class Mma8451Section(Section):
    """An MMA8451's own keys (``device`` with ``driver: mma8451``)."""

    bus: int | str = _f(1, "I2C bus number, /dev/i2c-N or 'emulated'")
    address: int = _f(0x1D, "I2C address: 0x1c (SA0 low) or 0x1d (SA0 high)", ge=0, le=0x7F, hexadecimal=True)
    range_g: Literal[2, 4, 8] = _f(2, "full scale, g")
    odr_hz: float = _f(100.0, "output data rate, Hz (one of the chip's rates)", gt=0, le=10_000)
    oversampling: Literal["normal", "low_noise_low_power", "high_resolution", "low_power"] = _f(
        "high_resolution", "oversampling mode")
    retries: int = _f(3, "retries of a bus transaction", ge=0, le=20)
    timeout_s: float = _f(1.0, "transaction timeout, s", ge=0.001, le=60)
    serial: str | int | None = _f(None, "board serial number (1-32 letters, digits and . _ : / -)")
    offset_trim_lsb: list[int] | None = _f(None, "offset registers [x, y, z], whole numbers -128..127")
    eeprom: I2cEepromSection | Literal[False] | None = _f(None, "the board's EEPROM (false: none)")
    simulator: SimulatedBoardSection | str | None = _f(
        None, "bus: emulated: the simulated board (a mapping of simulated-board keys, or a file)")
    seed: int | None = _f(None, "bus: emulated: random seed", ge=0, le=2**63 - 1)
    emulator: BusEmulatorSection | None = _f(None, "bus: emulated: the emulator's faults")

    @field_validator("serial")
    @classmethod
    def _serial_rule(cls, v: str | int | None) -> str | int | None:
        return _check_board_serial(v)

    @property
    def emulated(self) -> bool:
        """``bus: emulated``: built by the registry's ``mma8451-emulated`` (drivers/registry.py)."""
        return self.bus == "emulated"


class Mpu6050Section(Section):
    """An MPU6050 bridge's own keys (``device`` with ``driver: mpu6050``)."""

    port: str | None = _f(None, "serial port of the bridge (or 'emulated'); required")
    baud: int = _f(115200, "serial baud rate", ge=1200, le=4_000_000)
    range_g: Literal[2, 4, 8, 16] = _f(2, "full scale, g")
    odr_hz: float = _f(100.0, "output data rate, Hz", ge=0, le=1000)
    dlpf: int = _f(3, "digital low-pass filter setting", ge=0, le=6)
    timeout_s: float = _f(0.5, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(3, "retries of a serial transaction", ge=0, le=20)
    boot_wait_s: float = _f(2.0, "wait for the bridge to boot, s", ge=0, le=30)
    accept_who_am_i: list[Annotated[int, Field(ge=0, le=255)]] = _f(
        [], "MPU-6050 compatibles to calibrate too, by WHO_AM_I (clones on modules: 0x98, 0x70, 0x72; "
        "docs/station.md); their self-test is skipped")
    simulator: SimulatedBoardSection | str | None = _f(
        None, "port: emulated: the simulated board (a mapping of simulated-board keys, or a file)")
    seed: int | None = _f(None, "port: emulated: random seed", ge=0, le=2**32 - 1)
    emulator: BridgeEmulatorSection | None = _f(None, "port: emulated: the bridge emulator's chip and faults")

    @property
    def emulated(self) -> bool:
        """``port: emulated``: built by the registry's ``mpu6050-emulated`` (drivers/registry.py)."""
        return self.port == "emulated"


class _SlotKeys(Section):
    """What the station adds to a driver's keys: how the chip sits on the board, and a panel board's slot."""

    channel: int | None = _f(None, "panel board: multiplexer channel", ge=0, le=7)
    seated_deg: Annotated[list[float], Field(min_length=3, max_length=3)] | None = _f(
        None, "simulated panel board: how it really sits in its slot, an [x, y, z] rotation vector in degrees")
    mount: list[str] | None = _f(None, "how the chip sits on the board (or the board in the jig): the chip axes "
                                 "along the board's x, y, z, one of the 24 turns, e.g. [y, -x, z] (default [x, y, z]; "
                                 "docs/conventions.md); the station's, never the driver's")

    @field_validator("mount")
    @classmethod
    def _proper_mount(cls, v: list[str] | None) -> list[str] | None:
        return _check_mount(v)

    def mount_p(self) -> np.ndarray:
        """P of ``mount`` (identity when absent): how the station believes the chip sits (mount_p)."""
        return mount_p(self.mount)


class _PanelKeys(Section):
    """What a panel adds to a board's keys (``boards`` itself is declared per driver)."""

    spread: SpreadSection | None = _f(None, "panel, simulated or emulated: per-board spread of offset and gain")


class _SimulatedDriver(Section):
    driver: Literal["simulated"] = _f("simulated", "the driver: simulated")


class _Mma8451Driver(Section):
    driver: Literal["mma8451"] = _f(..., "the driver: mma8451")


class _Mpu6050Driver(Section):
    driver: Literal["mpu6050"] = _f(..., "the driver: mpu6050")


_BOARDS = f"panel: a count 1..{MAX_BOARDS} or a list of per-board mappings (these keys, overriding the panel's)"


class SimulatedPanelBoard(_SlotKeys, SimulatedBoardSection, _SimulatedDriver):
    """A simulated board of a panel (``device.boards[i]``, driver: simulated)."""


class SimulatedDevice(_PanelKeys, SimulatedPanelBoard):
    """``device`` with ``driver: simulated``: a simulated board (or panel of them)."""

    boards: int | list[SimulatedPanelBoard] | None = _f(None, _BOARDS)


class Mma8451PanelBoard(_SlotKeys, Mma8451Section, _Mma8451Driver):
    """An MMA8451 board of a panel (``device.boards[i]``, driver: mma8451)."""

    driver: Literal["mma8451"] = _f("mma8451", "the driver: mma8451")


class Mma8451Device(_PanelKeys, Mma8451PanelBoard):
    """``device`` with ``driver: mma8451``: an I2C board (or panel of them)."""

    driver: Literal["mma8451"] = _f(..., "the driver: mma8451")
    mux: MuxSection | None = _f(None, "panel on one I2C bus: a TCA9548A multiplexer")
    boards: int | list[Mma8451PanelBoard] | None = _f(None, _BOARDS)


class Mpu6050PanelBoard(_SlotKeys, Mpu6050Section, _Mpu6050Driver):
    """An MPU6050 bridge of a panel (``device.boards[i]``, driver: mpu6050)."""

    driver: Literal["mpu6050"] = _f("mpu6050", "the driver: mpu6050")


class Mpu6050Device(_PanelKeys, Mpu6050PanelBoard):
    """``device`` with ``driver: mpu6050``: a serial bridge (or panel of them)."""

    driver: Literal["mpu6050"] = _f(..., "the driver: mpu6050")
    boards: int | list[Mpu6050PanelBoard] | None = _f(None, _BOARDS)


DeviceSection = SimulatedDevice | Mma8451Device | Mpu6050Device
"""A validated ``device`` section: one driver's model (the built-in drivers' for typing; the schema's union
is the registry's, config/driver_models.py)."""
BUILT_IN_DEVICES: dict[str, type[Section]] = {"simulated": SimulatedDevice, "mma8451": Mma8451Device,
                                              "mpu6050": Mpu6050Device}


class DeviceKeys(_PanelKeys, _SlotKeys):
    """The base of a new chip's ``device`` model (docs/drivers.md, "Adding a chip"): what the station adds to
    a driver's own keys (``mount``, a panel's ``spread``, ...). The model declares ``driver:
    Literal["NAME"]`` (its entry point's name), its own keys and ``boards``; the built-in models carry the
    same keys through their panel-board bases."""

    @property
    def emulated(self) -> bool:
        """An emulated bus or port (the registry's ``NAME-emulated`` entry builds it): none by default."""
        return False


def _tag(key: str, default: str) -> Any:
    """The discriminator on ``key``: its value picks the model (``default`` when absent; a value
    that is not a mapping goes to the default model, which says 'allowed: a mapping')."""
    def pick(v: Any) -> str:
        got = v.get(key, default) if isinstance(v, dict) else getattr(v, key, default)
        return f"{key}={got}" if isinstance(got, str) else f"{key}=?"
    return pick


def _discriminator(key: str, default: str, models: dict[str, type[Section]],
                   pick: Callable[[Any], str] | None = None, union: str | None = None) -> Discriminator:
    """The discriminator of a union of ``models`` on ``key`` (a bad value: one line naming the values
    allowed); each member is tagged ``key=value`` (TAGGED: error paths find the member by it).
    ``pick``: the tag of a value, when more than ``key`` (or ``default``) decides it; ``union``: the
    union's name when another union discriminates on the same key (jig.type, chamber.type)."""
    TAGGED.update({f"{key}={tag}": m for tag, m in models.items()})
    CHOICES[union or key] = (key, tuple(models))
    return Discriminator(pick or _tag(key, default), custom_error_type=f"{union or key}_choice",
                         custom_error_message=f"unknown {key}")


TAGGED: dict[str, type[Section]] = {}  # "driver=mma8451" -> its model
CHOICES: dict[str, tuple[str, tuple[str, ...]]] = {}  # a union -> its discriminating key, the values it may take


# --- the jig: one model per type (``jig.type`` picks it) ----------------------------------------------

class SimulatedJigSection(Section):
    """A simulated jig's own keys (``jig`` with ``type: simulated``)."""

    rated_speed_dps: float = _f(100.0, "rated turning speed, deg/s: a move takes settle_s + angle / this "
                                "(docs/timing.md; 180 deg in 2.0 s with the defaults)", gt=0, le=10000)
    settle_s: float = _f(0.2, "settle time after each move, s", ge=0, le=60)
    move_time_s: float | None = _f(None, "a fixed time for every move instead, s (0: moves take no time)",
                                   ge=0, le=120)
    angle_tolerance_deg: float = _f(0.1, "each pose within +- this of its commanded attitude, deg (the uncertainty "
                                    "budget's jig_angle, docs/uncertainty.md; a machined fixture's)", ge=0, le=10)


class OperatorJigSection(Section):
    """An operator jig's own keys (``jig`` with ``type: operator``)."""

    tolerance_deg: float = _f(12.0, "pose tolerance, deg", ge=1, le=45)
    angle_tolerance_deg: float = _f(0.5, "each pose within +- this of its commanded attitude, deg (the uncertainty "
                                    "budget's jig_angle, docs/uncertainty.md; a board seated by hand in a "
                                    "fixture's pocket)", ge=0, le=10)
    hand: HandSection | Literal[True] | None = _f(None, "a simulated hand instead of a person (CI); true for the "
                                                  "default hand")


class MotorizedJigSection(Section):
    """A motorized jig's own keys (``jig`` with ``type: motorized``)."""

    port: str | None = _f(None, "serial port (or 'emulated'); required")
    baud: int = _f(115200, "serial baud rate", ge=300, le=4_000_000)
    timeout_s: float = _f(0.5, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(2, "retries of a command", ge=0, le=10)
    speed_deg_s: float | None = _f(None, "axis speed, deg/s (default: the controller's)", ge=1e-6, le=1e4)
    accel_deg_s2: float | None = _f(None, "axis acceleration, deg/s^2 (default: the controller's)", ge=1e-6,
                                    le=1e6)
    home_on_open: StrictBool = _f(True, "home the axes when the port opens")
    tolerance_deg: float = _f(0.02, "position tolerance, deg", ge=1e-4, le=5)
    angle_tolerance_deg: float = _f(0.05, "each pose within +- this of its commanded attitude, deg (the "
                                    "uncertainty budget's jig_angle, docs/uncertainty.md: axes, levelling and "
                                    "the board's seat)", ge=0, le=10)
    move_margin_s: float = _f(2.0, "extra time allowed for a move, s", ge=0, le=600)
    settle_s: float = _f(0.0, "wait after a move, s", ge=0, le=60)
    poll_s: float = _f(0.01, "status poll interval, s", ge=0.001, le=5)
    axis_sign: Annotated[list[Literal[1, -1]], Field(min_length=2, max_length=2)] = _f(
        [1, 1], "sign of each axis [pitch, roll]: 1 or -1")
    axis_offset_deg: Annotated[list[float], Field(min_length=2, max_length=2)] = _f(
        [0.0, 0.0], "zero offset of each axis [pitch, roll], deg")


class _SimulatedType(Section):
    type: Literal["simulated"] = _f("simulated", "the jig type: simulated")


class _OperatorType(Section):
    type: Literal["operator"] = _f(..., "the jig type: operator")


class _MotorizedType(Section):
    type: Literal["motorized"] = _f(..., "the jig type: motorized")


class SimulatedJigConfig(SimulatedJigSection, _SimulatedType):
    """``jig`` with ``type: simulated``."""


class OperatorJigConfig(OperatorJigSection, _OperatorType):
    """``jig`` with ``type: operator``."""


class MotorizedJigConfig(MotorizedJigSection, _MotorizedType):
    """``jig`` with ``type: motorized``."""


JigSection = SimulatedJigConfig | OperatorJigConfig | MotorizedJigConfig
"""A validated ``jig`` section: one jig type's model."""
JIG_MODELS: dict[str, type[Section]] = {"simulated": SimulatedJigConfig, "operator": OperatorJigConfig,
                                        "motorized": MotorizedJigConfig}
Jig = Annotated[
    Annotated[SimulatedJigConfig, Tag("type=simulated")] | Annotated[OperatorJigConfig, Tag("type=operator")]
    | Annotated[MotorizedJigConfig, Tag("type=motorized")],
    _discriminator("type", "simulated", JIG_MODELS)]
"""The ``jig`` field: one validation picks the jig type's model and checks its keys."""

"""The station configuration's declared schema: every section and key, its type, range,
default and meaning, in one place (pydantic v2 models).

``validate_station`` checks a whole config before any section is used: an unknown key in
any section, a wrong type, a number that is not finite or out of its range gives one line
(key path, value, what is allowed).  The sections' own code keeps the checks that depend
on other keys (a driver's own keys, k_leave >= k_enter, ...).  docs/config.md is generated
from these models (``python -m accelcal_station.config.docs``).
"""
from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, field_validator

from .validation import error_line, given, validate  # noqa: F401  (the schema's public names)

MAX_BOARDS = 64


# three numbers [x, y, z] (YAML gives a list; a strict tuple would refuse it)
Triple = Annotated[list[Annotated[float, Field(ge=0, le=1e6)]], Field(min_length=3, max_length=3)]


class Section(BaseModel):
    """A config section: unknown keys refused, numbers finite."""

    # strict: a quoted "5" or YAML 1.1's 1e300 (a string: no dot) is not taken for a number
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _f(default: Any, desc: str, ge: float | None = None, le: float | None = None, gt: float | None = None) -> Any:
    return Field(default, description=desc, ge=ge, le=le, gt=gt)


class StationSection(Section):
    id: str = _f("station-1", "station id recorded with every run")
    scan_serial: StrictBool = _f(False, "ask the operator to scan each board's serial")
    require_operator: StrictBool = _f(False, "refuse to run without --operator")
    language: Literal["en", "de"] = _f("en", "the operator's language: terminal prompts, the operator page and the "
                                       "verdict reasons shown to operators (--json and logs stay English)")


class StoreSection(Section):
    path: str = _f("accelcal-runs.sqlite", "results store: a SQLite file (relative to the current directory) "
                   "or a postgresql:// URL")
    outbox: str | None = _f(None, "local SQLite file keeping runs while a postgresql:// store is unreachable "
                            "(replayed by the next run or `accelcal report sync`); default "
                            "$XDG_STATE_HOME/accelcal/outbox.sqlite")


class PlanSection(Section):
    design: str = _f("an4399-8", "pose design (accelcal poses NAME shows it)")
    model: Literal[6, 9, 12, 15, "6", "9", "12", "15"] = _f(12, "calibration model: 6, 9, 12 or 15 parameters")


class CaptureSection(Section):
    block_s: float = _f(0.1, "length of one stillness block, s", gt=0, le=60)
    k_enter: float = _f(4.5, "still: block std and mean change within k_enter x the noise floor", ge=0, le=1000)
    k_leave: float = _f(7.0, "moving again beyond k_leave x the floor (hysteresis; >= k_enter)", ge=0, le=1000)
    hold_s: float = _f(0.3, "the board must be still this long before averaging starts, s", ge=0, le=600)
    target_sem_mg: float = _f(0.05, "stop averaging when every axis's standard error is below this, mg",
                              ge=0, le=1000)
    min_samples: int = _f(32, "fewest samples averaged per pose", gt=0, le=10_000_000)
    max_s: float = _f(20.0, "longest averaging per pose, s", gt=0, le=86_400)
    settle_timeout_s: float = _f(30.0, "longest wait for the board to be still, s", gt=0, le=86_400)
    pose_tolerance_deg: float = _f(12.0, "measured gravity direction vs the planned pose, deg", ge=0, le=180)
    max_recaptures: int = _f(3, "captures repeated when the board moved during one", ge=0, le=100)
    self_test_samples: int = _f(64, "samples averaged in each self-test state (self-test off, on)", ge=4, le=1024)


class AcceptanceSection(Section):
    """PASS only if every limit given holds (acceptance/rules.py); crossval_rms_mg defaults to 10."""

    residual_rms_mg: float | None = _f(None, "RMS of per-pose per-axis residuals, mg", ge=0, le=1e6)
    residual_max_mg: float | None = _f(None, "largest per-pose per-axis residual, mg", ge=0, le=1e6)
    crossval_rms_mg: float | None = _f(None, "held-out RMS, mg: leave-one-orientation-out where orientations "
                                             "repeat, else leave-one-pose-out", ge=0, le=1e6)
    gain_error_max: float | None = _f(None, "largest |W_ii - 1| (W maps reading in g to g), fraction", ge=0, le=100)
    cross_axis_max: float | None = _f(None, "largest |W_ij|, i != j, fraction", ge=0, le=100)
    offset_max_mg: float | None = _f(None, "largest |V_i|, mg", ge=0, le=1e6)
    cubic_max: float | None = _f(None, "largest |Gamma_ii|, 1/g^2", ge=0, le=1e6)
    stderr_offset_max_mg: float | None = _f(None, "largest standard error of V, mg", ge=0, le=1e6)
    stderr_gain_max: float | None = _f(None, "largest standard error of W, fraction", ge=0, le=100)
    verify_error_max_mg: float | None = _f(None, "closed-loop verification: largest |calibrated - expected|, mg",
                                           ge=0, le=1e6)
    self_test: StrictBool = _f(True, "run the chip's built-in self-test before the poses when the driver has one "
                                     "(docs/self-test.md); a board that fails it is not calibrated nor burned")
    self_test_low_g: Triple | None = _f(
        None, "mma8451: smallest self-test output change per axis [x, y, z], g (default: the data sheet's)")
    self_test_high_g: Triple | None = _f(
        None, "mma8451: largest self-test output change per axis [x, y, z], g (default: the data sheet's)")
    self_test_tolerance: float | None = _f(
        None, "mpu6050: largest |(STR - FT) / FT|, fraction (default: the data sheet's 0.14)", gt=0, le=10)
    offset_trim_tolerance: float = _f(
        0.25, "nvm.offset_trim: largest |measured - expected| trim change as a fraction of the expected change "
        "(or 4 standard errors, whichever is larger); beyond it: FAIL offset_trim", gt=0, le=1)


class NvmSection(Section):
    write: StrictBool = _f(True, "burn the calibration to the board's EEPROM (A/B slots, CRC-32)")
    slot_size: int | None = _f(None, "bytes per calibration slot (default: the blob's size)", ge=64, le=65536)
    offset_trim: StrictBool = _f(False, "also move the offset into the chip's offset registers (not model 15)")


class VerifySection(Section):
    poses: int = _f(3, "poses re-measured with the calibration applied (0: none)", ge=0, le=64)
    design: str | None = _f(None, "pose design to verify on (default: the plan's)")


class HandSection(Section):
    """A simulated operator's hand (operator jig in CI)."""

    wrong_face: list[str | int] = _f([], "poses (names or 1-based numbers) first presented on a wrong face")
    bump: list[str | int] = _f([], "poses (names or 1-based numbers) bumped during the capture")
    bump_after_s: float = _f(1.5, "bump this long into the capture, s", ge=0, le=60)
    bump_s: float = _f(0.5, "bump length, s", ge=0.01, le=10)
    bump_deg: float = _f(15.0, "bump tilt, deg", ge=0.1, le=90)
    move_time_s: float = _f(2.0, "time the hand takes between poses, s", ge=0, le=60)


class JigSection(Section):
    type: Literal["simulated", "operator", "motorized"] = _f("simulated", "simulated | operator | motorized")
    move_time_s: float = _f(2.0, "simulated: time between poses on the virtual clock, s", ge=0, le=120)
    tolerance_deg: float | None = _f(None, "operator: pose tolerance, deg (12); motorized: position "
                                     "tolerance, deg (0.02)", ge=1e-4, le=45)
    hand: HandSection | Literal[True] | None = _f(None, "operator: a simulated hand instead of a person (CI); "
                                                  "true for the default hand")
    port: str | None = _f(None, "motorized: serial port (or 'emulated')")
    baud: int = _f(115200, "motorized: serial baud rate", ge=300, le=4_000_000)
    timeout_s: float = _f(0.5, "motorized: reply timeout, s", ge=0.01, le=60)
    retries: int = _f(2, "motorized: retries of a command", ge=0, le=10)
    speed_deg_s: float | None = _f(None, "motorized: axis speed, deg/s", gt=0, le=1e4)
    accel_deg_s2: float | None = _f(None, "motorized: axis acceleration, deg/s^2", gt=0, le=1e6)
    home_on_open: StrictBool = _f(True, "motorized: home the axes when the port opens")
    move_margin_s: float = _f(2.0, "motorized: extra time allowed for a move, s", ge=0, le=600)
    settle_s: float = _f(0.0, "motorized: wait after a move, s", ge=0, le=60)
    poll_s: float = _f(0.01, "motorized: status poll interval, s", ge=0.001, le=5)
    axis_sign: list[int] | None = _f(None, "motorized: sign of each axis [pitch, roll]")
    axis_offset_deg: list[float] | None = _f(None, "motorized: zero offset of each axis [pitch, roll], deg")


class EepromSection(Section):
    size_bytes: int = _f(4096, "simulated: EEPROM size, bytes", ge=1, le=2**20)
    page_bytes: int = _f(32, "simulated: page size, bytes", ge=1, le=4096)
    write_cycle_ms: float = _f(5.0, "write cycle time, ms", ge=0, le=1000)
    fail_at_write: int | None = _f(None, "simulated: fail at this write (power-loss tests)", ge=1, le=2**31)
    image: str | None = _f(None, "simulated: keep the EEPROM in this file between commands")
    address: int = _f(0x50, "mma8451: EEPROM I2C address", ge=0x50, le=0x57)
    size: int = _f(4096, "mma8451: EEPROM size, bytes", ge=4096, le=65536)
    page_size: int = _f(32, "mma8451: page size, bytes", ge=8, le=256)


class SimulatorSection(Section):
    effects: dict[str, dict[str, Any] | None] | None = _f(
        None, "effects of the catalog (sim/sensor_model.py EFFECTS), each with its parameters")
    population: dict[str, Any] | None = _f(
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
    address: int = _f(0x50, "I2C address whose reads are corrupted (the EEPROM's)", ge=0, le=0x7F)


class BusEmulatorSection(Section):
    """mma8451 ``bus: emulated``: the register-level emulator's faults."""

    chip_id: int = _f(0x1A, "WHO_AM_I value the emulated chip answers", ge=0, le=255)
    nack_every: int = _f(0, "NACK every Nth bus transaction (0: never)", ge=0, le=1000)
    never_ready: StrictBool = _f(False, "the data-ready flag never sets")
    present: StrictBool = _f(True, "the chip answers on the bus at all")
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


class EmulatorSection(BusEmulatorSection, BridgeEmulatorSection):
    """``device.emulator``: every emulated chip's keys; each driver takes its own (check_kinds: mma8451
    BusEmulatorSection, mpu6050 BridgeEmulatorSection)."""


class MuxSection(Section):
    address: int = _f(0x70, "TCA9548A I2C address", ge=0x70, le=0x77)


class SpreadSection(Section):
    offset_mg: float = _f(0.0, "panel: per-board offset spread (standard deviation), mg", ge=0, le=1000)
    gain: float = _f(0.0, "panel: per-board gain spread (standard deviation), fraction", ge=0, le=0.5)


def _check_mount(v: list[str] | None) -> list[str] | None:
    """A mounting must be one of the 24 proper rotations (conventions.mount_matrix)."""
    if v is not None:
        from ..conventions import mount_label, mount_matrix

        return mount_label(mount_matrix(v))
    return v


class DeviceSection(Section):
    """The board's driver and its settings (each driver accepts its own keys, named below)."""

    driver: Literal["simulated", "mma8451", "mpu6050"] = _f("simulated", "simulated | mma8451 | mpu6050")
    chip: str | None = _f(None, "simulated: chip (mma8451, mpu6050)")
    range_g: Literal[2, 4, 8, 16] = _f(2, "full scale, g")
    odr_hz: float | None = _f(None, "output data rate, Hz", gt=0, le=10_000)
    dlpf: int | None = _f(None, "simulated/mpu6050: digital low-pass filter setting", ge=0, le=6)
    seed: int | None = _f(None, "simulated/emulated: random seed (default: fresh, recorded)", ge=0, le=2**63 - 1)
    serial: str | None = _f(None, "board serial number")
    realtime: StrictBool = _f(False, "simulated: sleep the wall time as the virtual clock runs")
    ambient_c: float = _f(25.0, "simulated: board temperature, C", ge=-60, le=150)
    self_heating_c: float = _f(0.0, "simulated: warm-up of the board, C", ge=0, le=50)
    eeprom: EepromSection | None = _f(None, "the board's calibration EEPROM")
    simulator: SimulatorSection | DeviceSection | str | None = _f(
        None, "simulated: the forward sensor model ({effects: ...}); emulated mpu6050: a board mapping "
        "(these keys) or the path of a simulator YAML file")
    effects: dict[str, dict[str, Any] | None] | None = _f(None, "simulated: effects (as simulator.effects)")
    bus: int | str | None = _f(None, "mma8451: I2C bus number, /dev/i2c-N or 'emulated'")
    address: int | None = _f(None, "mma8451: I2C address (0x1c or 0x1d)", ge=0, le=0x7F)
    oversampling: str | None = _f(None, "mma8451: oversampling mode")
    retries: int | None = _f(None, "mma8451/mpu6050: retries of a bus or serial transaction", ge=0, le=20)
    timeout_s: float | None = _f(None, "mma8451/mpu6050: transaction timeout, s", ge=0.001, le=60)
    offset_trim_lsb: list[int] | None = _f(None, "mma8451: offset registers [x, y, z], whole numbers -128..127")
    emulator: EmulatorSection | None = _f(
        None, "emulated chips' faults: mma8451 bus: emulated (the register emulator's), mpu6050 port: emulated "
        "(the bridge emulator's)")
    port: str | None = _f(None, "mpu6050: serial port of the bridge (or 'emulated')")
    baud: int | None = _f(None, "mpu6050: serial baud rate", ge=1200, le=4_000_000)
    boot_wait_s: float | None = _f(None, "mpu6050: wait for the bridge to boot, s", ge=0, le=30)
    boards: int | list[DeviceSection] | None = _f(None, f"panel: a count 1..{MAX_BOARDS} or a list of "
                                                  "per-board device mappings (these keys, overriding the panel's)")
    spread: SpreadSection | None = _f(None, "panel, simulated: per-board spread of offset and gain")
    mux: MuxSection | None = _f(None, "panel on one I2C bus: a TCA9548A multiplexer")
    channel: int | None = _f(None, "panel board: multiplexer channel", ge=0, le=7)
    seated_deg: list[float] | None = _f(None, "simulated panel board: how it really sits in its slot, an [x, y, z] "
                                        "rotation vector in degrees")
    mount: list[str] | None = _f(None, "how the chip sits on the board (or the board in the jig): the chip axes "
                                 "along the board's x, y, z, one of the 24 turns, e.g. [y, -x, z] (default [x, y, z]; "
                                 "docs/conventions.md)")
    true_mount: list[str] | None = _f(None, "simulated/emulated board: how its chip really sits on the board, as "
                                      "mount (default [x, y, z]); the station's belief is mount")

    @field_validator("mount", "true_mount")
    @classmethod
    def _proper_turn(cls, v: list[str] | None) -> list[str] | None:
        return _check_mount(v)


class SoakSection(Section):
    tolerance_c: float = _f(0.2, "board temperature stable within this, C", ge=0.001, le=10)
    band_c: float = _f(2.0, "board within this of the set point, C", ge=0.01, le=20)
    hold_s: float = _f(300.0, "stable for this long, s", ge=0, le=86_400)
    timeout_s: float = _f(5400.0, "give up soaking after this long, s", ge=1, le=604_800)
    poll_s: float = _f(10.0, "temperature poll interval, s", ge=0.01, le=3600)


TempC = Annotated[float, Field(ge=-70, le=180)]


class ThermalSection(Section):
    set_points_c: list[TempC] = _f(..., "calibration temperatures, C (-70 to 180 each; 3 or more, 5 C apart)")
    verify_set_points_c: list[TempC] = _f(..., "verification temperatures not used in the fit, C (between the "
                                          "calibration set points, 2.5 C or more from each)")
    method: Literal["linear", "quadratic"] = _f("linear", "interpolation of every parameter in temperature")
    soak: SoakSection | None = _f(None, "when a set point is reached")
    capture_band_c: float = _f(1.0, "board temperature during a capture within this of the set point, C",
                               ge=0.01, le=20)
    reference_c: float = _f(25.0, "temperature of the reported single calibration, C", ge=-70, le=180)


class ChamberFaultsSection(Section):
    min_air_c: float = _f(-75.0, "coldest air the emulated chamber reaches, C", ge=-100, le=200)
    max_air_c: float = _f(180.0, "hottest air, C", ge=-100, le=300)
    alarm_at_s: float | None = _f(None, "raise an alarm at this time, s", ge=0, le=1e7)
    alarm_code: int = _f(3, "alarm code raised", ge=1, le=99)
    door_open_at_s: float | None = _f(None, "open the door at this time, s", ge=0, le=1e7)
    door_open_s: float = _f(60.0, "door open this long, s", ge=0, le=1e5)
    stall_at_s: float | None = _f(None, "stop answering at this time, s", ge=0, le=1e7)


class ChamberEmulatorSection(Section):
    start_c: float = _f(25.0, "air and board temperature at start, C", ge=-70, le=150)
    room_c: float = _f(25.0, "room temperature, C", ge=-20, le=50)
    air_tau_s: float = _f(180.0, "air time constant, s", ge=1, le=1e5)
    board_tau_s: float = _f(300.0, "board time constant, s", ge=1, le=1e5)
    door_tau_s: float = _f(60.0, "time constant with the door open, s", ge=1, le=1e5)
    faults: ChamberFaultsSection | None = _f(None, "faults injected into the emulated chamber")


class ChamberSection(Section):
    driver: Literal["ascii"] = _f("ascii", "chamber protocol (docs/chamber-protocol.md)")
    port: str | None = _f(None, "serial port, or 'emulated'")
    baud: int = _f(9600, "serial baud rate", ge=300, le=1_000_000)
    timeout_s: float = _f(1.0, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(2, "retries of a command", ge=0, le=10)
    min_c: float = _f(-70.0, "lowest set point allowed, C", ge=-100, le=200)
    max_c: float = _f(180.0, "highest set point allowed, C", ge=-100, le=300)
    emulator: ChamberEmulatorSection | None = _f(None, "the emulated chamber's physics and faults")
    visa_library: str = Field("@py", min_length=1, description=(
        "the VISA backend pyvisa opens the port through: @py (pyvisa-py, the default), @ivi (an "
        "installed IVI VISA such as NI-VISA or Keysight IO), @sim (pyvisa-sim), or a vendor VISA library's path"))


class WebSection(Section):
    """``accelcal serve`` and ``accelcal run --ui web``."""

    token: str | None = _f(None, "shared secret that starting or aborting a run over the web API needs: "
                           "16-200 printable characters, no spaces")
    read_token: str | None = _f(None, "shared secret every read of `accelcal serve` needs (sent as "
                                "'Authorization: Bearer TOKEN'); required to listen beyond localhost "
                                "unless --public: 16-200 printable characters, no spaces")


class LoggingSection(Section):
    """The station's event log (docs/logging.md)."""

    level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = _f(
        "INFO", "least severe event logged: INFO (runs, burns, retries), WARNING (outbox), ERROR (lost ports, "
        "failed burns)")
    file: str | None = _f(None, "append the events to this file (relative to the current directory; a regular "
                          "file, never through a symlink); default: stderr")


class StationConfigSchema(Section):
    """A station configuration file (configs/*.yaml)."""

    station: StationSection | None = _f(None, "the station's identity and operator rules")
    store: StoreSection | None = _f(None, "where runs are recorded")
    device: DeviceSection = _f(..., "the board (or panel of boards) and its driver")
    jig: JigSection | None = _f(None, "the fixture that holds the board")
    plan: PlanSection | None = _f(None, "pose design and model")
    capture: CaptureSection | None = _f(None, "stillness gating and averaging at each pose")
    acceptance: AcceptanceSection | None = _f(None, "limits for PASS")
    nvm: NvmSection | None = _f(None, "burning the calibration")
    verify: VerifySection | None = _f(None, "closed-loop verification after the burn")
    thermal: ThermalSection | None = _f(None, "a thermal plan: a calibration at each set point")
    chamber: ChamberSection | None = _f(None, "the thermal chamber (thermal plans)")
    web: WebSection | None = _f(None, "the web pages and API (accelcal serve, accelcal run --ui web)")
    logging: LoggingSection | None = _f(None, "the station's event log: port losses, retries, burns, outbox")


def validate_station(raw: dict[str, Any]) -> StationConfigSchema:
    """A whole station config against the schema (ConfigError: one line)."""
    return validate(raw, StationConfigSchema)  # type: ignore[return-value]

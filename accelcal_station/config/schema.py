"""The station configuration's declared schema: every section and key, its type, range,
default and meaning, in one place (pydantic v2 models).

``validate_station`` checks a whole config before any section is used: an unknown key in
any section, a wrong type, a number that is not finite or out of its range gives one line
(key path, value, what is allowed).  ``device`` and ``jig`` are discriminated unions on
``driver`` and ``type`` (kinds.py): the same validation checks each driver's and jig type's own
keys.  The sections' own code keeps the checks that depend on other keys (k_leave >= k_enter,
an MMA8451's address among its two, ...).  docs/config.md is generated
from these models (``python -m accelcal_station.config.docs``).
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import Field, StrictBool, Tag

from ..errors import ConfigError
from .driver_models import device_models
from .kinds import (  # noqa: F401 - re-exported: every section model is reachable from the schema
    BUILT_IN_DEVICES,
    CHOICES,
    JIG_MODELS,
    TAGGED,
    BridgeEmulatorSection,
    BusEmulatorSection,
    CorruptReadsSection,
    DeviceKeys,
    DeviceSection,
    HandSection,
    I2cEepromSection,
    Jig,
    JigSection,
    Mma8451Device,
    Mma8451PanelBoard,
    Mma8451Section,
    MotorizedJigConfig,
    MotorizedJigSection,
    Mpu6050Device,
    Mpu6050PanelBoard,
    Mpu6050Section,
    MuxSection,
    OperatorJigConfig,
    OperatorJigSection,
    SimEepromSection,
    SimulatedBoardSection,
    SimulatedDevice,
    SimulatedJigConfig,
    SimulatedJigSection,
    SimulatedPanelBoard,
    SimulatorSection,
    SpreadSection,
    _check_mount,
    _discriminator,
)
from .section import MAX_BOARDS, Section, Triple, _f  # noqa: F401
from .site_section import SiteSection
from .validation import _models_in, _range, error_line, validate  # noqa: F401 (the schema's public names)

DEVICE_MODELS: dict[str, type[Section]] = device_models()
"""``device.driver`` -> its model: every ``accelcal.drivers`` entry point's declared model (driver_models.py)."""
if TYPE_CHECKING:
    Device = DeviceSection
else:
    Device = Annotated[Union[tuple(Annotated[m, Tag(f"driver={n}")] for n, m in DEVICE_MODELS.items())],  # noqa: UP007
                       _discriminator("driver", "simulated", DEVICE_MODELS)]
"""The ``device`` field: one validation picks the registered driver's model and checks its keys."""


class StationSection(Section):
    id: str = _f("station-1", "station id recorded with every run")
    scan_serial: StrictBool = _f(False, "ask the operator to scan each board's serial")
    require_operator: StrictBool = _f(False, "refuse to run without --operator")
    language: Literal["en", "de"] = _f("en", "the operator's language: terminal prompts, the operator page and the "
                                       "verdict reasons shown to operators (--json and logs stay English)")
    site: SiteSection | None = _f(None, "where the station stands: its gravity, measured or WGS84 normal gravity "
                                  "(docs/uncertainty.md); default: standard gravity 9.80665 m/s^2")


class StoreSection(Section):
    path: str = _f("accelcal-runs.sqlite", "results store: a SQLite file (relative to the current directory) "
                   "or a postgresql:// URL")
    outbox: str | None = _f(None, "local SQLite file keeping runs while a postgresql:// store is unreachable "
                            "(replayed by the next run or `accelcal report sync`); default "
                            "$XDG_STATE_HOME/accelcal/outbox.sqlite")
    heartbeat_s: float = _f(30.0, "seconds between a running run's heartbeats; a run silent for 10 of them "
                            "reads stale on every host (docs/store.md)", ge=0.1, le=3600)


class PlanSection(Section):
    design: str = _f("an4399-8", "pose design (accelcal poses NAME shows it)")
    model: Literal[6, 9, 12, 15, "6", "9", "12", "15"] = _f(12, "calibration model: 6, 9, 12 or 15 parameters")


class WarmupSection(Section):
    """Hold a freshly powered board until its offset has settled (docs/warm-up.md)."""

    mode: Literal["settled", "time"] = _f("settled", "settled: until the drift over a window is below drift_limit_mg "
                                          "(at most max_s); time: hold for time_s")
    time_s: float = _f(120.0, "mode time: how long to hold, s", ge=0, le=86_400)
    window_s: float = _f(10.0, "mode settled: the window whose mean is compared with the previous one, s",
                         gt=0, le=3600)
    drift_limit_mg: float = _f(0.1, "mode settled: largest change of the window mean on any axis, mg", gt=0, le=1000)
    max_s: float = _f(900.0, "mode settled: the longest hold; a board not settled by then is run anyway "
                      "(recorded)", gt=0, le=86_400)


class CaptureSection(Section):
    block_s: float = _f(0.1, "length of one stillness block, s", gt=0, le=60)
    k_enter: float = _f(4.5, "still: block std and mean change within k_enter x the noise floor", ge=0, le=1000)
    k_leave: float = _f(7.0, "moving again beyond k_leave x the floor (hysteresis; >= k_enter)", ge=0, le=1000)
    hold_s: float = _f(0.3, "the board must be still this long before averaging starts, s", ge=0, le=600)
    target_sem_mg: float | None = _f(None, "per-pose standard error std / sqrt(n_eff) per axis, mg (n_eff = n / "
                                     "tau_int): alone without parameter targets (compat), else a floor every "
                                     "pose must also reach; captures outside the design use it (0.05 if unset)",
                                     ge=0, le=1000)
    target_offset_u_mg: float | None = _f(0.018, "sequential capture: standard uncertainty the fitted offsets "
                                          "must reach, mg (docs/capture.md)", gt=0, le=1000)
    target_gain_u: float | None = _f(1e-4, "sequential capture: standard uncertainty the fitted gains must "
                                     "reach, a fraction (1e-4 = 100 ppm)", gt=0, le=1)
    min_samples: int = _f(32, "fewest samples averaged per pose", gt=0, le=10_000_000)
    max_s: float = _f(20.0, "longest averaging per pose, s", gt=0, le=86_400)
    settle_timeout_s: float = _f(30.0, "longest wait for the board to be still, s", gt=0, le=86_400)
    pose_tolerance_deg: float = _f(12.0, "measured gravity direction vs the planned pose, deg", ge=0, le=180)
    max_recaptures: int = _f(3, "captures repeated when the board moved during one", ge=0, le=100)
    self_test_samples: int = _f(64, "samples averaged in each self-test state (self-test off, on)", ge=4, le=1024)
    warmup: WarmupSection | None = _f(None, "hold the board after power-up until its offset settles "
                                      "(absent: no hold)")
    powered_ahead_s: float = _f(60.0, "how long each board has been powered when it is placed, s: a line powers "
                                "the next boards while the previous one is measured (docs/warm-up.md); the "
                                "simulated board's warm-up clock starts this long before its run; 0: powered "
                                "at placement", ge=0, le=86_400)


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
    decision_rule: Literal["simple", "guarded"] = _f(
        "guarded", "guarded: a limit on V or W holds only inside the limit by the expanded uncertainty U "
        "(ILAC-G8, ISO 14253-1); simple: up to the limit, a board within U of it passes with a warning "
        "(docs/uncertainty.md)")
    offset_trim_tolerance: float = _f(
        0.25, "nvm.offset_trim: largest |measured - expected| trim change as a fraction of the expected change "
        "(or 4 standard errors, whichever is larger); beyond it: FAIL offset_trim", gt=0, le=1)


class NvmSection(Section):
    write: StrictBool = _f(True, "burn the calibration to the board's EEPROM (A/B slots, CRC-32)")
    slot_size: int | None = _f(None, "bytes per calibration slot (default: the blob's size)", ge=64, le=65536)
    offset_trim: StrictBool = _f(False, "also move the offset into the chip's offset registers (not model 15)")


class VerifySection(Section):
    poses: int = _f(3, "poses re-measured with the calibration applied (0: none)", ge=0, le=64)
    mode: Literal["fit-poses", "independent"] = _f(
        "fit-poses", "fit-poses: fresh captures at the last fit poses, the first where the jig stands (no move); "
        "independent: the design's (or verify.design's) own poses, each presented (docs/capture.md)")
    design: str | None = _f(None, "pose design to verify on (default: the plan's)")
    target_sem_mg: float | None = _f(None, "averaging target of a verification pose, mg (default: capture."
                                     "target_sem_mg; docs/timing.md)", gt=0, le=100)


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
    temperature_u_c: float = _f(0.5, "standard uncertainty of the temperature each set point's fit is assigned (the "
                                "die sensor's or the chamber air's), C: Type B in each set point's uncertainty "
                                "budget through the table's slope (docs/uncertainty.md)", ge=0, le=20)


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


class _ChamberKeys(Section):
    """What every chamber has: its protocol, patience and the set points it may be sent."""

    driver: Literal["ascii"] = _f("ascii", "chamber protocol (docs/chamber-protocol.md)")
    timeout_s: float = _f(1.0, "reply timeout, s", ge=0.01, le=60)
    retries: int = _f(2, "retries of a command", ge=0, le=10)
    min_c: float = _f(-70.0, "lowest set point allowed, C", ge=-100, le=200)
    max_c: float = _f(180.0, "highest set point allowed, C", ge=-100, le=300)


class _VisaType(Section):
    type: Literal["visa"] = _f("visa", "the chamber type: visa (a real chamber)")


class _EmulatedType(Section):
    # its default: the older spelling (port: emulated without a type) is routed here by _chamber_type
    type: Literal["emulated"] = _f("emulated", "the chamber type: emulated")


class VisaChamberConfig(_ChamberKeys, _VisaType):
    """``chamber`` with ``type: visa``: a real chamber, opened through a VISA backend."""

    port: str = _f(..., "serial device (/dev/ttyUSB2, COM3), host:port (the chamber's LAN option) or a VISA "
                   "resource name")
    baud: int = _f(9600, "serial baud rate", ge=300, le=1_000_000)
    visa_library: str = Field("@py", min_length=1, description=(
        "the VISA backend pyvisa opens the port through: @py (pyvisa-py, the default), @ivi (an "
        "installed IVI VISA such as NI-VISA or Keysight IO), @sim (pyvisa-sim), or a vendor VISA library's path"))


class EmulatedChamberConfig(_ChamberKeys, _EmulatedType):
    """``chamber`` with ``type: emulated``: the chamber emulator around the simulated boards.

    It answers on a pseudo-terminal, spoken to through pyvisa-py (@py) by the real chamber driver; the
    boards' clock is its clock and their temperature follows its air."""

    emulator: ChamberEmulatorSection | None = _f(None, "the emulated chamber's physics and faults")
    port: Literal["emulated"] | None = _f(None, "the older spelling of type: emulated (port: emulated, no type); "
                                          "accepted, nothing else")


ChamberSection = VisaChamberConfig | EmulatedChamberConfig
"""A validated ``chamber`` section: a real chamber's or the emulated one's model."""
CHAMBER_MODELS: dict[str, type[Section]] = {"visa": VisaChamberConfig, "emulated": EmulatedChamberConfig}


def _chamber_type(v: Any) -> str:
    """``type`` picks the model; without one, the older ``port: emulated`` still means the emulated chamber."""
    if isinstance(v, dict):
        got = v.get("type", "emulated" if v.get("port") == "emulated" else "visa")
    else:
        got = getattr(v, "type", "visa")
    return f"type={got}" if isinstance(got, str) else "type=?"


Chamber = Annotated[
    Annotated[VisaChamberConfig, Tag("type=visa")] | Annotated[EmulatedChamberConfig, Tag("type=emulated")],
    _discriminator("type", "visa", CHAMBER_MODELS, _chamber_type, union="chamber_type")]
"""The ``chamber`` field: a real chamber (type: visa, the default) or the emulated one (type: emulated)."""


class WebSection(Section):
    """``accelcal serve`` and ``accelcal run --ui web``."""

    token: str | None = _f(None, "shared secret that starting or aborting a run over the web API needs: "
                           "16-200 printable characters, no spaces")
    read_token: str | None = _f(None, "shared secret every read of `accelcal serve` needs (sent as "
                                "'Authorization: Bearer TOKEN'); required to listen beyond localhost "
                                "unless --public: 16-200 printable characters, no spaces")
    operator_token: str | None = _f(None, "shared secret every request of the operator page (`run --ui web`) "
                                    "needs (default: read_token); required to listen beyond localhost unless "
                                    "--public: 16-200 printable characters, no spaces")


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
    device: Device = _f(..., "the board (or panel of boards) and its driver (driver: simulated, mma8451, mpu6050)")
    jig: Jig | None = _f(None, "the fixture that holds the board (type: simulated, operator, motorized)")
    plan: PlanSection | None = _f(None, "pose design and model")
    capture: CaptureSection | None = _f(None, "stillness gating and averaging at each pose")
    acceptance: AcceptanceSection | None = _f(None, "limits for PASS")
    nvm: NvmSection | None = _f(None, "burning the calibration")
    verify: VerifySection | None = _f(None, "closed-loop verification after the burn")
    thermal: ThermalSection | None = _f(None, "a thermal plan: a calibration at each set point")
    chamber: Chamber | None = _f(None, "the thermal chamber (thermal plans; type: visa, emulated)")
    web: WebSection | None = _f(None, "the web pages and API (accelcal serve, accelcal run --ui web)")
    logging: LoggingSection | None = _f(None, "the station's event log: port losses, retries, burns, outbox")


class _DeviceOnly(Section):
    device: Device = _f(..., "a device section on its own (a command's device file)")


def validate_device(section: object, file: str | None = None) -> DeviceSection:
    """A ``device`` section on its own (a command's device file, a test's mapping) against its driver's
    model: the one validation of a device section outside a station config (ConfigError: one line,
    naming ``file`` when given)."""
    try:
        only = validate({"device": section}, _DeviceOnly)
    except ConfigError as e:
        if file is None:
            raise
        raise ConfigError(f"{file}: {e}") from None
    assert isinstance(only, _DeviceOnly)
    return only.device


class _JigOnly(Section):
    jig: Jig = _f(..., "a jig section on its own (a test's, a tool's)")


def validate_jig(section: object) -> JigSection:
    """A ``jig`` section on its own against its type's model (ConfigError: one line)."""
    only = validate({"jig": section}, _JigOnly)
    assert isinstance(only, _JigOnly)
    return only.jig


class _ChamberOnly(Section):
    chamber: Chamber = _f(..., "a chamber section on its own (a test's, a tool's)")


def validate_chamber(section: object) -> ChamberSection:
    """A ``chamber`` section on its own against its type's model (ConfigError: one line)."""
    only = validate({"chamber": section}, _ChamberOnly)
    assert isinstance(only, _ChamberOnly)
    return only.chamber


def validate_station(raw: Mapping[str, object]) -> StationConfigSchema:
    """A whole station config against the schema (ConfigError: one line)."""
    return validate(raw, StationConfigSchema)  # type: ignore[return-value]

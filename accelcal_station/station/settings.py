"""The station configuration: read a station config (YAML) once and check every section, each
error naming its key path, before anything touches a board.  What is checked is kept as the
schema's typed sections (``StationConfig.schema``): the station, its factories and flows read
those, never the file's mapping again."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from pydantic import BaseModel

from ..acceptance.rules import Limits
from ..config.checks import load_yaml_text
from ..config.schema import (
    CaptureSection,
    DeviceSection,
    JigSection,
    LoggingSection,
    MotorizedJigConfig,
    NvmSection,
    PlanSection,
    SimulatedJigConfig,
    StationConfigSchema,
    StationSection,
    VerifySection,
    WebSection,
    validate_station,
)
from ..config.sections import default_config_path, with_port
from ..config.site import STANDARD_SITE, Site
from ..config.site_section import site_of
from ..errors import ConfigError
from ..fixtures.designs import get_design
from ..models.fitting import check_model
from ..store.heartbeat import HEARTBEAT_S
from ..store.location import outbox_of, store_path, store_target
from .capture import CaptureSettings
from .verification import verify_mode


@dataclass
class StationConfig:
    """A checked station configuration (every error names its key path)."""

    schema: StationConfigSchema  # every section, validated once (config/schema.py)
    text: str  # the text that was parsed, recorded with every run
    path: Path
    station_id: str
    design: str
    model: str
    capture: CaptureSettings
    limits: Limits
    nvm_write: bool
    slot_size: int | None
    offset_trim: bool
    verify_poses: int
    verify_design: str | None
    store_file: Path | str  # a file, or a store URL (postgresql://...)
    web_token: str | None = None  # web.token: what starting or aborting a run over the web API needs
    event_log: LoggingSection | None = None  # logging: (config/event_log.py)
    web_read_token: str | None = None  # web.read_token: what every read of `accelcal serve` needs
    site: Site = STANDARD_SITE  # station.site: the gravity the jig's references are scaled to (config/site.py)

    @classmethod
    def load(cls, path: str | Path | None = None, store_override: str | Path | None = None,
             port: str | None = None, jig_port: str | None = None) -> StationConfig:
        """Read and check a station config; ``port``/``jig_port`` override the device's
        port (or MMA8451 bus) and the motorized jig's port."""
        p = default_config_path() if path is None else Path(path)
        raw, text = load_yaml_text(p)
        # the declared schema (config/schema.py): every key, type, finite number and range, each
        # driver's and jig type's own keys included (discriminated on device.driver and jig.type)
        sc = _with_ports(validate_station(raw), port, jig_port)
        # then what depends on more than one key, in this order (a config with several errors
        # names the same one first)
        if "device" not in raw:
            raise ConfigError(f"{p}: device: required (a mapping with a 'driver' key)")
        design, model = _plan(sc.plan or PlanSection())
        settings = _capture_settings(sc.capture or CaptureSection())
        nvm = sc.nvm or NvmSection()
        if nvm.offset_trim and model == "15":
            raise ConfigError("nvm.offset_trim: the 15-parameter model's cubic term cannot be moved into "
                              "offset registers; allowed with models 6, 9, 12")
        ver = sc.verify or VerifySection()
        if ver.design is not None:
            get_design(ver.design)
        verify_mode(ver)  # verify.mode against verify.design (station/verification.py)
        # a relative store path is taken from the current directory: the station's
        # working folder, never the (possibly installed, read-only) config folder
        store_file = store_target(store_override) if store_override else store_path(sc.store, Path.cwd())
        limits = Limits.from_section(sc.acceptance)
        verify_poses = _verify_poses(ver.poses, limits)
        return cls(sc, text, p, (sc.station or StationSection()).id, design, model, settings,
                   limits, nvm.write, nvm.slot_size, nvm.offset_trim, verify_poses, ver.design, store_file,
                   _web_token(sc.web), sc.logging,
                   _web_token(sc.web, read=True), site_of((sc.station or StationSection()).site))

    @property
    def operator_page_token(self) -> str | None:
        """What every request of the operator page (`run --ui web`) needs: web.operator_token, else
        web.read_token (docs/security.md, "The operator page")."""
        return _web_token(self.schema.web, key="operator_token") or self.web_read_token

    def with_sections(self, **sections: BaseModel) -> StationConfig:
        """This configuration with some sections replaced by ones already validated (a benchmark's
        panel of N boards, a jig without moves), each marked as given."""
        return replace(self, schema=self.schema.model_copy(update=sections))

    @property
    def device(self) -> DeviceSection:
        """The ``device`` section (a board, or a panel of boards with ``boards``)."""
        return self.schema.device

    @property
    def jig(self) -> JigSection:
        """The ``jig`` section (the simulated jig when the file has none)."""
        return self.schema.jig or SimulatedJigConfig()

    @property
    def is_panel(self) -> bool:
        """A panel: ``device.boards`` given (a count or a list)."""
        return self.schema.device.boards is not None

    @property
    def is_thermal(self) -> bool:
        """A thermal plan: ``thermal`` or ``chamber`` given (the flow refuses one without the other)."""
        return self.schema.thermal is not None or self.schema.chamber is not None

    @property
    def heartbeat_s(self) -> float:
        """``store.heartbeat_s``: seconds between a running run's heartbeats (store/heartbeat.py)."""
        return self.schema.store.heartbeat_s if self.schema.store is not None else HEARTBEAT_S

    @property
    def outbox(self) -> Path | None:
        """``store.outbox``, or None for the default outbox."""
        return outbox_of(self.schema.store)


def _with_ports(sc: StationConfigSchema, port: str | None, jig_port: str | None) -> StationConfigSchema:
    """The validated config with the command line's device and jig ports applied."""
    if port is not None:
        sc = sc.model_copy(update={"device": with_port(sc.device, port)})
    if jig_port is not None:
        if not isinstance(sc.jig, MotorizedJigConfig):
            raise ConfigError(f"--jig-port {jig_port}: the config's jig is not motorized (jig.type: motorized)")
        sc = sc.model_copy(update={"jig": sc.jig.model_copy(update={"port": jig_port})})
    return sc


def _plan(plan: PlanSection) -> tuple[str, str]:
    """plan.design and plan.model: an unknown design fails now, not mid-run."""
    get_design(plan.design)
    return plan.design, check_model(plan.model)


def _capture_settings(cap: CaptureSection) -> CaptureSettings:
    """capture: (ranges from the schema; its defaults are CaptureSettings', a test keeps them equal).
    Precedence: parameter targets (sequential capture) unless the file gives target_sem_mg alone."""
    settings = CaptureSettings(**cap.model_dump())
    if "target_sem_mg" in cap.model_fields_set and not {"target_offset_u_mg", "target_gain_u"} & cap.model_fields_set:
        # a config that names only the per-pose SEM keeps the per-pose rule (docs/capture.md, precedence)
        settings.target_offset_u_mg = settings.target_gain_u = None
    if settings.k_leave < settings.k_enter:
        raise ConfigError("capture.k_leave must be >= capture.k_enter (hysteresis)")
    return settings


def _verify_poses(verify_poses: int, limits: Limits) -> int:
    """verify.poses (0..64, default 3); 0 only when no limit needs the verification captures."""
    if verify_poses == 0 and "verify_error_max_mg" in limits.values:
        # without verification captures this limit would never be judged: a board would pass unchecked
        raise ConfigError("acceptance.verify_error_max_mg: needs verification captures (verify.poses: 0); "
                          "allowed: verify.poses of 1 or more, or remove the limit")
    return verify_poses


def _web_token(web: WebSection | None, read: bool = False, key: str | None = None) -> str | None:
    """web.token (web.read_token, or the ``key`` named): a shared secret of 16-200 printable characters
    (no spaces), or absent."""
    key = key or ("read_token" if read else "token")
    token = None if web is None else getattr(web, key)  # keys and type: the schema's
    if token is None:
        return None
    if not 16 <= len(token) <= 200 or not token.isprintable() or " " in token:
        raise ConfigError(f"web.{key}: allowed: a string of 16-200 printable characters without spaces")
    return str(token)


def configured_rate(device: DeviceSection) -> tuple[int | None, float | None]:
    """(range_g, odr_hz) the file set for the device; None where it left the driver's own default."""
    given_keys = device.model_fields_set
    return (device.range_g if "range_g" in given_keys else None,
            device.odr_hz if "odr_hz" in given_keys else None)

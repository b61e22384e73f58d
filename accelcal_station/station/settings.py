"""The station configuration: read a station config (YAML) once and check every section, each
error naming its key path, before anything touches a board.  What is checked is kept as the
schema's typed sections (``StationConfig.schema``): the station, its factories and flows read
those, never the file's mapping again."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
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
from ..config.site import Site
from ..config.site_section import site_of
from ..errors import ConfigError
from ..fixtures.designs import get_design
from ..models.fitting import check_model
from ..store.heartbeat import HEARTBEAT_S
from ..store.location import outbox_of, store_path, store_target
from .capture import CaptureSettings
from .verification import verify_mode


@dataclass(frozen=True)
class StationConfig:
    """A checked station configuration (every error names its key path).

    It holds the validated schema and what the file and the command line gave besides it; every other
    value is derived from ``schema`` (computed once, read-only), so none can disagree with it."""

    schema: StationConfigSchema  # every section, validated once (config/schema.py)
    text: str  # the text that was parsed, recorded with every run
    path: Path
    store_override: Path | str | None = None  # --store: a file or store URL instead of store.path
    workdir: Path = field(default_factory=Path.cwd)  # where a relative store.path is taken from (at load)

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
        if "device" not in raw:
            raise ConfigError(f"{p}: device: required (a mapping with a 'driver' key)")
        # a relative store path is taken from the current directory: the station's
        # working folder, never the (possibly installed, read-only) config folder
        return cls(sc, text, p, store_target(store_override) if store_override else None)._checked()

    def _checked(self) -> StationConfig:
        """What depends on more than one key, in this order (a config with several errors names the
        same one first): each derived value computed now, so a bad one fails at load, not mid-run."""
        _ = self.design, self.model, self.capture
        if self.offset_trim and self.model == "15":
            raise ConfigError("nvm.offset_trim: the 15-parameter model's cubic term cannot be moved into "
                              "offset registers; allowed with models 6, 9, 12")
        if self.verify_design is not None:
            get_design(self.verify_design)
        verify_mode(self.schema.verify)  # verify.mode against verify.design (station/verification.py)
        _ = self.store_file, self.limits, self.verify_poses, self.web_token, self.web_read_token, self.site
        return self

    def with_sections(self, **sections: BaseModel) -> StationConfig:
        """This configuration with some sections replaced by ones already validated (a benchmark's
        panel of N boards, a jig without moves), each marked as given; the derived values follow."""
        return replace(self, schema=self.schema.model_copy(update=sections))._checked()

    # --- derived from the schema (read-only; cached where a section is turned into another object) ---

    @property
    def station_id(self) -> str:
        """``station.id``: recorded with every run."""
        return (self.schema.station or StationSection()).id

    @cached_property
    def _plan(self) -> tuple[str, str]:
        return _plan(self.schema.plan or PlanSection())

    @property
    def design(self) -> str:
        """``plan.design``: the pose design (known: checked at load)."""
        return self._plan[0]

    @property
    def model(self) -> str:
        """``plan.model`` as text ("6", "9", "12", "15")."""
        return self._plan[1]

    @cached_property
    def capture(self) -> CaptureSettings:
        """``capture``: the capture's settings (station/capture.py)."""
        return _capture_settings(self.schema.capture or CaptureSection())

    @cached_property
    def limits(self) -> Limits:
        """``acceptance``: the limits a board is judged by."""
        return Limits.from_section(self.schema.acceptance)

    @property
    def _nvm(self) -> NvmSection:
        return self.schema.nvm or NvmSection()

    @property
    def nvm_write(self) -> bool:
        """``nvm.write``: burn the calibration."""
        return self._nvm.write

    @property
    def slot_size(self) -> int | None:
        """``nvm.slot_size``: bytes per slot (None: the blob's size)."""
        return self._nvm.slot_size

    @property
    def offset_trim(self) -> bool:
        """``nvm.offset_trim``: move the offset into the chip's offset registers too."""
        return self._nvm.offset_trim

    @property
    def verify_poses(self) -> int:
        """``verify.poses`` (0 only when no limit needs the verification captures)."""
        return _verify_poses((self.schema.verify or VerifySection()).poses, self.limits)

    @property
    def verify_design(self) -> str | None:
        """``verify.design`` (None: the plan's)."""
        return (self.schema.verify or VerifySection()).design

    @cached_property
    def store_file(self) -> Path | str:
        """A file, or a store URL (postgresql://...): ``--store``, else ``store.path`` from ``workdir``."""
        if self.store_override is not None:
            return self.store_override
        return store_path(self.schema.store, self.workdir)

    @property
    def web_token(self) -> str | None:
        """``web.token``: what starting or aborting a run over the web API needs."""
        return _web_token(self.schema.web)

    @property
    def web_read_token(self) -> str | None:
        """``web.read_token``: what every read of `accelcal serve` needs."""
        return _web_token(self.schema.web, read=True)

    @property
    def event_log(self) -> LoggingSection | None:
        """``logging`` (config/event_log.py)."""
        return self.schema.logging

    @cached_property
    def site(self) -> Site:
        """``station.site``: the gravity the jig's references are scaled to (config/site.py)."""
        return site_of((self.schema.station or StationSection()).site)

    @property
    def operator_page_token(self) -> str | None:
        """What every request of the operator page (`run --ui web`) needs: web.operator_token, else
        web.read_token (docs/security.md, "The operator page")."""
        return _web_token(self.schema.web, key="operator_token") or self.web_read_token

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

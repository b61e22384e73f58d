"""The station configuration: read a station config (YAML) and check every section, each
error naming its key path, before anything touches a board."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..acceptance.rules import Limits
from ..calibration import MODELS
from ..config.checks import check_keys, choice, load_yaml, number
from ..config.sections import default_config_path, with_port
from ..errors import AccelcalError, ConfigError
from ..fixtures.designs import get_design
from ..models.fitting import check_model
from ..store.location import store_path, store_target
from .capture import CaptureSettings
from .identity import IDENTITY_KEYS, identity_options

TOP_KEYS = ("station", "store", "device", "jig", "plan", "capture", "acceptance", "nvm", "verify",
            "thermal", "chamber", "web")  # thermal plans: station/thermal.py; web: `accelcal serve`, --ui web
JIG_TYPES = ("simulated", "operator", "motorized")


@dataclass
class StationConfig:
    """A checked station configuration (every error names its key path)."""

    raw: dict[str, Any]
    text: str
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

    @classmethod
    def load(cls, path: str | Path | None = None, store_override: str | Path | None = None,
             port: str | None = None, jig_port: str | None = None) -> StationConfig:
        """Read and check a station config; ``port``/``jig_port`` override the device's
        port (or MMA8451 bus) and the motorized jig's port."""
        p = default_config_path() if path is None else Path(path)
        raw = _read_with_ports(p, port, jig_port)
        # the checks run in this order: a config with several errors names the same one first
        st = _check_sections(raw, p)
        design, model = _plan(raw)
        settings = _capture_settings(raw)
        write, slot, trim = _nvm_options(raw, model)
        ver = check_keys(raw.get("verify"), ["poses", "design"], "verify")
        vdesign = ver.get("design")
        if vdesign is not None:
            get_design(str(vdesign))
        _check_jig(raw)
        # a relative store path is taken from the current directory: the station's
        # working folder, never the (possibly installed, read-only) config folder
        store_file = store_target(store_override) if store_override else store_path(raw, Path.cwd())
        limits = Limits.from_config(raw.get("acceptance"))
        verify_poses = _verify_poses(ver, limits)
        return cls(raw, p.read_text(), p, str(st.get("id", "station-1")), design, model, settings,
                   limits, write, slot, trim, verify_poses,
                   None if vdesign is None else str(vdesign), store_file, _web_token(raw))


def _read_with_ports(p: Path, port: str | None, jig_port: str | None) -> dict[str, Any]:
    """The config file's mapping with the command line's device and jig ports applied."""
    raw = load_yaml(p)
    if port is not None:
        raw["device"] = with_port(dict(raw.get("device") or {}), port)
    if jig_port is not None:
        jig = dict(raw.get("jig") or {})
        if jig.get("type") != "motorized":
            raise ConfigError(f"--jig-port {jig_port}: the config's jig is not motorized (jig.type: motorized)")
        raw["jig"] = {**jig, "port": jig_port}
    return raw


def _check_sections(raw: dict[str, Any], p: Path) -> dict[str, Any]:
    """Known top-level sections, a device section, and the station section (returned)."""
    check_keys(raw, TOP_KEYS, str(p.name))
    if "device" not in raw:
        raise ConfigError(f"{p}: device: required (a mapping with a 'driver' key)")
    st = check_keys(raw.get("station"), ["id", *IDENTITY_KEYS], "station")
    identity_options(raw)
    return st


def _plan(raw: dict[str, Any]) -> tuple[str, str]:
    """plan.design and plan.model, checked: unknown names fail now, not mid-run."""
    plan = check_keys(raw.get("plan"), ["design", "model"], "plan")
    design = str(plan.get("design", "an4399-8"))
    get_design(design)
    try:
        model = check_model(plan.get("model", "12"))
    except AccelcalError:
        raise ConfigError(f"plan.model: {plan.get('model')!r}; allowed: {', '.join(MODELS)}") from None
    return design, model


def _capture_settings(raw: dict[str, Any]) -> CaptureSettings:
    """capture:, over the CaptureSettings defaults (positive times and counts, k_leave >= k_enter)."""
    cap = check_keys(raw.get("capture"), CaptureSettings.__dataclass_fields__, "capture")
    defaults = CaptureSettings()
    values: dict[str, Any] = {
        k: number(cap, k, "capture", getattr(defaults, k), lo=0.0,
                  integer=isinstance(getattr(defaults, k), int)) for k in cap}
    settings = CaptureSettings(**values)
    for k in ("block_s", "max_s", "settle_timeout_s", "min_samples"):
        if getattr(settings, k) <= 0:
            raise ConfigError(f"capture.{k}: {getattr(settings, k)!r}; allowed: a positive number")
    if settings.k_leave < settings.k_enter:
        raise ConfigError("capture.k_leave must be >= capture.k_enter (hysteresis)")
    return settings


def _nvm_options(raw: dict[str, Any], model: str) -> tuple[bool, int | None, bool]:
    """nvm.write, nvm.slot_size and nvm.offset_trim (not with model 15's cubic term)."""
    nvm = check_keys(raw.get("nvm"), ["write", "slot_size", "offset_trim"], "nvm")
    write, trim = nvm.get("write", True), nvm.get("offset_trim", False)
    for key, v in (("write", write), ("offset_trim", trim)):
        if not isinstance(v, bool):
            raise ConfigError(f"nvm.{key}: {v!r}; allowed: true, false")
    if trim and model == "15":
        raise ConfigError("nvm.offset_trim: the 15-parameter model's cubic term cannot be moved into "
                          "offset registers; allowed with models 6, 9, 12")
    slot = None if nvm.get("slot_size") is None else number(nvm, "slot_size", "nvm", lo=64, integer=True)
    return write, slot, trim


def _check_jig(raw: dict[str, Any]) -> None:
    jig = raw.get("jig") or {"type": "simulated"}
    check_keys(jig, list(jig), "jig")
    choice(jig, "type", "jig", JIG_TYPES)


def _verify_poses(ver: dict[str, Any], limits: Limits) -> int:
    """verify.poses (0..64, default 3); 0 only when no limit needs the verification captures."""
    verify_poses = number(ver, "poses", "verify", 3, 0, 64, integer=True)
    if verify_poses == 0 and "verify_error_max_mg" in limits.values:
        # without verification captures this limit would never be judged: a board would pass unchecked
        raise ConfigError("acceptance.verify_error_max_mg: needs verification captures (verify.poses: 0); "
                          "allowed: verify.poses of 1 or more, or remove the limit")
    return verify_poses


def _web_token(raw: dict[str, Any]) -> str | None:
    """web.token: a shared secret of 16-200 printable characters (no spaces), or absent."""
    web = check_keys(raw.get("web"), ["token"], "web")
    token = web.get("token")
    if token is None:
        return None
    if not isinstance(token, str) or not 16 <= len(token) <= 200 or not token.isprintable() or " " in token:
        raise ConfigError("web.token: allowed: a string of 16-200 printable characters without spaces")
    return token

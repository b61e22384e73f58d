"""Who and what a run is about: the operator (required when the config says so) and the
board's serial number, scanned with a barcode reader (it types the serial and Enter)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Protocol

from ..config.schema import StationConfigSchema, StationSection
from ..errors import ConfigError, DataError
from ..fixtures.operator_ui import OperatorUI

IDENTITY_KEYS = ("scan_serial", "require_operator")
SERIAL_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:/-]{0,63}")


def identity_options(station: StationSection | None) -> dict[str, bool]:
    """station.scan_serial and station.require_operator (both default false)."""
    st = station or StationSection()
    return {k: getattr(st, k) for k in IDENTITY_KEYS}


def check_serial(text: str, where: str) -> str:
    s = text.strip()
    if not SERIAL_RE.fullmatch(s):
        raise DataError(f"{where}: {s[:40]!r} is not a serial number; allowed: 1-64 letters, digits and . _ : / -, "
                        "starting with a letter or digit")
    return s


class RunConfig(Protocol):
    """What the identity rules read of a station config (settings.StationConfig)."""

    @property
    def schema(self) -> StationConfigSchema: ...

    @property
    def path(self) -> Path: ...


def ask_run_identity(cfg: RunConfig, operator: str | None, serial: str | None,
                     ui: OperatorUI) -> tuple[str | None, str | None]:
    """Apply the config's identity rules; asks the operator (``ui``) for a serial scan when
    the config wants one (OperatorAbort on end of input)."""
    opts = identity_options(cfg.schema.station)
    if opts["require_operator"] and not (operator or "").strip():
        raise ConfigError(f"--operator: required (station.require_operator: true in {cfg.path.name})")
    if serial is not None:
        return operator, check_serial(serial, "--serial")
    if not opts["scan_serial"]:
        return operator, None
    while True:
        text = ui.ask_serial("Scan the board's serial number")
        try:
            return operator, check_serial(text, "scanned serial")
        except DataError as e:
            ui.say(f"  {e}; scan again")

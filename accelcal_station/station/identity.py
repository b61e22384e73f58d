"""Who and what a run is about: the operator (required when the config says so) and the
board's serial number, scanned with a barcode reader (it types the serial and Enter)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Protocol

from ..config.schema import StationConfigSchema, StationSection
from ..config.serials import check_label, check_serial
from ..errors import ConfigError, DataError
from ..fixtures.operator_ui import OperatorUI

IDENTITY_KEYS = ("scan_serial", "require_operator")
# a person's name: letters of any script, digits, space . ' -; starting with a letter or digit (never
# =, +, -, @ that a spreadsheet runs, never a control character)
NAME_RE = re.compile(r"[^\W_][^\W_ .'-]*(?:[ .'-]+[^\W_]+)*[.]?")


def identity_options(station: StationSection | None) -> dict[str, bool]:
    """station.scan_serial and station.require_operator (both default false)."""
    st = station or StationSection()
    return {k: getattr(st, k) for k in IDENTITY_KEYS}


def check_name(text: str, where: str) -> str:
    """An operator name as recorded: 1-64 letters (any script), digits, spaces and . ' -, starting
    with a letter or digit; else one DataError naming what is allowed."""
    s = " ".join(text.split())
    if len(s) > 64 or not NAME_RE.fullmatch(s):
        raise DataError(f"{where}: {s[:40]!r} is not a name; allowed: 1-64 letters, digits, spaces and . ' -, "
                        "starting with a letter or digit")
    return s


def check_run_labels(operator: str | None, lot: str | None, station_id: str | None) -> tuple[str | None, str | None]:
    """--operator (check_name), --lot and the config's station.id (check_serial) as a run records them."""
    if station_id is not None:
        check_serial(station_id, "station.id", what="station id")
    return (None if operator is None or not operator.strip() else check_name(operator, "--operator"),
            None if lot is None or not lot.strip() else check_label(lot, "--lot"))


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

"""`accelcal run --dry-run`: check a station before its first board without touching one (issue 49).

The config is validated (it was, to get here); every instrument the run would use is opened and
identified: each board's device (its serial by the one rule, a few samples read and their magnitude
checked against 1 g), the motorized jig (identified, homed and moved to the design's first pose and
back, so its axes are seen to move), the chamber (one status read, no set point).  Nothing is written:
no NVM, no store row (the store is named, not opened), no chamber set point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config.kinds import MotorizedJigConfig
from ..config.serials import check_serial
from ..drivers.factory import make_driver
from ..errors import AccelcalError
from ..fixtures.designs import get_design
from ..fixtures.factory import board_of, make_jig
from ..instruments.factory import make_chamber
from .panel_config import panel_sections
from .settings import StationConfig

SAMPLES = 32  # read per board: enough to see the chip answer and its magnitude
MAGNITUDE_TOLERANCE_G = 0.2  # a still board reads 1 g; an uncalibrated one within its offsets and gains


@dataclass(frozen=True)
class Check:
    """One instrument checked: what, whether it answered as it should, and what it said."""

    what: str
    ok: bool
    detail: str

    def to_json(self) -> dict[str, object]:
        return {"what": self.what, "ok": self.ok, "detail": self.detail}


def _boards(cfg: StationConfig, echo_checks: list[Check]) -> list[object]:
    """Open, identify and read every board's device; the simulated boards behind them (for the jig)."""
    buses: dict[object, object] = {}
    sims: list[object] = []
    sections = panel_sections(cfg.device) if cfg.is_panel else [(cfg.device, "device")]
    for sec, path in sections:
        try:
            driver = make_driver(sec, path, buses)  # type: ignore[arg-type]
            with driver:
                ident = driver.identify()
                if ident.serial:
                    check_serial(ident.serial, f"{path}: the serial the {ident.chip} reports")
                cap = driver.capture(n=SAMPLES)
                g = float(np.linalg.norm(cap.mean_counts / driver.counts_per_g))
            ok = abs(g - 1.0) <= MAGNITUDE_TOLERANCE_G
            echo_checks.append(Check(path, ok, f"{ident.chip} on {ident.interface}, serial {ident.serial or '-'}; "
                                     f"{cap.n} samples, |a| = {g:.3f} g"
                                     + ("" if ok else f" (a still board reads 1 g +- {MAGNITUDE_TOLERANCE_G})")))
            sims.append(board_of(driver))
        except AccelcalError as e:
            echo_checks.append(Check(path, False, str(e)))
    return sims


def _jig(cfg: StationConfig, checks: list[Check]) -> None:
    if not isinstance(cfg.jig, MotorizedJigConfig):
        checks.append(Check("jig", True, f"{cfg.jig.type}: nothing to open"))
        return
    try:
        with make_jig(cfg.jig, None) as jig:
            first = get_design(cfg.design)[0]
            jig.present(first)
            jig.home()
            checks.append(Check("jig", True, f"motorized on {cfg.jig.port}: identified, homed, moved to "
                                             f"{first.name} and back"))
    except AccelcalError as e:
        checks.append(Check("jig", False, str(e)))


def _chamber(cfg: StationConfig, sims: list[object], checks: list[Check]) -> None:
    section = cfg.schema.chamber
    if section is None:
        return
    try:
        board = sims[0] if sims else None
        with make_chamber(section, board, others=sims[1:]) as chamber:  # type: ignore[arg-type]
            st = chamber.status()
        checks.append(Check("chamber", not st.alarms, f"air {st.air_c:.1f} C, mode {st.mode}"
                                                       + (f", alarms {st.alarm_text()}" if st.alarms else "")))
    except AccelcalError as e:
        checks.append(Check("chamber", False, str(e)))


def dry_run(cfg: StationConfig) -> list[Check]:
    """Every instrument the run would use, opened, identified and read; nothing written (module docstring)."""
    checks = [Check("config", True, f"{cfg.path}: station {cfg.station_id}, design {cfg.design}, model {cfg.model}"),
              Check("store", True, f"{cfg.store_file} (not opened: a dry run writes nothing)")]
    sims = _boards(cfg, checks)
    _jig(cfg, checks)
    _chamber(cfg, sims, checks)
    return checks

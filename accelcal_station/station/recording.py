"""A finished run recorded in the store, or kept in the local outbox with the exact truth said.

``finish_run`` writes the poses, calibration, verdict and NVM outcome in one transaction.
When it fails (a disk I/O error, a malformed database, a full disk) after the board's NVM
was burned, the board carries a calibration the store has no record of.  ``record_result``
then closes the run as ``error`` where it still can, writes the whole result into the local
outbox (an SQLite file of its own: store.outbox, default $XDG_STATE_HOME/accelcal/outbox.sqlite),
and raises one StoreError that says exactly what was burned (slot, generation, CRC-32), what
the store holds for the run and where the result was kept.
"""
from __future__ import annotations

import contextlib
import functools
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from ..acceptance.reasons import Reason, codes
from ..calibration import Calibration
from ..config.site import SiteJson
from ..errors import AccelcalError
from ..jsontypes import JsonObject
from ..nvm.outcome import BurnOutcome
from ..session import Session
from ..store.outbox import default_outbox
from ..store.records import StoreError
from ..store.runs import Store
from .jig_pose import JigPoseEstimate
from .offset_trim import OffsetTrimRecord
from .report import FitFigures, RunReport, Timing, WarmupRecord, fit_figures
from .settings import StationConfig
from .time_budget import TimeBudget

if TYPE_CHECKING:
    from .thermal_table import ThermalSummary


class JigPoseRecord(TypedDict):
    """The jig's per-pose rotation as a panel's runs keep it (jig_pose.JigPoseEstimate)."""

    estimated: bool
    note: str | None
    rotvec_deg: list[list[float]]


class RunSummary(FitFigures, total=False):
    """What the store keeps of a run beside its poses and calibration (``fit_summary``): a single
    board's (``board_summary``: the fit's figures and reason codes), a thermal plan's single board's
    (``thermal_summary``) or a panel board's (``panel_summary``: its panel id and the jig's pose)."""

    reason_codes: list[str]
    measured: dict[str, float]
    verify_error_max_mg: float | None
    offset_trim_lsb: list[int] | None
    offset_trim: OffsetTrimRecord | None
    self_test: dict[str, object] | None  # drivers.self_test.SelfTestResult.to_json
    warmup: WarmupRecord | None  # station/warmup.py
    design: str
    skipped: list[str]
    timing: Timing
    time_budget: TimeBudget
    thermal: ThermalSummary | None
    nvm_verified: bool
    software_version: str | None  # the accelcal that recorded the run (its certificate names it)
    panel_id: str | None
    jig_pose: JigPoseRecord | None


class StartArgs(TypedDict):
    """Store.start_run's arguments for a run (to open it again in the outbox)."""

    device_serial: str | None
    chip: str | None
    station_id: str
    operator: str | None
    lot: str | None
    config_text: str
    model: str
    units: str
    counts_per_g: float | None
    panel_id: str | None


class FinishArgs(TypedDict):
    """Store.finish_run's arguments for a finished run."""

    session: Session
    calibration: Calibration | None
    verdict: str
    reasons: list[Reason]
    nvm_outcome: JsonObject | None
    fit_summary: RunSummary
    model: str
    retries: list[int]
    limits: dict[str, float]
    site: SiteJson | None
    uncertainty: Mapping[str, object] | None


@functools.cache
def software_version() -> str | None:
    """The installed accelcal-station's version (the package's __version__, which setuptools stamps into
    the distribution); read from the distribution because the package root imports the library face,
    a layer above the station.  None when running from a tree that was never installed."""
    try:
        return metadata.version("accelcal-station")
    except metadata.PackageNotFoundError:
        return None


def board_summary(cfg: StationConfig, rep: RunReport) -> RunSummary:
    """A single board's run at room temperature: its fit's figures, reason codes and what it measured."""
    return {**fit_figures(rep.fit), "reason_codes": codes(rep.reasons), "measured": rep.measured,
            "verify_error_max_mg": rep.verify_error_max_mg, "offset_trim_lsb": rep.offset_trim_lsb,
            "offset_trim": rep.offset_trim, "self_test": rep.self_test, "warmup": rep.warmup, "design": cfg.design,
            "skipped": rep.skipped, "timing": rep.timing, "time_budget": rep.time_budget,
            "nvm_verified": rep.nvm_verified, "software_version": software_version()}


def thermal_summary(cfg: StationConfig, rep: RunReport, thermal: ThermalSummary) -> RunSummary:
    """A single board's thermal plan: what it measured, its timing and the plan's summary."""
    return {"measured": rep.measured, "verify_error_max_mg": rep.verify_error_max_mg, "design": cfg.design,
            "timing": rep.timing, "thermal": thermal, "nvm_verified": rep.nvm_verified, "self_test": rep.self_test,
            "warmup": rep.warmup, "software_version": software_version()}


def panel_summary(cfg: StationConfig, rep: RunReport, panel_id: str | None, est: JigPoseEstimate | None,
                  thermal: ThermalSummary | None = None) -> RunSummary:
    """A panel board's run: what it measured, its panel's id and the jig's pose (a thermal plan's summary)."""
    jig = None if est is None else JigPoseRecord(estimated=est.estimated, note=est.note,
                                                  rotvec_deg=est.rotvec_deg.tolist())
    out: RunSummary = {
        "measured": rep.measured, "verify_error_max_mg": rep.verify_error_max_mg,
        "offset_trim_lsb": rep.offset_trim_lsb, "offset_trim": rep.offset_trim, "self_test": rep.self_test,
        "warmup": rep.warmup, "design": cfg.design, "skipped": rep.skipped, "timing": rep.timing,
        "nvm_verified": rep.nvm_verified, "time_budget": rep.time_budget, "panel_id": panel_id,
        "software_version": software_version(),
        "jig_pose": jig}
    if thermal is not None:
        out["thermal"] = thermal
    return out


def stored_uncertainty(rep: RunReport) -> dict[str, object] | None:
    """The ``uncertainty`` column: the budget with the decision rule it was judged by (None: no fit)."""
    if rep.uncertainty is None:
        return None
    return {**rep.uncertainty, "decision_rule": rep.decision_rule,
            "warnings": [w.to_dict() for w in rep.warnings]}


def burned_text(nvm: BurnOutcome | Mapping[str, object] | None) -> str:
    """What the board's NVM holds after the run, from its burn outcome (a BurnOutcome, its dict or None)."""
    d = nvm.to_dict() if isinstance(nvm, BurnOutcome) else nvm
    if d is None:
        return "nothing was written to the board's NVM"
    crc = d.get("crc32")
    where = (f"slot {d.get('slot')}, generation {d.get('generation')}, CRC-32 "
             f"{f'0x{crc:08x}' if isinstance(crc, int) else crc}")
    if d.get("ok"):
        return f"the board's NVM WAS written ({where}{', verified' if d.get('verified') else ''})"
    return f"the NVM burn failed ({where}: {d.get('error') or 'not verified'}); the previous calibration is kept"


def _held(store: Store, run_id: int) -> str:
    """What the store holds for ``run_id`` now, read back (never assumed)."""
    try:
        rec = store.get_run(run_id)
    except AccelcalError as e:
        return f"what {store.path} holds for run {run_id} cannot be read ({e})"
    cal = "with" if rec.calibration else "without"
    return (f"{store.path} holds run {run_id} as {rec.status} {cal} a calibration "
            f"(NVM status {rec.nvm_status or 'none'})")


def _keep(outbox: Path, start: StartArgs, finish: FinishArgs, target: str, run_id: int) -> str:
    """The run written whole into the outbox; where it went, or why it could not be."""
    try:
        with Store(outbox) as ob:
            local = ob.start_run(**start)
            ob.log_event(local, "unrecorded", f"not recorded in {target} (run {run_id})",
                         data={"target": target, "run_id": run_id})
            ob.finish_run(local, **finish)
    except (AccelcalError, OSError) as e:
        return f"the result could NOT be kept in the outbox {outbox} either ({e})"
    return (f"its calibration, verdict and NVM outcome are kept in the outbox {outbox} as run {local} "
            f"(`accelcal report show {local} --db {outbox}`)")


def start_args(cfg: StationConfig, rep: RunReport, operator: str | None, lot: str | None,
               counts_per_g: float | None, panel_id: str | None, device_serial: str | None) -> StartArgs:
    """Store.start_run's arguments for a run of ``cfg`` reported in ``rep``."""
    return {"device_serial": device_serial, "chip": rep.chip, "station_id": cfg.station_id, "operator": operator,
            "lot": lot, "config_text": cfg.text, "model": cfg.model, "units": "counts",
            "counts_per_g": counts_per_g, "panel_id": panel_id}


def record_result(store: Store, run_id: int, start: StartArgs, finish: FinishArgs,
                  outbox: Path | None) -> None:
    """``store.finish_run(run_id, **finish)``; on failure the outbox and one true StoreError (module doc).

    ``start``: the run's Store.start_run arguments, to open it again in the outbox."""
    try:
        store.finish_run(run_id, **finish)
        return
    except AccelcalError as e:
        failed = e
    with contextlib.suppress(AccelcalError):  # never leave the run 'running' where the store still writes
        store.interrupt_run(run_id, f"could not record the result: {failed}", status="error",
                            nvm_outcome=finish["nvm_outcome"])
    kept = _keep(outbox or default_outbox(), start, finish, str(store.path), run_id)
    raise StoreError(f"run {run_id}: the result could not be recorded ({failed}); "
                     f"{burned_text(finish['nvm_outcome'])}; {_held(store, run_id)}; {kept}") from None

"""A stored run as Python values: ``RunRecord`` (rebuilds the captured Session), the
conversions between column values and Python values (times, typed reasons, JSON columns,
pose rows) and ``StoreError``.

Times are unix seconds (REAL); ``iso`` gives ISO 8601 UTC for exports.  A JSON column that
does not parse is damaged: its row is shown as damaged, never fatal.
"""
from __future__ import annotations

import copy
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, NotRequired

import numpy as np
from typing_extensions import TypedDict  # the web API's response models build on these: pydantic on 3.11 wants this one

from ..acceptance.reasons import Reason, codes
from ..calibration import Calibration
from ..errors import DataError
from ..jsontypes import JsonObject, JsonValue
from ..session import PoseRecord, Session
from .database import Row
from .rowcheck import CheckedRow, DamagedRow, check_row, parse_json

AXES = "xyz"


class StoreError(DataError):
    """The results store cannot be opened, read or written."""


class RunNotFound(StoreError):
    """No run of that id in the store (the store itself was read)."""


class StoreUnreachable(StoreError):
    """The store's database server cannot be reached, or the connection to it was lost."""


def iso(t: float | None) -> str | None:
    """Unix seconds as ISO 8601 UTC."""
    return None if t is None else datetime.fromtimestamp(t, UTC).isoformat(timespec="milliseconds")


def timestamp(value: object, what: str = "time") -> float | None:
    """Unix seconds from unix seconds, a datetime or an ISO 8601 string (naive = local time)."""
    if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return None if value is None else float(value)
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value)
        except ValueError:
            raise DataError(f"{what} {value!r}: not a date; allowed ISO 8601 like 2024-05-01 or "
                            "2024-05-01T13:30") from None
    if isinstance(value, datetime):
        return value.timestamp()
    raise DataError(f"{what} {value!r}: not a time")


def is_damaged(text: str | None) -> bool:
    """A JSON column that does not parse within the limits (rowcheck.parse_json): the row is
    shown as damaged, the listing goes on."""
    if text is None:
        return False
    try:
        parse_json(text)
    except ValueError:
        return True
    return False


def load_or(text: str | None, default: JsonValue) -> JsonValue:
    """A JSON column's value, or ``default`` when it is empty or damaged."""
    try:
        return default if text is None else parse_json(text)
    except ValueError:
        return default


def to_json(x: object) -> str | None:
    """A JSON column's text (None stays NULL); NaN and infinity are refused."""
    return None if x is None else json.dumps(x, allow_nan=False)


def opt(x: Any, cast: Callable[[Any], Any] = float) -> Any:
    """``cast(x)``, None kept as None."""
    return None if x is None else cast(x)


def stored_reasons(text: str | None) -> list[Reason]:
    """The typed reasons of a ``reasons`` column ([] when empty or damaged)."""
    return reasons_of(load_or(text, []))


def reasons_of(value: JsonValue) -> list[Reason]:
    """The typed reasons of a checked (parsed) ``reasons`` value ([] when None)."""
    return [Reason.from_dict(x) for x in value] if isinstance(value, list) else []


def pose_record(p: CheckedRow) -> PoseRecord:
    """A checked ``poses`` row with no damage as the PoseRecord that was captured."""
    def vec(c: str) -> np.ndarray | None:
        return None if p.value(f"{c}_x") is None else np.array([p.real(f"{c}_{a}") for a in AXES], dtype=float)

    return PoseRecord(p.text("name") or "", np.array([p.real(f"mean_{a}") for a in AXES], dtype=float), vec("std"),
                      p.int("n"), vec("ref"), p.real("pitch_deg"), p.real("roll_deg"), p.real("temp_c"),
                      p.int("dropped") or 0, p.real("t_start"), p.real("t_end"))


class RunLabels(TypedDict):
    """Who and what a run was and how it ended: the ``runs`` columns every form of a run shows alike
    (the row, the listing, the web's and the API's run)."""

    status: str | None
    status_reason: str | None
    device_serial: str | None
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    model: str | None
    verdict: str | None


class RunTimes(TypedDict):
    """A run's start and end, unix s (the listing gives them as ISO 8601 instead)."""

    started_at: float | None
    finished_at: float | None


class RunSetup(TypedDict):
    """How a run was set up: its config, its readings' units and scale, the panel it was on."""

    config_hash: str | None
    config_text: str | None
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    panel_id: str | None  # the boards calibrated together on one jig


class RunColumns(RunLabels, RunTimes, RunSetup):
    """The ``runs`` columns every form of a stored run has alike (a damaged value None)."""

    id: int | None
    nvm_status: str | None
    nvm_outcome: JsonObject | None
    calibration: JsonObject | None
    fit_summary: JsonObject | None
    host: str | None
    pid: int | None
    limits: dict[str, float] | None
    heartbeat_at: float | None
    heartbeat_s: float | None
    site: JsonObject | None  # the site's gravity (schema 6; config/site.py)
    uncertainty: JsonObject | None  # the uncertainty budget and decision rule (schema 6; docs/uncertainty.md)


class RunRow(RunColumns):
    """A ``runs`` row checked (rowcheck): JSON columns parsed, a damaged value None (named in its damage)."""

    reasons: list[JsonValue] | None


def run_row(raw: Row) -> tuple[RunRow, list[DamagedRow]]:
    """A ``runs`` row read back, checked (rowcheck.check_row), and what is damaged in it."""
    c = check_row("runs", raw)
    t = c.text
    row: RunRow = {
        "id": c.int("id"), "started_at": c.real("started_at"), "finished_at": c.real("finished_at"),
        "status": t("status"), "status_reason": t("status_reason"), "device_serial": t("device_serial"),
        "chip": t("chip"), "station_id": t("station_id"), "operator": t("operator"), "lot": t("lot"),
        "config_hash": t("config_hash"), "config_text": t("config_text"), "model": t("model"), "units": t("units"),
        "counts_per_g": c.real("counts_per_g"), "gravity_mps2": c.real("gravity_mps2"), "verdict": t("verdict"),
        "reasons": c.json_list("reasons"), "nvm_status": t("nvm_status"), "nvm_outcome": c.json_object("nvm_outcome"),
        "calibration": c.json_object("calibration"), "fit_summary": c.json_object("fit_summary"), "host": t("host"),
        "pid": c.int("pid"), "panel_id": t("panel_id"), "limits": c.numbers("limits"),
        "heartbeat_at": c.real("heartbeat_at"), "heartbeat_s": c.real("heartbeat_s"),
        "site": c.json_object("site"), "uncertainty": c.json_object("uncertainty")}
    return row, list(c.damage)


class StoredEvent(TypedDict):
    """A run's event as stored: when, what kind, its line and its data (a JSON value, or None);
    a damaged value reads as None."""

    t: float | None
    kind: str | None
    message: str | None
    data: JsonValue  # JSON as logged: a burn's outcome, a capture's numbers, ...


class StoredPose(TypedDict):
    """A pose of a stored run (``RunRecord.to_dict``'s poses): reference and readings per axis."""

    name: str
    pitch_deg: float | None
    roll_deg: float | None
    reference_g: list[float] | None
    mean: list[float]
    std: list[float] | None
    n: int | None
    dropped: int
    temp_c: float | None
    t_start: float | None
    t_end: float | None
    retries: int


class RunSummary(RunLabels):
    """A run's listing entry (``Store.list_runs``; no poses); ``damaged``/``damage`` when its row is."""

    id: int | None  # a damaged value reads as None (rowcheck), the row still listed
    started_at: str | None  # ISO 8601 (iso)
    finished_at: str | None
    reasons: list[str]
    reason_codes: list[str]
    nvm_status: str | None
    pose_count: int
    panel_id: str | None
    limits: dict[str, float] | None
    residual_rms_g: float | None
    damaged: NotRequired[list[str]]
    damage: NotRequired[list[dict[str, str]]]  # DamagedRow.to_dict: code, table, id, column, problem


@dataclass
class RunRecord:
    """One stored run; ``session()`` rebuilds the captured Session."""

    id: int | None  # a damaged value reads as None (rowcheck), named in ``damage``
    started_at: float | None
    finished_at: float | None
    status: str | None
    status_reason: str | None
    device_serial: str | None
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    config_hash: str | None
    config_text: str | None
    model: str | None
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    verdict: str | None
    reasons: list[Reason]
    nvm_status: str | None
    nvm_outcome: JsonObject | None
    calibration: JsonObject | None
    fit_summary: JsonObject | None
    host: str | None
    pid: int | None
    panel_id: str | None = None  # the boards calibrated together on one jig
    limits: dict[str, float] | None = None  # the acceptance limits the run was judged by (schema 4)
    heartbeat_at: float | None = None  # the station's last sign of life, unix s (schema 5; store/heartbeat.py)
    heartbeat_s: float | None = None  # seconds between its heartbeats
    site: JsonObject | None = None  # the site's gravity the references were scaled to (schema 6)
    uncertainty: JsonObject | None = None  # the uncertainty budget and decision rule (schema 6)
    poses: list[PoseRecord] = field(default_factory=list)
    retries: list[int] = field(default_factory=list)
    events: list[StoredEvent] = field(default_factory=list)
    damaged: list[str] = field(default_factory=list)  # columns of the run's row that are damaged (shown as None)
    damage: list[DamagedRow] = field(default_factory=list)  # every damaged value of the run, its poses and events

    def session(self) -> Session:
        meta: dict[str, Any] = {"run_id": self.id, "station_id": self.station_id, "lot": self.lot, "chip": self.chip,
                                "started_at": iso(self.started_at)}
        if self.site is not None and isinstance(self.site.get("gravity_mps2"), (int, float)):
            meta["site"] = dict(self.site)  # the stored references are the site's; model 9's norm is too
        return Session(list(self.poses), self.units or "counts", self.counts_per_g, self.gravity_mps2,
                       self.device_serial, meta)

    def poses_unread(self) -> str | None:
        """Why a complete run's poses cannot all be read, None when they can: a complete run was
        fitted on its poses, so none read (rows deleted, or a ``run_id`` such as 2.5 that names no
        run: `report check` lists those rows), or fewer than its fit summary's ``pose_count``, leaves
        it out of any refit unless named."""
        if self.status != "complete":
            return None
        want = (self.fit_summary or {}).get("pose_count")
        fitted = want if isinstance(want, int) and not isinstance(want, bool) and want > 0 else None
        used = f"its fit used {fitted}; " if fitted is not None else ""
        if not self.poses:
            return f"poses_unreadable: complete, but none of its pose rows can be read ({used}see report check)"
        if fitted is not None and len(self.poses) < fitted:
            return (f"poses_unreadable: only {len(self.poses)} of the {fitted} pose rows its fit used can be read "
                    "(see report check)")
        return None

    def calibration_object(self) -> Calibration | None:
        return None if self.calibration is None else Calibration.from_dict(self.calibration, f"run {self.id}")

    def to_dict(self) -> RunDocument:
        """The run as ``report show --json`` and the JSON export give it."""
        return {
            "id": self.id, "started_at": self.started_at, "finished_at": self.finished_at, "status": self.status,
            "status_reason": self.status_reason, "device_serial": self.device_serial, "chip": self.chip,
            "station_id": self.station_id, "operator": self.operator, "lot": self.lot,
            "config_hash": self.config_hash, "config_text": self.config_text, "model": self.model,
            "units": self.units, "counts_per_g": self.counts_per_g, "gravity_mps2": self.gravity_mps2,
            "verdict": self.verdict, "reasons": [str(r) for r in self.reasons], "nvm_status": self.nvm_status,
            "nvm_outcome": copy.deepcopy(self.nvm_outcome), "calibration": copy.deepcopy(self.calibration),
            "fit_summary": copy.deepcopy(self.fit_summary), "host": self.host, "pid": self.pid,
            "panel_id": self.panel_id, "limits": None if self.limits is None else dict(self.limits),
            "heartbeat_at": self.heartbeat_at, "heartbeat_s": self.heartbeat_s,
            "site": copy.deepcopy(self.site), "uncertainty": copy.deepcopy(self.uncertainty),
            "poses": [_pose_dict(p, r) for p, r in zip(self.poses, self.retries, strict=True)],
            "retries": list(self.retries), "events": copy.deepcopy(self.events), "damaged": list(self.damaged),
            "damage": [x.to_dict() for x in self.damage], "started_at_iso": iso(self.started_at),
            "finished_at_iso": iso(self.finished_at), "reason_codes": codes(self.reasons)}


class RunDocument(RunColumns):
    """A stored run in full (``RunRecord.to_dict``): the record's fields, its poses and events as
    JSON, its damage, the times also as ISO 8601 and the reasons as text with their codes."""

    reasons: list[str]
    poses: list[StoredPose]
    retries: list[int]
    events: list[StoredEvent]
    damaged: list[str]
    damage: list[dict[str, str]]  # DamagedRow.to_dict
    started_at_iso: str | None
    finished_at_iso: str | None
    reason_codes: list[str]


def build_record(run: RunRow, damage: list[DamagedRow], pose_rows: list[Row],
                 event_rows: list[Row]) -> RunRecord:
    """A RunRecord from a checked ``runs`` row and its raw pose and event rows (checked here:
    a damaged pose is left out of the session, a damaged event keeps what is readable)."""
    damage = list(damage)
    rec = RunRecord(
        id=run["id"], started_at=run["started_at"], finished_at=run["finished_at"], status=run["status"],
        status_reason=run["status_reason"], device_serial=run["device_serial"], chip=run["chip"],
        station_id=run["station_id"], operator=run["operator"], lot=run["lot"], config_hash=run["config_hash"],
        config_text=run["config_text"], model=run["model"], units=run["units"], counts_per_g=run["counts_per_g"],
        gravity_mps2=run["gravity_mps2"], verdict=run["verdict"], reasons=reasons_of(run["reasons"]),
        nvm_status=run["nvm_status"], nvm_outcome=run["nvm_outcome"], calibration=run["calibration"],
        fit_summary=run["fit_summary"], host=run["host"], pid=run["pid"], panel_id=run["panel_id"],
        limits=run["limits"], heartbeat_at=run["heartbeat_at"], heartbeat_s=run["heartbeat_s"],
        site=run["site"], uncertainty=run["uncertainty"], damaged=sorted({d.column for d in damage}))
    for raw in pose_rows:
        p = check_row("poses", raw)
        damage += p.damage
        if not p.damage:
            rec.poses.append(pose_record(p))
            rec.retries.append(p.int("retries") or 0)
    for raw in event_rows:
        e = check_row("events", raw)
        damage += e.damage
        rec.events.append({"t": e.real("t"), "kind": e.text("kind"), "message": e.text("message"),
                           "data": e.json("data")})
    rec.damage = damage
    return rec


def run_summary(r: RunRow, damage: list[DamagedRow], pose_count: int) -> RunSummary:
    """The listing entry of a checked ``runs`` row (no poses)."""
    reasons = reasons_of(r["reasons"])
    fit = r["fit_summary"] if isinstance(r["fit_summary"], dict) else {}
    rms = fit.get("residual_rms_g")
    out: RunSummary = {"id": r["id"], "started_at": iso(r["started_at"]), "finished_at": iso(r["finished_at"]),
            "status": r["status"], "status_reason": r["status_reason"], "device_serial": r["device_serial"],
            "chip": r["chip"], "station_id": r["station_id"], "operator": r["operator"], "lot": r["lot"],
            "model": r["model"], "verdict": r["verdict"], "reasons": [str(x) for x in reasons],
            "reason_codes": codes(reasons), "nvm_status": r["nvm_status"], "pose_count": pose_count,
            "panel_id": r["panel_id"], "limits": r["limits"],
            "residual_rms_g": rms if isinstance(rms, (int, float)) and not isinstance(rms, bool) else None}
    if damage:
        out["damaged"], out["damage"] = sorted({d.column for d in damage}), [d.to_dict() for d in damage]
    return out


def _pose_dict(p: PoseRecord, retries: int) -> StoredPose:
    def arr(a: np.ndarray | None) -> list[float] | None:
        return None if a is None else np.asarray(a).tolist()

    return {"name": p.name, "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg, "reference_g": arr(p.reference_g),
            "mean": np.asarray(p.mean).tolist(), "std": arr(p.std), "n": p.n, "dropped": p.dropped,
            "temp_c": p.temp_c, "t_start": p.t_start, "t_end": p.t_end, "retries": retries}

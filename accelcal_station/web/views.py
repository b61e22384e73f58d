"""What the web layer shows of the store, as types: a run (``RunView``), a station's and a shift's
yields, a chart's points, the feed's rows, a lot's counts and calibrations (queries.py reads them;
api.py and pages.py show them).  ``pass`` and ``yield`` are Python keywords: those TypedDicts
have the functional form."""
from __future__ import annotations

from typing import NotRequired, TypedDict

from ..jsontypes import JsonObject


class Judged(TypedDict):
    """The limits a run was judged by and where they come from: "stored" (schema 4 runs), "config"
    (an older run: the acceptance section of the config it ran with) or None."""

    limits: dict[str, float] | None
    source: str | None


class RunHead(TypedDict):
    """A run's own columns as shown (RunView's first part)."""

    id: int | None
    started_at: float | None
    finished_at: float | None
    status: str | None
    status_reason: str | None
    device_serial: str | None
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    model: str | None
    verdict: str | None
    nvm_status: str | None
    limits: dict[str, float] | None


class RunTail(TypedDict):
    """What is read from a run's columns: its limits' source, reasons and figures (RunView's last part)."""

    limits_source: str | None
    reasons: list[dict[str, str]]  # Reason.to_dict: code, message
    reason_codes: list[str]
    residual_rms_mg: float | None
    measured: dict[str, float]


class RunView(RunHead, RunTail):
    """A run as the API and pages show it (queries.summary of its row): typed reasons, the fit
    figures, the limits it was judged by; ``damage`` when a value of its row is damaged."""

    damage: NotRequired[list[dict[str, str]]]  # DamagedRow.to_dict


# a station's (and shift's) yields; "pass" and "yield" are keywords: the functional form
Rates = TypedDict("Rates", {"runs": int, "pass": int, "first_runs": int, "yield": float | None,
                            "first_pass_yield": float | None})
StationYield = TypedDict("StationYield", {"station_id": str | None, "runs": int, "pass": int, "first_runs": int,
                                          "yield": float | None, "first_pass_yield": float | None})
ShiftYield = TypedDict("ShiftYield", {"station_id": str | None, "shift": str, "runs": int, "pass": int,
                                      "first_runs": int, "yield": float | None, "first_pass_yield": float | None})


class StationRow(StationYield):
    """A station on the line page: its latest run and its yields in the window."""

    latest: RunView


class SeriesPoint(TypedDict):
    """A run on a station's chart: id, start (unix s), the limits it was judged by, its measured figures."""

    id: int | None
    t: float
    limits: dict[str, float]
    measured: dict[str, float]


class FeedRow(TypedDict):
    """A run as the feed sees it: id, status, start (unix s)."""

    id: int
    status: str | None
    started_at: float | None


class RunFilters(TypedDict):
    """The MES API's filters (None: not filtered); times in unix s."""

    since: float | None
    until: float | None
    station: str | None
    serial: str | None
    verdict: str | None
    lot: str | None
    status: str | None


class LotRow(TypedDict):
    """A lot in the lots list: its name, runs and newest start (unix s)."""

    lot: str | None
    runs: int
    last: float | None


# the lot page's counts ("pass" is a keyword: the functional form)
LotCounts = TypedDict("LotCounts", {
    "runs": int, "by_status": dict[str, int], "pass": int, "fail": int, "pass_rate": float | None, "devices": int,
    "first_started": float | None, "last_started": float | None, "nvm": dict[str, int],
    "interruptions": dict[str, int], "failure_reasons": dict[str, int]})


class LotCalibration(TypedDict):
    """A calibrated run of a lot: id, start (unix s), station, its calibration (parsed) and limits."""

    id: int | None
    t: float
    station_id: str | None
    calibration: JsonObject
    limits: dict[str, float]

"""What the web layer shows of the store, as types: a run (``RunView``), a station's and a shift's
yields, a chart's points, the feed's rows, a lot's counts and calibrations (queries.py reads them;
api.py and pages.py show them).  ``pass`` and ``yield`` are Python keywords: those TypedDicts
have the functional form."""
from __future__ import annotations

from typing import Annotated

from pydantic import Field
from typing_extensions import TypedDict  # the API's response models (api.py) are these: pydantic on 3.11 wants this one

from ..jsontypes import JsonObject
from ..store.records import RunLabels, RunTimes


class Judged(TypedDict):
    """The limits a run was judged by and where they come from: "stored" (schema 4 runs), "config"
    (an older run: the acceptance section of the config it ran with) or None."""

    limits: dict[str, float] | None
    source: str | None


class Reason(TypedDict):
    """A reason as shown: its code and the whole text (the acceptance Reason's ``to_dict``)."""

    code: str
    message: str


class RunFigures(TypedDict):
    """What is read from a run's columns: its reasons, NVM status, fit figures and the limits it was
    judged by (in the order the API has always given them)."""

    reasons: list[Reason]
    reason_codes: list[str]
    nvm_status: str | None
    residual_rms_mg: float | None
    measured: dict[str, float]
    # optional in the OpenAPI (a default of null), as clients were given it; always set here
    limits: Annotated[dict[str, float] | None, Field(default=None)]
    limits_source: Annotated[str | None, Field(default=None)]


class Damaged(TypedDict, total=False):
    """What of a run's row is damaged (DamagedRow.to_dict); only there when something is."""

    damage: list[dict[str, str]]


class RunView(RunTimes, RunLabels, RunFigures, Damaged):
    """A run as the API and pages show it (queries.summary of its row): typed reasons, the fit
    figures, the limits it was judged by; ``damage`` when a value of its row is damaged."""

    id: int | None  # a damaged value reads as None (rowcheck); the API's RunSummary says int


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


# a lot's yield in the line page's window ("pass" and "yield" are keywords: the functional form)
LotYield = TypedDict("LotYield", {"lot": str | None, "runs": int, "pass": int, "yield": float | None})


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

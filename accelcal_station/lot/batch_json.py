"""What ``accelcal batch`` (pose tables and stored runs) prints and records, as typed JSON: a
board's result, the lot's report, what was written where (lot/batch.py builds them)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NotRequired, TypedDict


class BoardResultJson(TypedDict):
    """``BoardResult.to_dict``: one board of `accelcal batch --json` (key order as written)."""

    source: str
    serial: str | None
    run_id: int | None
    ok: bool
    message: str
    model: str
    pose_count: int
    W: list[list[float]] | None
    V: list[float] | None
    Gamma: list[float] | None
    residual_rms_g: float | None
    residual_max_g: float | None
    crossval_rms_g: float | None
    crossval_by_orientation_rms_g: float | None
    condition_number: float | None
    temperatures_c: list[float] | None
    input_units: str | None
    input_per_g: float | None
    held: Sequence[Mapping[str, object]]  # models/held.Held.to_json of each held term
    verdict: str | None
    reasons: list[dict[str, str]] | None  # Reason.to_dict
    file: NotRequired[str | None]  # the calibration file written for it (cli/batch.py adds it)


class FitSummaryJson(TypedDict):
    """``BoardResult.fit_summary``: the fit figures the results store summarises."""

    model: str
    pose_count: int
    residual_rms_g: float | None
    residual_max_g: float | None
    crossval_rms_g: float | None
    crossval_by_orientation_rms_g: float | None
    condition_number: float | None
    temperatures_c: list[float] | None
    source: str
    recalibrated_by: str


class StoreCounts(TypedDict):
    """What ``record_in_store`` recorded."""

    events: int
    runs: int


class BatchOutputs(TypedDict, total=False):
    """What `accelcal batch` wrote, where (each key only when that output was asked for)."""

    out_dir: str
    calibrations: int
    csv: str
    store: StoreOutput


class StoreOutput(StoreCounts):
    path: str


class BatchReportJson(TypedDict):
    """``BatchReport.to_dict``: `accelcal batch --json` (pose tables and stores)."""

    model: str
    boards: int
    fitted: int
    skipped: int
    fit_calls: int
    elapsed_s: float
    results: list[BoardResultJson]
    outputs: NotRequired[BatchOutputs]

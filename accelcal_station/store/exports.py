"""Exports and summaries of stored runs: the JSON document, the runs and poses CSV tables and
the lot summary (counts, pass rate, failure reasons, parameter distributions).

Store.export_json, Store.export_csv and Store.lot_summary read the runs and hand them here.
"""
from __future__ import annotations

import csv
import io
import json
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TypedDict

import numpy as np

from ..acceptance.reasons import codes
from ..atomic import atomic_write
from ..calibration import PARAM_NAMES, param_vector
from ..errors import DataError
from ..fileguard.cells import safe_row
from .liveness import STALE
from .records import RunDocument, RunRecord, RunRow, StoreError, iso, reasons_of
from .rowcheck import DamagedRow
from .schema import POSE_COLS, STATUSES

_RUN_CSV_COLS = ("id", "started_at", "finished_at", "status", "status_reason", "device_serial", "chip",
                 "station_id", "operator", "lot", "config_hash", "model", "units", "counts_per_g", "verdict",
                 "reasons", "nvm_status", "pose_count")
_FIT_SCALARS = ("residual_rms_g", "residual_max_g", "crossval_rms_g", "crossval_by_orientation_rms_g",
                "condition_number")


def write_export(path: str | Path, text: str) -> None:
    """Write an export atomically (a reader never sees half of it)."""
    try:
        atomic_write(path, text)
    except OSError as e:
        raise StoreError(f"{path}: cannot write export ({e.strerror})") from None


def runs_json(data: list[RunDocument]) -> str:
    """The JSON export document of runs given as RunRecord.to_dict()."""
    return json.dumps({"schema": "accelcal.runs", "version": 1, "runs": data}, indent=1) + "\n"


def _run_rows(recs: Sequence[RunRecord]) -> Iterator[list[object]]:
    """One row per run, fit figures and calibration parameters flattened."""
    yield [*_RUN_CSV_COLS, *_FIT_SCALARS, *PARAM_NAMES]
    for rec in recs:
        d = asdict(rec)
        d.update(started_at=iso(rec.started_at), finished_at=iso(rec.finished_at),
                 reasons="; ".join(rec.reasons), pose_count=len(rec.poses))
        fit = rec.fit_summary or {}
        params = param_vector(rec.calibration).tolist() if rec.calibration else [None] * 15
        yield [*(d[c] for c in _RUN_CSV_COLS), *(fit.get(k) for k in _FIT_SCALARS), *params]


def _pose_rows(recs: Sequence[RunRecord]) -> Iterator[list[object]]:
    """One row per pose, with its run's device, lot, verdict and units."""
    def v(a: np.ndarray | None) -> list[object]:
        return [None] * 3 if a is None else list(a)

    yield ["run_id", "device_serial", "lot", "verdict", "units", *POSE_COLS]
    for rec in recs:
        for i, (p, retries) in enumerate(zip(rec.poses, rec.retries, strict=True)):
            yield [rec.id, rec.device_serial, rec.lot, rec.verdict, rec.units, i, p.name, p.pitch_deg,
                   p.roll_deg, *v(p.reference_g), *v(p.mean), *v(p.std), p.n, p.dropped, p.temp_c,
                   p.t_start, p.t_end, retries]


_CSV_TABLES: dict[str, Callable[[Sequence[RunRecord]], Iterator[list[object]]]] = {"runs": _run_rows,
                                                                                 "poses": _pose_rows}


def csv_table(kind: str) -> Callable[[Sequence[RunRecord]], str]:
    """The CSV text maker of ``kind`` (runs or poses); checked before any run is read."""
    if kind not in _CSV_TABLES:
        raise DataError(f"CSV kind {kind!r}; allowed: runs, poses")
    rows = _CSV_TABLES[kind]

    def text(recs: Sequence[RunRecord]) -> str:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerows(safe_row(r) for r in rows(recs))  # no cell a formula
        return buf.getvalue()

    return text


class Stats(TypedDict):
    """A figure over runs: how many, mean, sample std (ddof=1; 0 for one value), min, max."""

    n: int
    mean: float
    std: float
    min: float
    max: float


# ``report summary --json`` ("pass" is a keyword: the functional form)
LotSummary = TypedDict("LotSummary", {
    "runs": int, "by_status": dict[str, int], "pass": int, "fail": int, "pass_rate": float | None,
    "failure_reasons": dict[str, int], "interruptions": dict[str, int], "nvm": dict[str, int], "devices": int,
    "models": dict[str, int], "first_started": str | None, "last_started": str | None,
    "parameters": dict[str, Stats] | None, "fit": dict[str, Stats], "damaged_rows": list[dict[str, str]]})


def _stats(values: np.ndarray) -> list[Stats]:
    """Stats of each column of ``values`` (N, m) over axis 0; a 1-D array is one column."""
    v = np.asarray(values, dtype=float)
    cols = (v.mean(axis=0), v.std(axis=0, ddof=1) if len(v) > 1 else np.zeros(v.shape[1:]), v.min(axis=0),
            v.max(axis=0))
    mean, std, lo, hi = (np.atleast_1d(c).tolist() for c in cols)
    return [{"n": int(len(v)), "mean": a, "std": b, "min": c, "max": d}
            for a, b, c, d in zip(mean, std, lo, hi, strict=True)]


def _distributions(done: Sequence[RunRow]) -> tuple[dict[str, Stats] | None, dict[str, Stats]]:
    """Parameter and fit-figure statistics over complete runs (those with a calibration / fit)."""
    cals = [c for c in (r["calibration"] for r in done) if c]
    params = None
    if cals:
        params = dict(zip(PARAM_NAMES, _stats(np.array([param_vector(c) for c in cals])), strict=True))
    fits = [f for f in (r["fit_summary"] for r in done) if isinstance(f, dict)]
    fit_stats = {}
    for k in _FIT_SCALARS:
        vals = [f[k] for f in fits if isinstance(f.get(k), (int, float)) and not isinstance(f.get(k), bool)]
        if vals:
            fit_stats[k] = _stats(np.array(vals))[0]
    return params, fit_stats


def summarize(checked: Sequence[tuple[RunRow, list[DamagedRow]]]) -> LotSummary:
    """Counts, pass rate, failure reasons and parameter distributions of checked run rows
    (rowcheck.check_row: JSON parsed, damaged values None; ``damaged_rows`` names them).

    pass_rate = PASS / (PASS + FAIL) over complete runs (None when there are none);
    failure_reasons counts FAIL runs per reason code; parameters (W, V, Gamma
    elements, PARAM_NAMES) and fit figures give mean, sample std (ddof=1), min,
    max over complete runs with a calibration.
    """
    rows = [r for r, _ in checked]
    by_status = Counter(r["status"] for r in rows)
    done = [r for r in rows if r["status"] == "complete"]
    verdicts = Counter(r["verdict"] for r in done if r["verdict"])
    decided = verdicts["PASS"] + verdicts["FAIL"]
    fail_reasons: Counter[str] = Counter()
    for r in done:
        if r["verdict"] == "FAIL":
            fail_reasons.update(set(codes(reasons_of(r["reasons"]))))
    params, fit_stats = _distributions(done)
    starts = [r["started_at"] for r in rows if r["started_at"] is not None]
    return {
        "runs": len(rows),
        "by_status": {s: by_status.get(s, 0) for s in (*STATUSES, STALE)},  # stale: running, process gone
        "pass": verdicts["PASS"], "fail": verdicts["FAIL"],
        "pass_rate": verdicts["PASS"] / decided if decided else None,
        "failure_reasons": dict(fail_reasons.most_common()),
        "interruptions": dict(Counter(r["status_reason"] or "unknown" for r in rows
                                      if r["status"] in ("interrupted", "error")).most_common()),
        "nvm": dict(Counter(r["nvm_status"] or "none" for r in done)),
        "devices": len({r["device_serial"] for r in rows}),
        "models": dict(Counter(r["model"] for r in done if r["model"])),
        "first_started": iso(min(starts)) if starts else None,
        "last_started": iso(max(starts)) if starts else None,
        "parameters": params,
        "fit": fit_stats,
        "damaged_rows": [d.to_dict() for _, damage in checked for d in damage],
    }

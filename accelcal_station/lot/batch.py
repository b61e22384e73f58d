"""Batch recalibration: fit many boards' recorded sessions with one model, vectorised.

Boards are grouped by what one stacked fit must share (pose count, units, whether
counts_per_g and per-pose noise are known, local gravity); each group of up to
``chunk_size`` boards is ONE ``models.fit_batch`` call on (D, P, 3) arrays, which
gives every board exactly what fitting it alone gives (AN4399 Eqn 46 per board,
or the model 9 gravity-norm fit), holding at nominal the terms its poses leave weak
exactly as `accelcal fit` does (models/held.py: ``BoardResult.held``, in the calibration's
metadata, the summary CSV and the verdict).  A board that cannot be fitted (unreadable,
no or too few poses, NaN, implausible units, an underdetermined pose set) stays
in the report with its reason: it is skipped, never silently dropped.  Boards
with poses at two or more temperatures are fitted one at a time by
``fit_temperature`` (a temperature table).

Results go to calibration JSON files (``write_calibrations``), a CSV summary
(``summary_csv``) or the results store (``record_in_store``).
"""
from __future__ import annotations

import csv
import glob
import io
import re
import time as _time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..acceptance.reasons import Reason, codes
from ..acceptance.rules import FitFigures, Limits, Verdict, judge_all
from ..atomic import atomic_write
from ..calibration import PARAM_NAMES, Calibration, param_vector
from ..data.loader import load_pose_table
from ..data.lotchunk import RANGES
from ..errors import AccelcalError, DataError
from ..fileguard.cells import safe_row
from ..fileguard.identity import Named, refuse_overwrite
from ..models.fitting import check_model, check_plausible_g, fit_batch, fit_temperature
from ..models.held import Held
from ..models.result import FitResult
from ..session import Session
from ..store.location import store_identity
from ..store.reader import StoreReader
from ..store.records import iso
from ..store.runs import Store
from .batch_json import BatchReportJson, BoardResultJson, FitSummaryJson, StoreCounts

BATCH_STATION = "accelcal-batch"  # station_id of runs recorded by a batch recalibration
Source = tuple[str, "Session | AccelcalError"]
Board = tuple[int, str, Session]  # input position, source, session of a board that passed the screen


@dataclass
class BoardResult:
    """One board of a batch: its fit, or why it was skipped (``ok`` False, ``message``)."""

    source: str  # file path, or "run N" of a results store
    serial: str | None
    ok: bool
    message: str
    model: str
    pose_count: int = 0
    calibration: Calibration | None = None
    residual_rms_g: float | None = None
    residual_max_g: float | None = None
    crossval_rms_g: float | None = None
    condition_number: float | None = None
    crossval_by_orientation_rms_g: float | None = None  # every pose of one orientation left out (models/crossval)
    temperatures_c: list[float] | None = None
    run_id: int | None = None
    fit: FitResult | None = field(default=None, repr=False)  # single-temperature fits
    session: Session | None = field(default=None, repr=False)
    verdict: Verdict | None = None  # judged when recalibrate is given limits
    held: list[Held] = field(default_factory=list)  # terms held at nominal (models/held.py), as `accelcal fit`

    @property
    def fitted_calibration(self) -> Calibration:
        """The calibration of a fitted board (``ok``); a skipped board has none."""
        if self.calibration is None:
            raise DataError(f"{self.source}: no calibration ({self.message})")
        return self.calibration

    def to_dict(self) -> BoardResultJson:
        cal = self.calibration
        return {"source": self.source, "serial": self.serial, "run_id": self.run_id, "ok": self.ok,
                "message": self.message, "model": self.model, "pose_count": self.pose_count,
                "W": None if cal is None else cal.W.tolist(), "V": None if cal is None else cal.V.tolist(),
                "Gamma": None if cal is None else cal.Gamma.tolist(),
                "residual_rms_g": self.residual_rms_g, "residual_max_g": self.residual_max_g,
                "crossval_rms_g": self.crossval_rms_g,
                "crossval_by_orientation_rms_g": self.crossval_by_orientation_rms_g,
                "condition_number": self.condition_number, "temperatures_c": self.temperatures_c,
                "input_units": None if cal is None else cal.input_units,
                "input_per_g": None if cal is None else cal.input_per_g,
                "held": [h.to_json() for h in self.held],
                "verdict": None if self.verdict is None else self.verdict.label,
                "reasons": None if self.verdict is None else [r.to_dict() for r in self.verdict.reasons]}

    def fit_summary(self) -> FitSummaryJson:
        """The fit figures the results store summarises (store/exports.py _FIT_SCALARS names)."""
        return {"model": self.model, "pose_count": self.pose_count, "residual_rms_g": self.residual_rms_g,
                "residual_max_g": self.residual_max_g, "crossval_rms_g": self.crossval_rms_g,
                "crossval_by_orientation_rms_g": self.crossval_by_orientation_rms_g,
                "condition_number": self.condition_number, "temperatures_c": self.temperatures_c,
                "source": self.source, "recalibrated_by": "accelcal batch"}


@dataclass
class BatchReport:
    model: str
    results: list[BoardResult]
    fit_calls: int  # stacked fit_batch calls (vectorised groups) plus one-at-a-time fits
    elapsed_s: float
    limits: dict[str, float] | None = None  # the acceptance limits the boards were judged by (None: not judged)

    @property
    def fitted(self) -> list[BoardResult]:
        return [r for r in self.results if r.ok]

    @property
    def skipped(self) -> list[BoardResult]:
        return [r for r in self.results if not r.ok]

    def to_dict(self) -> BatchReportJson:
        return {"model": self.model, "boards": len(self.results), "fitted": len(self.fitted),
                "skipped": len(self.skipped), "fit_calls": self.fit_calls, "elapsed_s": self.elapsed_s,
                "results": [r.to_dict() for r in self.results]}


# -- sources ---------------------------------------------------------------------------------

def expand_paths(specs: Iterable[str]) -> list[Path]:
    """Pose-table paths from files, directories (their *.csv) and glob patterns, in order, once each."""
    out: list[Path] = []
    for spec in specs:
        p = Path(spec)
        if p.is_dir():
            found = sorted(p.glob("*.csv"))
            if not found:
                raise DataError(f"{spec}: directory holds no pose tables (*.csv)")
        elif glob.has_magic(spec):
            found = [Path(x) for x in sorted(glob.glob(spec))]
            if not found:
                raise DataError(f"{spec}: no file matches this pattern")
        else:
            found = [p]  # a missing file is reported as a skipped board, not a batch failure
        out += found
    seen: set[Path] = set()
    unique = []
    for p in out:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def sessions_from_files(paths: Sequence[Path], units: str | None = None, counts_per_g: float | None = None,
                        gravity_mps2: float | None = None, model: str = "12",
                        progress: Callable[[int], None] | None = None) -> list[Source]:
    """(source, Session or the error that kept it from being read) per pose table."""
    out: list[Source] = []
    for p in paths:
        try:
            out.append((str(p), load_pose_table(p, units, counts_per_g, gravity_mps2, references=model != "9").session))
        except AccelcalError as e:
            out.append((str(p), e))
        if progress:
            progress(1)
    return out


def sessions_from_store(store: StoreReader, **filters: Any) -> list[Source]:
    """(``run N``, Session) of the store's complete runs with poses (Store.sessions_for_batch filters);
    a damaged run is (``run N``, DataError naming its damaged_row), skipped and counted by the batch."""
    skipped: list[tuple[str, str]] = []
    good: list[Source] = []
    for s in store.sessions_for_batch(skipped, **filters):
        why = stored_value_problem(s)  # the store's row checks allow n = 0 or a negative std
        good.append((f"run {s.metadata['run_id']}", s if why is None else DataError(why)))
    return [*good, *((label, DataError(why)) for label, why in skipped)]


def stored_value_problem(session: Session) -> str | None:
    """The first value of a stored run's poses outside what a pose table or lot file allows
    (data.lotchunk.RANGES: n a whole number >= 1, std >= 0, angles within +-360 deg, ...), or None;
    checked here, once, so the fit never computes with it."""
    for p in session.poses:
        std = (None,) * 3 if p.std is None else tuple(p.std)
        ref = (None,) * 3 if p.reference_g is None else tuple(p.reference_g)
        vals = {"x": p.mean[0], "y": p.mean[1], "z": p.mean[2], "pitch_deg": p.pitch_deg, "roll_deg": p.roll_deg,
                "ref_x": ref[0], "ref_y": ref[1], "ref_z": ref[2], "std_x": std[0], "std_y": std[1],
                "std_z": std[2], "n": p.n, "temp_c": p.temp_c}
        for cols, lo, hi, what in RANGES:
            for k in cols:
                v = vals[k]
                if v is not None and v == v and not (lo <= v <= hi and (k != "n" or float(v).is_integer())):
                    return f"pose {p.name!r}: {k} {float(v):g}: {what} out of range; allowed {lo:g} to {hi:g}"
    return None


def board_serial(session: Session) -> str | None:
    """A session's board serial: a pose table's ``# serial:`` line, else a stored run's device."""
    return session.metadata.get("serial") or (session.device if "run_id" in session.metadata else None)


# -- fitting ---------------------------------------------------------------------------------

def _skip(source: str, session: Session | AccelcalError, model: str, reason: str) -> BoardResult:
    s = session if isinstance(session, Session) else None
    return BoardResult(source, None if s is None else board_serial(s), False, reason, model,
                       0 if s is None else len(s), session=s,
                       run_id=None if s is None else s.metadata.get("run_id"))


def _screen(session: Session, model: str) -> str | None:
    """Why a board cannot join a stacked fit, for checks fit_batch makes over a whole stack."""
    if len(session) == 0:
        return "the session has no poses"
    bad = ~np.all(np.isfinite(session.readings), axis=1)
    if bad.any():
        return f"pose {session.names[int(np.argmax(bad))]!r}: reading is NaN or infinite"
    have_t = [p.temp_c is not None for p in session.poses]
    if any(have_t) and not all(have_t):
        return (f"pose {session.names[have_t.index(False)]!r} has no temp_c while others do; "
                "give temp_c for every pose or for none")
    if model != "9" and not session.has_references:
        missing = next(p.name for p in session.poses if p.reference_g is None)
        return f"pose {missing!r} has no reference; model {model} needs one per pose (only model 9 fits without)"
    if model != "9":
        try:  # fit_batch judges units on the median over the whole stack: judge each board
            check_plausible_g(session.readings_g(), session.units)
        except AccelcalError as e:
            return str(e)
    return None


def _group_key(s: Session) -> tuple[Any, ...]:
    return (len(s), s.units, s.counts_per_g is None, s.gravity_mps2 if s.units == "mps2" else None,
            s.noise() is not None, s.site_gravity_g)  # model 9's norm is the site's (models/site_norm.py)


def _fit_stack(members: list[tuple[str, Session]], model: str) -> list[BoardResult]:
    """One fit_batch call over boards sharing a group key; per board on a whole-stack error."""
    ss = [s for _, s in members]
    s0 = ss[0]
    x = np.stack([s.readings for s in ss])
    # the screen gives every board references (models 6/12/15); the group key, noise to all or none
    ref = None if model == "9" else np.stack(cast("list[np.ndarray]", [s.references_g for s in ss]))
    noise = np.stack(cast("list[np.ndarray]", [s.noise() for s in ss])) if s0.noise() is not None else None
    cpg = None if s0.counts_per_g is None else np.array([s.counts_per_g for s in ss])
    try:
        b = fit_batch(x, ref, model, units=s0.units, counts_per_g=cpg, gravity_mps2=s0.gravity_mps2, noise=noise,
                      norm_g=s0.site_gravity_g if model == "9" else 1.0)
    except AccelcalError as e:
        if len(members) == 1:
            return [_skip(members[0][0], s0, model, str(e))]
        return [r for m in members for r in _fit_stack([m], model)]
    out: list[BoardResult] = []
    for d, (src, s) in enumerate(members):
        if not b.ok[d]:
            out.append(_skip(src, s, model, b.messages[d]))
            continue
        fr = b.result(d)
        out.append(BoardResult(src, board_serial(s), True, fr.message, model, len(s), fr.calibration,
                               fr.residual_rms_g, fr.residual_max_g, fr.crossval_rms_g, fr.condition_number,
                               fr.crossval_by_orientation_rms_g, run_id=s.metadata.get("run_id"), fit=fr,
                               session=s, held=fr.held))
    return out


def _fit_temperature(src: str, s: Session, model: str) -> BoardResult:
    try:
        cal, fits = fit_temperature(s, model)
    except AccelcalError as e:
        return _skip(src, s, model, str(e))
    res = np.concatenate([f.residuals_g for _, f in fits])
    cvs = [f.crossval_rms_g for _, f in fits if f.crossval_rms_g is not None]
    return BoardResult(src, board_serial(s), True, "", model, len(s), cal,
                       float(np.sqrt(np.mean(res**2))), float(np.max(np.abs(res))),
                       float(np.sqrt(np.mean(np.square(cvs)))) if len(cvs) == len(fits) else None,
                       float(max(f.condition_number for _, f in fits)), None, [t for t, _ in fits],
                       run_id=s.metadata.get("run_id"), session=s)


def _screen_all(sessions: Sequence[Source],
                model: str) -> tuple[dict[int, BoardResult], list[list[Board]], list[Board]]:
    """Skipped boards with their reason (by input position), the others grouped by what one
    stacked fit must share, and the boards with poses at two or more temperatures."""
    skipped: dict[int, BoardResult] = {}
    groups: dict[tuple[Any, ...], list[Board]] = {}
    multi_temp: list[Board] = []
    for i, (src, s) in enumerate(sessions):
        if isinstance(s, AccelcalError):
            skipped[i] = _skip(src, s, model, str(s))
            continue
        reason = _screen(s, model)
        if reason is not None:
            skipped[i] = _skip(src, s, model, reason)
        elif s.temps_c is not None and len(s.by_temperature()) >= 2:
            multi_temp.append((i, src, s))
        else:
            groups.setdefault(_group_key(s), []).append((i, src, s))
    return skipped, list(groups.values()), multi_temp


def _judge(results: list[BoardResult], limits: Limits) -> None:
    """Each board's verdict by the one acceptance rule table (acceptance.judge_all over all
    single-temperature fits at once); a board that could not be fitted FAILs ``unfitted``,
    as in a lot file.  Boards fitted over temperature keep no verdict (no single fit)."""
    fitted = [r for r in results if r.ok and r.fit is not None]
    if fitted:
        for r, v in zip(fitted, judge_all(FitFigures.from_fits([cast(FitResult, r.fit) for r in fitted]), limits),
                        strict=True):
            r.verdict = v
    for r in results:
        if not r.ok:
            r.verdict = Verdict(False, [Reason("unfitted", r.message)], {})


def recalibrate(sessions: Sequence[Source], model: str | int = "12", *, chunk_size: int = 256,
                progress: Callable[[int], None] | None = None, limits: Limits | None = None) -> BatchReport:
    """Fit every board of ``sessions`` ((source, Session or read error) pairs) with ``model``;
    with ``limits``, judge each board (``BoardResult.verdict``).

    Results come back in input order; ``progress(n)`` is called as n more boards are done.
    """
    model = check_model(model)
    t0 = _time.perf_counter()

    def tick(n: int) -> None:
        if progress and n:
            progress(n)

    results, groups, multi_temp = _screen_all(sessions, model)
    tick(len(results))
    calls = 0
    for group in groups:
        for k in range(0, len(group), chunk_size):
            part = group[k:k + chunk_size]
            # _fit_stack gives one result per board, in order
            for (i, _, _), r in zip(part, _fit_stack([(src, s) for _, src, s in part], model), strict=True):
                results[i] = r
            calls += 1
            tick(len(part))
    for i, src, s in multi_temp:
        results[i] = _fit_temperature(src, s, model)
        calls += 1
        tick(1)
    ordered = [results[i] for i in range(len(sessions))]
    for r in ordered:
        if r.ok:
            r.fitted_calibration.metadata = {"source": r.source, "serial": r.serial, "run_id": r.run_id,
                                             "pose_count": r.pose_count, "recalibrated_by": "accelcal batch",
                                             "recalibrated_at": iso(_time.time()),
                                             **({"held": [h.to_json() for h in r.held]} if r.held else {})}
    if limits is not None:
        _judge(ordered, limits)
    return BatchReport(model, ordered, calls, _time.perf_counter() - t0,
                       None if limits is None else dict(limits.values))


# -- outputs ---------------------------------------------------------------------------------

def _file_stem(r: BoardResult) -> str:
    stem = f"run{r.run_id}" + (f"-{r.serial}" if r.serial else "") if r.run_id is not None else Path(r.source).stem
    return re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._") or "board"


def write_calibrations(report: BatchReport, out_dir: str | Path, force: bool = False,
                       protected: Iterable[Named] = ()) -> dict[str, Path]:
    """One calibration JSON per fitted board in ``out_dir`` (atomic writes); source -> path.

    Files are named for the board (pose table name, or ``runN-SERIAL``); a name taken
    by an earlier board of the same batch gets ``-2``, ``-3``...; files from earlier
    batches are replaced.
    """
    d = Path(out_dir)
    if d.exists() and not d.is_dir():
        raise DataError(f"--out-dir {d}: exists and is not a directory")
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DataError(f"--out-dir {d}: cannot create ({e.strerror})") from None
    taken: set[str] = set()
    plan: list[tuple[BoardResult, Path]] = []
    for r in report.fitted:
        stem = base = _file_stem(r)
        n = 1
        while stem in taken:
            n += 1
            stem = f"{base}-{n}"
        taken.add(stem)
        plan.append((r, d / f"{stem}.json"))
    # a calibration never replaces a board's own input (a pose table named like the JSON it would get)
    refuse_overwrite([("--out-dir file", p, "json") for _, p in plan],
                     [*(("input", r.source) for r in report.results), *protected], force)
    out: dict[str, Path] = {}
    for r, path in plan:
        try:
            r.fitted_calibration.save(path)
        except AccelcalError as e:
            raise DataError(f"{path}: cannot write ({e})") from None
        out[r.source] = path
    return out


CSV_COLUMNS = ("source", "serial", "run_id", "ok", "message", "model", "pose_count", "residual_rms_mg",
               "residual_max_mg", "crossval_rms_mg", "crossval_by_orientation_rms_mg", "condition_number", "held",
               *PARAM_NAMES)


def summary_csv(report: BatchReport, path: str | Path | None = None) -> str:
    """One row per board (skipped ones too, with their reason); written atomically to ``path``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    mg = lambda v: "" if v is None else repr(v * 1e3)  # noqa: E731
    for r in report.results:
        params = param_vector(r.fitted_calibration.to_dict()).tolist() if r.ok else [""] * len(PARAM_NAMES)
        w.writerow(safe_row([r.source, r.serial or "", "" if r.run_id is None else r.run_id, int(r.ok), r.message,
                             r.model, r.pose_count, mg(r.residual_rms_g), mg(r.residual_max_g), mg(r.crossval_rms_g),
                             mg(r.crossval_by_orientation_rms_g),
                             "" if r.condition_number is None else repr(r.condition_number),
                             "; ".join(h.term for h in r.held), *map(str, params)]))  # no cell a formula (cells.py)
    text = buf.getvalue()
    if path is not None:
        atomic_write(Path(path), text)
    return text


def record_in_store(report: BatchReport, store: Store, *, source_store: str | Path | None = None,
                    config_text: str | None = None) -> StoreCounts:
    """Record the batch in ``store``; returns counts of what was recorded.

    A board read from this same store gets a ``recalibration`` event on its source run
    (``recalibration_skipped`` with the reason when it could not be fitted), so lot
    summaries do not count it twice.  Any other board with its session becomes a new
    complete run (station ``accelcal-batch``) as a station records one: poses, calibration,
    verdict, reasons, the measured figures and the limits it was judged by (``config_text``:
    the --config it came from); a board that could not be fitted is recorded only when judged
    (FAIL, reason ``unfitted``), so the line's yield counts it.
    """
    same = source_store is not None and store_identity(source_store) == store.identity
    events = runs = 0
    for r in report.results:
        v = r.verdict
        measured = {} if v is None else {k: float(x) for k, x in v.measured.items() if np.isfinite(x)}
        judged = {} if v is None else {"verdict": v.label, "reasons": [x.to_dict() for x in v.reasons],
                                       "measured": measured, "limits": report.limits}
        if same and r.run_id is not None:
            data = {"model": r.model, **judged,
                    **({"calibration": r.fitted_calibration.to_dict(), **r.fit_summary()} if r.ok else {})}
            store.log_event(r.run_id, "recalibration" if r.ok else "recalibration_skipped",
                            r.message if not r.ok else f"model {r.model} by accelcal batch", data)
            events += 1
        elif r.session is not None and (r.ok or v is not None):
            s = r.session
            rid = store.start_run(device_serial=r.serial, chip=s.metadata.get("chip"), station_id=BATCH_STATION,
                                  lot=s.metadata.get("lot"), model=r.model, units=s.units,
                                  counts_per_g=s.counts_per_g, gravity_mps2=s.gravity_mps2, config_text=config_text)
            summary = {**r.fit_summary(), **({"measured": measured, "reason_codes": codes(v.reasons)} if v else {})}
            store.finish_run(rid, session=s, calibration=r.calibration, verdict=None if v is None else v.label,
                             reasons=() if v is None else v.reasons, fit_summary=summary, model=r.model,
                             limits=report.limits if v is not None else None)
            runs += 1
    return {"events": events, "runs": runs}

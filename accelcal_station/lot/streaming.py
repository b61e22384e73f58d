"""Streaming batch recalibration of a lot file: read a chunk, fit it stacked, judge it, write it.

Peak memory is one chunk's (``chunk_boards`` boards) whatever the lot size.  Each
chunk's results are appended to a temporary file beside the output, which is
flushed once per chunk, fsynced and renamed over the output at the end: the
results file is whole or absent after a crash, never half written.
"""
from __future__ import annotations

import time as _time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict, TypeVar

import numpy as np

from ..acceptance.reasons import Reason
from ..data.lotfile import LotChunk, board_arrays, lot_scale, lot_site_g, nonfinite_rows, open_lot
from ..data.results_table import ChunkFit, ResultsWriter
from ..errors import AccelcalError, DataError
from ..models.fitting import check_model, fit_batch
from ..models.gravity_norm import nominal_scale
from ..models.held import Held
from ..models.result import BatchFit
from ..models.sanity import distinct_directions_batch
from ..models.screening import directions_apart


class SkippedJson(TypedDict):
    serial: str
    reason: str


# ``LotSummary.to_dict``: `accelcal batch LOT --json`'s summary ("pass" is a keyword: the functional form)
LotSummaryJson = TypedDict("LotSummaryJson", {
    "model": str, "boards": int, "fitted": int, "skipped": int, "pass": int, "fail": int, "elapsed_s": float,
    "boards_per_s": float, "skipped_examples": list[SkippedJson]})


if TYPE_CHECKING:  # the rules (and the config schema, pydantic, under them) load only when a lot is judged
    from ..acceptance.rules import FitFigures, Limits

_R = TypeVar("_R", bound=str)


@dataclass
class LotSummary:
    model: str
    boards: int = 0
    fitted: int = 0
    passed: int = 0
    failed: int = 0
    elapsed_s: float = 0.0
    unfitted_examples: list[tuple[str, str]] = field(default_factory=list)  # first few (serial, reason)

    @property
    def boards_per_s(self) -> float:
        return self.boards / self.elapsed_s if self.elapsed_s > 0 else float("nan")

    def to_dict(self) -> LotSummaryJson:
        return {"model": self.model, "boards": self.boards, "fitted": self.fitted,
                "skipped": self.boards - self.fitted, "pass": self.passed, "fail": self.failed,
                "elapsed_s": self.elapsed_s, "boards_per_s": self.boards_per_s,
                "skipped_examples": [{"serial": s, "reason": r} for s, r in self.unfitted_examples]}


def fit_chunk(chunk: LotChunk, model: str, per_g: float | None, units: str, site_g: float = 1.0) -> ChunkFit:
    """Fit every board of a chunk: a ChunkFit of per-board arrays (``site_g``: the site's gravity in
    standard g, every reference scaled by it: config/site.py)."""
    x, ref, noise, reasons = board_arrays(chunk, model)
    if ref is not None and site_g != 1.0:
        ref = ref * site_g
    starts = chunk.starts
    B = len(starts) - 1
    sizes = np.diff(starts)
    out: ChunkFit = {
        "ok": np.zeros(B, bool), "W": np.full((B, 3, 3), np.nan), "V": np.full((B, 3), np.nan),
        "Gamma": np.full((B, 3), np.nan), "residual_rms_g": np.full(B, np.nan), "residual_max_g": np.full(B, np.nan),
        "crossval_rms_g": np.full(B, np.nan), "crossval_by_orientation_rms_g": np.full(B, np.nan),
        "distinct_orientations": np.zeros(B, int), "condition_number": np.full(B, np.nan),
        "stderr_V_max": np.full(B, np.nan), "stderr_W_max": np.full(B, np.nan), "input_per_g": np.full(B, np.nan),
        "pose_count": sizes, "distinct_poses": np.zeros(B, int), "held": [[]] * B,  # replaced per board
        "message": []}
    can = np.array([r is None for r in reasons], bool)
    has_noise = np.zeros(B, bool)
    bad_noise = None if noise is None or not B else nonfinite_rows(noise)
    if noise is not None and B:
        has_noise = np.ones(B, bool) if bad_noise is None else np.logical_and.reduceat(~bad_noise, starts[:-1])
    fit_sizes = sizes[can]
    # one pose count (the usual lot) without np.unique, whose first call imports numpy.ma
    for P in fit_sizes[:1] if len(fit_sizes) and (fit_sizes == fit_sizes[0]).all() else np.unique(fit_sizes):
        for nz_flag in (False, True):
            idx = np.flatnonzero(can & (sizes == P) & (has_noise == nz_flag))
            if idx.size:
                _fit_group(idx, int(P), ChunkReadings(x, ref, noise if nz_flag else None, starts),
                           LotScale(model, per_g, units, site_g), out, reasons)
    out["message"] = ["" if r is None else r for r in reasons]
    return out


@dataclass(frozen=True)
class ChunkReadings:
    """A chunk's pose rows as data.lotfile.board_arrays gives them (readings, references in g, stated
    per-sample std; None where the lot has none) and the row where each board starts (B + 1)."""

    x: np.ndarray
    ref: np.ndarray | None
    noise: np.ndarray | None
    starts: np.ndarray


@dataclass(frozen=True)
class LotScale:
    """How a lot's readings are fitted: the model, the input units per g (None: each board's nominal
    scale) and the units' name (for the messages)."""

    model: str
    per_g: float | None
    units: str
    site_g: float = 1.0  # the site's gravity in standard g: model 9's calibrated norm (models/site_norm.py)


def _fit_group(idx: np.ndarray, P: int, readings: ChunkReadings, how: LotScale, out: ChunkFit,
               reasons: list[str | None]) -> None:
    """Fit the boards ``idx`` (all with ``P`` poses) in one stacked fit into ``out``; a board that
    cannot be fitted gets its reason."""
    x, ref, noise = readings.x, readings.ref, readings.noise
    model, per_g, units = how.model, how.per_g, how.units
    rows = _BoardRows(idx, P, readings.starts)
    xs = rows.take(x)
    if per_g is None:
        scale = nominal_scale(xs)
        gf = xs / scale[:, None, None]
    else:  # one scale for the lot: a scalar division (the same numbers as by a column of it)
        scale = np.full(len(idx), per_g)
        gf = xs / per_g
    if model != "9":
        implausible = ~_plausible_g(gf)
        med = np.zeros(len(gf))
        med[implausible] = np.median(np.linalg.norm(gf[implausible], axis=-1), axis=1)
        for k in np.flatnonzero(implausible):
            hint = "counts given as g? use --units counts --counts-per-g N" if med[k] > 3 else "wrong counts_per_g?"
            reasons[idx[k]] = (f"readings in {units} have a median norm of {med[k]:.4g} g, expected about 1 g "
                               f"({hint})")
        keep = ~implausible
        rows.keep(keep)
        idx, gf, scale = idx[keep], gf[keep], scale[keep]
        if not idx.size:
            return
    nz = None if noise is None else (rows.take(noise) / per_g if per_g is not None
                                     else rows.take(noise) / scale[:, None, None])
    try:
        # ref is None only when board_arrays gave every board a reason (models 6/12/15 need one)
        # the one front of every path (models.fitting.fit_batch): identifiability, absurd
        # readings and coefficients, then the stacked estimator; readings already in g here
        b = fit_batch(gf, None if model == "9" or ref is None else rows.take(ref), model, units="g", noise=nz,
                      norm_g=how.site_g if model == "9" else 1.0)
    except AccelcalError as e:
        for i in idx:
            reasons[i] = str(e)
        return
    for k in np.flatnonzero(~b.ok):
        reasons[idx[k]] = b.messages[k] or f"model {model} could not be fitted"
    _put(out, b, idx, scale, gf, None if ref is None else rows.take(ref))


class _BoardRows:
    """The rows of boards ``idx`` (each of P poses) of a chunk's per-row arrays: gathered by an
    index (n, P), or, when they are consecutive boards end to end (a clean chunk), as a view."""

    def __init__(self, idx: np.ndarray, P: int, starts: np.ndarray):
        first = starts[idx]
        self.index = first[:, None] + np.arange(P)
        self.P = P
        n = idx.size
        self.start: int | None = int(first[0]) if n and starts[idx[-1] + 1] - first[0] == P * n \
            and idx[-1] - idx[0] == n - 1 else None

    def take(self, a: np.ndarray) -> np.ndarray:
        """(n, P, 3) of the per-row (rows, 3) array ``a``."""
        if self.start is None:
            return a[self.index]
        return a[self.start:self.start + self.index.size].reshape(-1, self.P, a.shape[-1])

    def keep(self, mask: np.ndarray) -> None:
        """Only the boards where ``mask``."""
        if not mask.all():
            self.index, self.start = self.index[mask], None


def _put(out: ChunkFit, b: BatchFit, idx: np.ndarray, scale: np.ndarray, gf: np.ndarray,
         ref: np.ndarray | None) -> None:
    """The fitted boards' figures into ``out`` (``idx``: their rows of the chunk's arrays; ``ref``
    (D, P, 3) their nominal references, or None)."""
    ok = b.ok
    every = bool(ok.all())
    pick: Callable[[np.ndarray], np.ndarray] = (lambda a: a) if every else (lambda a: a[ok])
    rows = idx[ok]
    # every board of the chunk (the usual group): slices, not index arrays
    sel: slice | np.ndarray = slice(None) if len(rows) == len(out["ok"]) else rows
    out["ok"][sel] = True
    out["W"][sel], out["V"][sel], out["Gamma"][sel] = pick(b.W), pick(b.V), pick(b.Gamma)
    out["residual_rms_g"][sel] = pick(b.residual_rms_g)
    out["residual_max_g"][sel] = _abs_max(pick(b.residuals_g))
    out["crossval_rms_g"][sel] = np.where(pick(b.crossval_ok), pick(b.crossval_rms_g), np.nan)
    if b.crossval_by_orientation_rms_g is not None and b.crossval_by_orientation_ok is not None:
        out["crossval_by_orientation_rms_g"][sel] = np.where(pick(b.crossval_by_orientation_ok),
                                                             pick(b.crossval_by_orientation_rms_g), np.nan)
    if b.distinct_orientations is not None:
        out["distinct_orientations"][sel] = pick(b.distinct_orientations)
    out["condition_number"][sel] = pick(b.condition_number)
    se = pick(b.stderr_ok)
    out["stderr_V_max"][sel] = np.where(se, pick(b.stderr_V).max(axis=1), np.nan)
    out["stderr_W_max"][sel] = np.where(se, pick(b.stderr_W).reshape(-1, 9).max(axis=1), np.nan)
    out["input_per_g"][sel] = pick(scale)
    # the nominal references certify most boards' poses distinct without comparing pairs (exact)
    g_ok = pick(gf)
    if b.poses_apart is not None:  # certified by fit_batch's screen
        apart = pick(b.poses_apart)
    else:
        apart = directions_apart(g_ok, ref if every or ref is None else ref[ok])
    out["distinct_poses"][sel] = distinct_directions_batch(g_ok, apart=apart)
    if any(b.held):  # terms held at nominal (models/held.py), as `accelcal fit`
        for k in np.flatnonzero(np.array([bool(h) for h in b.held]) & ok):
            out["held"][idx[k]] = b.held[k]


def _abs_max(r: np.ndarray) -> np.ndarray:
    """(D,) the largest |residual| of each board's (D, P, 3) residuals; the stacked fitters give
    them as a view of a boards-last (3, P, D) array, reduced as stored (no transposed copy)."""
    t = r.transpose(2, 1, 0)
    if t.flags.c_contiguous:
        return np.maximum(t.max(axis=(0, 1)), -t.min(axis=(0, 1)))
    return np.max(np.abs(r), axis=(1, 2))


def _plausible_g(gf: np.ndarray) -> np.ndarray:
    """(B,) the median reading norm of each board is 0.3 to 3 g: decided for most boards by every
    squared norm lying in 0.1 to 8.9 g^2 (no median needed), by the median itself for the rest."""
    sq = np.einsum("bpk,bpk->bp", gf, gf)
    sure = np.all((sq >= 0.1) & (sq <= 8.9), axis=1)
    out = sure.copy()
    rest = np.flatnonzero(~sure)
    if rest.size:
        med = np.median(np.linalg.norm(gf[rest], axis=-1), axis=1)
        out[rest] = (med >= 0.3) & (med <= 3.0)
    return out


def figures(res: Mapping[str, np.ndarray], held: list[list[Held]], model: str) -> FitFigures:
    """The acceptance rules' inputs for a chunk's boards (NaN where a board was not fitted); the
    held-out figure by orientation where a board revisits an orientation (models/crossval.py)."""
    from ..acceptance.rules import FitFigures

    repeat = res["distinct_orientations"] < res["pose_count"]
    cv = np.where(repeat, res["crossval_by_orientation_rms_g"], res["crossval_rms_g"]) if repeat.any() \
        else res["crossval_rms_g"]
    return FitFigures(model, res["W"], res["V"], res["Gamma"], res["residual_rms_g"], res["residual_max_g"],
                      cv, res["stderr_V_max"], res["stderr_W_max"], res["distinct_poses"],
                      [[h.text for h in hs] for hs in held] if any(held) else None)


def judge_chunk(res: ChunkFit, limits: Limits | None, model: str) -> tuple[list[str], list[Sequence[Reason]]]:
    """Verdict and reasons per board by acceptance.judge_all ("" verdict: no limits given).

    A board that could not be fitted FAILs with reason ``unfitted: <why>``; verify_error_max_mg
    needs a verification capture and is not judged here.  A board with no reason shares one empty
    tuple (no list is built per passing board).
    """
    return _judge(res, limits, model, Reason.of)


def _judge(res: ChunkFit, limits: Limits | None, model: str, word: Callable[[str, str], _R]
           ) -> tuple[list[str], list[Sequence[_R]]]:
    """``judge_chunk`` with each reason made by ``word(code, text)``: a Reason, or the text alone
    where only the words are written (the results table)."""
    ok = res["ok"]
    B = len(ok)
    reasons: list[Sequence[_R]] = [()] * B
    unfitted = np.flatnonzero(~ok)
    for b in unfitted.tolist():
        reasons[b] = [word("unfitted", f"unfitted: {res['message'][b]}")]
    if limits is None:
        verdict = np.where(ok, "", "FAIL")
        return verdict.tolist(), reasons
    from ..acceptance.rules import limit_failures, measure_all

    fitted = np.flatnonzero(ok)
    failing = ~ok
    if fitted.size:
        every = fitted.size == B  # the usual chunk: the figures are the chunk's own arrays
        pick: Callable[[np.ndarray], np.ndarray] = (lambda a: a) if every else (lambda a: a[fitted])
        sub = {"W": pick(res["W"]), "V": pick(res["V"]), "Gamma": pick(res["Gamma"]),
               "residual_rms_g": pick(res["residual_rms_g"]), "residual_max_g": pick(res["residual_max_g"]),
               "crossval_rms_g": pick(res["crossval_rms_g"]),
               "crossval_by_orientation_rms_g": pick(res["crossval_by_orientation_rms_g"]),
               "distinct_orientations": pick(res["distinct_orientations"]), "pose_count": pick(res["pose_count"]),
               "stderr_V_max": pick(res["stderr_V_max"]), "stderr_W_max": pick(res["stderr_W_max"]),
               "distinct_poses": pick(res["distinct_poses"])}
        held = res["held"] if every else [res["held"][b] for b in fitted]
        figs = figures(sub, held, model)
        # the verdict's reasons over the whole chunk (limit_failures, as judge_all gives them), with
        # no per-board Verdict or list built: a lot row keeps only the label and the reasons
        for idx, code, texts in limit_failures(measure_all(figs), np.asarray(figs.distinct_poses, dtype=int),
                                               model, limits):
            rows = fitted[idx]
            failing[rows] = True
            for b, t in zip(rows.tolist(), texts, strict=True):
                prev: Sequence[_R] = reasons[b]
                reasons[b] = [*prev, word(code, t)]
    return np.where(failing, "FAIL", "PASS").tolist(), reasons


def _text(code: str, text: str) -> str:
    return text


def recalibrate_lot(path: str | Path, out: str | Path, model: str = "12", *, units: str | None = None,
                    counts_per_g: float | None = None, gravity_mps2: float | None = None,
                    limits: Limits | None = None, chunk_boards: int = 4096,
                    progress: Callable[[int], None] | None = None) -> LotSummary:
    """Fit every board of a lot file and write one results table (CSV, Parquet or JSON lines)."""
    model = check_model(model)
    if chunk_boards < 1:
        raise DataError(f"--chunk-boards {chunk_boards}; allowed: a whole number >= 1")
    meta, chunks = open_lot(path, chunk_boards)
    units, per_g = lot_scale(meta, path, units, counts_per_g, gravity_mps2, model)
    site_g = lot_site_g(meta, path, gravity_mps2)
    summary = LotSummary(model)
    t0 = _time.perf_counter()
    with ResultsWriter(out) as w:
        for chunk in chunks:
            res = fit_chunk(chunk, model, per_g, units, site_g)
            verdicts, reasons = _judge(res, limits, model, _text)  # the table keeps the words only
            w.write_chunk(chunk, res, model, units, verdicts, reasons)
            n = len(chunk.serials)
            summary.boards += n
            summary.fitted += int(res["ok"].sum())
            summary.passed += verdicts.count("PASS")
            summary.failed += verdicts.count("FAIL")
            for b in np.flatnonzero(~res["ok"])[:max(0, 5 - len(summary.unfitted_examples))]:
                summary.unfitted_examples.append((chunk.serials[b], res["message"][b]))
            if progress:
                progress(n)
        if summary.boards == 0:  # raised inside: the writer then leaves no output file
            raise DataError(f"{path}: no boards (no rows after the header)")
    summary.elapsed_s = _time.perf_counter() - t0
    return summary

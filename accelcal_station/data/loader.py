"""One loader for every command (`fit`, `batch`, `diagnose`): a pose table or a raw log
in, a Session out, with what was inferred and why.

Units, when neither the command line nor the file states them, are judged from the
median norm of the static readings: about 1 -> g, about 9.8 -> m/s^2, more than 20 ->
counts.  Unsigned (offset-binary) counts, every reading within half the range of the
mid-scale code 2^(b-1), have the mid-scale subtracted first.  Counts with no counts
per g get the nearest power of two to the readings' radius when within 5 % (datasheet
sensitivities are powers of two), else the radius itself; the fit's W absorbs the rest.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ..config.site import MEASURED_U_MPS2, STANDARD_SITE, Site
from ..conventions import units_per_g
from ..errors import AccelcalError, DataError, UnitsError
from ..models.gravity_norm import nominal_scale
from ..session import PoseColumns, PoseRecord, Session
from .log_info import LogInfo
from .posetable import read_pose_table, stated_scale, table_metadata
from .rawlog import MAX_ABS_READING, RawLog, read_raw_log, read_text_file
from .sample_grid import REPEAT_MIN, repeat_fraction
from .static_poses import StaticDetection, static_session

MAX_TEXT_NOTED = 50  # prose lines listed by line and text (a count says how many in all)

G_RANGE = (0.5, 2.0)  # median norm of readings in g
MPS2_RANGE = (5.0, 20.0)  # in m/s^2
COUNTS_MIN = 20.0  # counts per g of any real accelerometer exceed this
POW2_TOL = 0.05
OFFSET_BINARY_BITS = (8, 10, 12, 14, 16, 20, 24, 32)
MPS2_PER_G = 9.80665
# one fit's poses, as data.posetable.MAX_POSE_ROWS: fit memory is linear in their count
# (benchmarks/bench_resources.py: under 200 MB at 100,000)
MAX_POSES = 200_000


def check_pose_count(session: Session, path: str | Path) -> None:
    """Refuse more poses than one fit takes (MAX_POSES), before any fit allocates for them."""
    if len(session) > MAX_POSES:
        raise DataError(f"{path}: {len(session)} poses; one fit takes at most {MAX_POSES} (its fit "
                        "takes time and memory with the pose count; a run has tens); fit a lot of boards with "
                        "accelcal batch LOT --out RESULTS")


@dataclass(frozen=True)
class UnitsJudgement:
    """The units of the readings, the counts per g and the mid-scale subtracted, with the reason."""

    units: str
    counts_per_g: float | None
    offset_counts: float
    reason: str


@dataclass
class Loaded:
    """A loaded file: its Session, the raw log and its segmentation (raw logs only), and what was inferred."""

    session: Session
    units: UnitsJudgement
    log: RawLog | None = None
    detection: StaticDetection | None = None
    inferred: list[str] = field(default_factory=list)
    table_text_lines: list[tuple[int, str]] = field(default_factory=list)  # prose skipped in a pose table

    def to_json(self) -> dict:
        out: dict = {"units": self.units.units, "counts_per_g": self.units.counts_per_g,
                     "offset_counts": self.units.offset_counts, "units_reason": self.units.reason}
        if self.table_text_lines:
            out["text_lines_skipped"] = len(self.table_text_lines)
            out["text_lines"] = [{"line": n, "text": t} for n, t in self.table_text_lines[:MAX_TEXT_NOTED]]
        if self.log is not None:
            i = self.log.info
            out.update({"skipped_rows": i.skipped_rows, "preamble": i.preamble, "rate_hz": self.log.rate_hz,
                        "rate_source": i.rate_source, "time_unit": i.time_unit, "columns": i.axis_names,
                        "text_lines_skipped": len(i.text_lines),
                        "text_lines": [{"line": n, "text": t} for n, t in i.text_lines[:MAX_TEXT_NOTED]],
                        "repeated_fraction": repeat_fraction(self.log.xyz),
                        "decimals": i.decimals})
        return out


def offset_binary_midscale(x: np.ndarray) -> float:
    """2^(b-1) when every reading sits within half the range of that mid-scale code, else 0.

    A signed sensor cannot do this: all three axes at +0.5..1.5 of half its full scale
    in every pose would need a norm near its full scale in every orientation.
    """
    if x.size == 0 or np.min(x) < 0:
        return 0.0
    top = float(np.max(x))
    for b in OFFSET_BINARY_BITS:
        if top < 2.0**b:
            o = 2.0 ** (b - 1)
            return o if np.all((x > 0.5 * o) & (x < 1.5 * o)) else 0.0
    return 0.0


def _counts_per_g(x: np.ndarray) -> tuple[float, str]:
    r = float(nominal_scale(x[None])[0]) if len(x) > 1 else float(np.linalg.norm(x[0]))
    if len(x) > 1 and np.ptp(x, axis=0).max() < 0.5 * r:  # one orientation: the mid-range is no centre
        r = float(np.median(np.linalg.norm(x, axis=1)))
    p2 = 2.0 ** round(math.log2(r))
    if abs(r / p2 - 1) <= POW2_TOL:
        return p2, f"{p2:g} counts/g, the power of two nearest the readings' {r:.5g} ({100 * (r / p2 - 1):+.1f} %)"
    return float(f"{r:.4g}"), f"{float(f'{r:.4g}'):g} counts/g estimated from the readings' norm"


def judge_units(readings: ArrayLike, units: str | None = None, counts_per_g: float | None = None,
                stated_by: str = "") -> UnitsJudgement:
    """Units of static readings (P, 3): given ones are kept, else judged from the norm (module doc)."""
    x = np.asarray(readings, dtype=float)
    off = offset_binary_midscale(x) if units in (None, "counts") else 0.0
    xc = x - off
    ob = f"unsigned counts (every reading near mid-scale {off:g}), {off:g} subtracted; " if off else ""
    with np.errstate(all="ignore"):
        med = float(np.median(np.linalg.norm(xc, axis=1)))
    if units is None:
        if G_RANGE[0] <= med <= G_RANGE[1]:
            units, why = "g", f"median norm {med:.4g}: g"
        elif MPS2_RANGE[0] <= med <= MPS2_RANGE[1]:
            units, why = "mps2", f"median norm {med:.4g}: m/s^2"
        elif med > COUNTS_MIN:
            units, why = "counts", f"median norm {med:.5g}: counts"
        else:
            raise DataError(f"median norm of the readings {med:.4g}: not g (about 1), m/s^2 (about 9.8) or counts "
                            "(more than 20); give --units counts|g|mps2")
    else:
        why = f"{units} ({stated_by or 'given'})"
        per_g = {"g": 1.0, "mps2": MPS2_PER_G}.get(units)
        if per_g is not None and not (0.3 <= med / per_g <= 3.0):  # models.fitting.check_plausible_g's range
            hint = ("counts given as g? use --units counts --counts-per-g N" if med / per_g > 3
                    else "readings in another unit? give --units counts|g|mps2")
            raise UnitsError(f"readings in {units} have a median norm of {med / per_g:.4g} g, expected about "
                             f"1 g ({hint}; units {stated_by or 'given'})")
    cpg = counts_per_g
    if units == "counts" and cpg is None:
        cpg, how = _counts_per_g(xc)
        why += f"; {how}"
    elif units == "counts":
        why += f"; {cpg:g} counts/g given"
    return UnitsJudgement(units, cpg, off, ob + why)


def _apply(session: Session, j: UnitsJudgement, gravity_mps2: float | None) -> Session:
    """The session in its judged units, at its site: ``gravity_mps2`` (--gravity, or the file's
    ``# gravity_mps2:`` line) is the site's gravity, every reference scaled to it (config/site.py), so
    the fit maps the input to standard g; m/s^2 are then turned into g by standard gravity."""
    poses: Sequence[PoseRecord]
    grav = session.gravity_mps2 if session.gravity_mps2 is not None else gravity_mps2
    site = STANDARD_SITE if grav is None else Site(units_per_g("mps2", gravity_mps2=grav), "measured",
                                                    MEASURED_U_MPS2)
    k = site.gravity_g
    if isinstance(session.poses, PoseColumns):  # a large table stays columns (session.py)
        cols = session.poses.shifted(j.offset_counts) if j.offset_counts else session.poses
        poses = cols.scaled_references(k) if k != 1.0 else cols
    else:
        poses = list([replace(p, mean=p.mean - j.offset_counts) for p in session.poses] if j.offset_counts
                     else session.poses)
        if k != 1.0:
            poses = [p if p.reference_g is None else replace(p, reference_g=p.reference_g * k) for p in poses]
    meta = {**session.metadata, "site": site.to_json()}
    return Session(poses, j.units, j.counts_per_g, MPS2_PER_G if j.units == "mps2" else None, session.device, meta)


def load_pose_table(path: str | Path, units: str | None = None, counts_per_g: float | None = None,
                    gravity_mps2: float | None = None, references: bool = False) -> Loaded:
    """A pose table with its units judged as every command judges them."""
    meta = table_metadata(path)
    notes: list[tuple[int, str]] = []
    session = read_pose_table(path, units or meta.get("units") or "counts", counts_per_g, gravity_mps2,
                              references=references, notes=notes)
    check_pose_count(session, path)
    big = np.argwhere(np.abs(session.readings) > MAX_ABS_READING)
    if big.size:
        p, a = big[0]
        raise DataError(f"{path}: pose {session.names[p]!r}, column {'xyz'[a]}: {session.readings[p, a]:g}; "
                        f"allowed: a reading within +-{MAX_ABS_READING:g}")
    stated = units or meta.get("units")
    by = "--units" if units else "stated in the file ('# units:')"
    cpg = counts_per_g if counts_per_g is not None else session.counts_per_g
    try:
        j = judge_units(session.readings, stated, cpg, by)
    except AccelcalError as e:
        raise type(e)(f"{path}: {e}") from None
    said = [_text_note(notes)] if notes else []
    return Loaded(_apply(session, j, gravity_mps2), j, inferred=[*said, f"units: {j.reason}"],
                  table_text_lines=notes)


def _text_note(lines: list[tuple[int, str]]) -> str:
    """The prose lines skipped (banner, prompts, repeated header), the first three by line and text."""
    shown = ", ".join(f"{n} {t[:40]!r}" for n, t in lines[:3])
    more = f" and {len(lines) - 3} more" if len(lines) > 3 else ""
    return (f"skipped {len(lines)} text line{'s' if len(lines) != 1 else ''} among the data "
            f"(banner, prompts, repeated header: line {shown}{more})")


def load_raw_log(path: str | Path, units: str | None = None, counts_per_g: float | None = None,
                 gravity_mps2: float | None = None, columns: str | list[str] | None = None,
                 skip_rows: int | None = None, rate_hz: float | None = None) -> Loaded:
    """A raw log: data block, rate, columns and units found, static poses segmented."""
    log = read_raw_log(path, columns, skip_rows, rate_hz)
    info = log.info
    # "# units:" / "# counts_per_g:" / "# gravity:" lines honoured or refused as a pose table's are
    said, counts_per_g, gravity_mps2 = stated_scale(path, info.stated, info.stated_line, units, counts_per_g,
                                                    gravity_mps2)
    in_file = units is None and said is not None
    units = said
    if info.units_hint == "mg" and units is None:  # milli-g: g after / 1000
        log.xyz = log.xyz / 1000.0
        info.units_hint = "g"
    session, det = static_session(log, units or info.units_hint or "counts", counts_per_g, gravity_mps2)
    check_pose_count(session, path)
    stated = units or info.units_hint
    by = ("stated in the file ('# units:')" if in_file else "--units") if units \
        else f"named in the header ({info.axis_names.get('x')!r})"
    try:
        j = judge_units(session.readings, stated, counts_per_g, by)
    except AccelcalError as e:
        raise type(e)(f"{path}: {e}") from None
    if j.offset_counts:
        log.xyz = log.xyz - j.offset_counts
    return Loaded(_apply(session, j, gravity_mps2), j, log, det, _inferred(log, j))


def _inferred(log: RawLog, j: UnitsJudgement) -> list[str]:
    i: LogInfo = log.info
    out = []
    if i.skipped_rows:
        pre = "; ".join(f"{k}={v}" if v else k for k, v in list(i.preamble.items())[:6])
        out.append(f"skipped {i.skipped_rows} row{'s' if i.skipped_rows != 1 else ''} before the data"
                   + (f" ({pre})" if pre else ""))
    if i.text_lines:
        out.append(_text_note(i.text_lines))
    rep = repeat_fraction(log.xyz)
    if rep > REPEAT_MIN:
        out.append(f"{100 * rep:.0f} % of consecutive samples repeat the previous one (the host read faster than "
                   "the chip updates): each pose's noise is judged on its distinct samples")
    if log.rate_hz:
        out.append(f"rate {log.rate_hz:.6g} Hz from {i.rate_source}"
                   + (f"; time in {i.time_unit}: {i.time_unit_reason}" if log.has_time else ""))
    else:
        out.append("rate unknown (no time column, no stated rate, no --rate): times are sample numbers")
    out.append("columns: " + ", ".join(f"{a} = {i.axis_names[a]!r}" for a in "txyz" if a in i.axis_names))
    out.append(f"units: {j.reason}")
    return out


def load(path: str | Path, raw: bool = False, *, units: str | None = None, counts_per_g: float | None = None,
         gravity_mps2: float | None = None, columns: str | list[str] | None = None, skip_rows: int | None = None,
         rate_hz: float | None = None, references: bool = False) -> Loaded:
    """A pose table, or with ``raw`` a raw log (the options that only raw logs take are refused otherwise)."""
    if raw:
        return load_raw_log(path, units, counts_per_g, gravity_mps2, columns, skip_rows, rate_hz)
    for flag, v in (("--columns", columns), ("--skip-rows", skip_rows)):
        if v is not None:
            raise DataError(f"{flag} is for raw sample logs; add --raw to read {path} as one")
    try:
        return load_pose_table(path, units, counts_per_g, gravity_mps2, references)
    except DataError as e:
        if _raw_looking(str(e)):
            raise DataError(f"{e}; if {path} is a raw sample log, add --raw") from None
        raise


def _raw_looking(message: str) -> bool:
    """A pose-table header refusal that a raw sample log gives: a number as a column name (a log with
    no header) or a column a pose table does not have (acc_x, time, ...) with x, y, z or pose missing."""
    return "unknown column" in message or "missing column" in message


__all__ = ["Loaded", "UnitsJudgement", "judge_units", "load", "load_pose_table", "load_raw_log",
           "offset_binary_midscale", "read_text_file"]

"""A lot file: one long table of every pose of every board of a lot, streamed in chunks.

::

    # units: counts
    # counts_per_g: 4096
    serial,pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,temp_c,n,std_x,std_y,std_z
    B000001,p1,0,0,12.1,-30.2,4101.7,,,,25.0,200,3.1,2.9,4.0
    ...

The columns are a pose table's (posetable.COLUMNS) plus ``serial``; a board's rows
are contiguous.  CSV always; Parquet through pyarrow (the ``parquet`` extra).  Rows
are read in blocks, cut at board boundaries, and fitted as a chunk with the stacked
fitters (models/stacked.py), so memory stays bounded whatever the lot size.

A board that cannot be fitted (a bad cell, a NaN reading, a missing reference,
poses at several temperatures, too few or degenerate poses) is returned with
``ok`` False and its reason: never dropped.
"""
from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from ..conventions import STANDARD_GRAVITY_MPS2, an4399_reference, check_units, units_per_g
from ..errors import DataError, UnitsError
from ..fileguard.numbers import ALLOWED, all_decimal, decimal_float
from ..fileguard.regular import check_regular, open_regular
from .lotarrow import BLOCK_BYTES, SMALL_BLOCK_BYTES, arrow_available, read_csv_arrow, read_parquet_chunks
from .lotchunk import COLUMNS, NUMERIC, LotChunk, missing_serial
from .posetable import COLUMNS as POSE_COLUMNS
from .posetable import read_preamble

__all__ = ["COLUMNS", "SMALL_BLOCK_BYTES", "LotChunk", "arrow_available", "board_arrays", "lot_scale", "lot_site_g",
           "open_lot"]

TEMP_TOLERANCE_C = 2.0  # as models.fit_temperature groups poses
MAX_LINE_CHARS = 1 << 20  # a lot row is under 200 characters; a longer line is not a lot row


def _header(lines_iter: Iterable[str], path: Path) -> tuple[list[str], dict[str, str], int]:
    """The header's columns, the metadata before it and its line number; errors name the line."""
    meta, _, index, s = read_preamble(lines_iter, path, f"serial,{','.join(POSE_COLUMNS[:6])}")
    line_no = index + 1
    try:
        header = [c.strip() for c in next(csv.reader([s]))]
    except csv.Error as e:
        raise DataError(f"{path}: line {line_no}: not a readable CSV header ({e})") from None
    for c in header:
        if c not in COLUMNS:
            raise DataError(f"{path}: line {line_no}: unknown column {c[:40]!r}; allowed: {', '.join(COLUMNS)}")
    if len(set(header)) != len(header):
        raise DataError(f"{path}: line {line_no}: a column appears twice in the header")
    for c in ("serial", "pose", "x", "y", "z"):
        if c not in header:
            raise DataError(f"{path}: line {line_no}: missing column {c!r}; a lot file needs "
                            "serial,pose,x,y,z (and pitch_deg,roll_deg or ref_x,ref_y,ref_z for models 6/12/15)")
    return header, meta, line_no


def _lines(f: Iterable[str], path: Path) -> Iterator[str]:
    """The file's lines, each refused when longer than MAX_LINE_CHARS (never held whole in memory)."""
    for n, line in enumerate(f, 1):
        if len(line) >= MAX_LINE_CHARS and not line.endswith("\n"):
            raise DataError(f"{path}: line {n}: longer than {MAX_LINE_CHARS} characters; a lot file's rows are "
                            "short lines of numbers")
        yield line


def _floats(cells: list[str], col: str, lines: np.ndarray, path: Path, bad_rows: dict[int, str]) -> np.ndarray:
    """A column's cells as floats (NaN where empty); a cell that is not a finite decimal number
    (fileguard.numbers: no 'nan', '4_096' or other scripts' digits) marks its row bad."""
    if all_decimal(cells):  # the common case: one conversion, no per-cell look
        try:
            return np.array(cells, dtype=float) if "" not in cells else \
                np.array([float(v) if v else math.nan for v in cells])
        except ValueError:
            pass
    out = np.empty(len(cells))
    for i, v in enumerate(cells):
        try:
            out[i] = decimal_float(v) if v.strip() else math.nan
        except ValueError:
            out[i] = math.nan
            bad_rows.setdefault(i, f"{path}: line {lines[i]}, column {col}: {v[:40]!r} is not a number; "
                                   f"allowed: {ALLOWED}")
    return out


def _chunk(rows: list[list[str]], lines: list[int], header: list[str], path: Path, row0: int) -> LotChunk:
    """Whole boards from CSV rows of the header's width (their file lines given)."""
    n_rows = len(rows)
    bad_rows: dict[int, str] = {}
    line_arr = np.asarray(lines)
    by_col = dict(zip(header, zip(*rows, strict=True), strict=True)) if rows else dict.fromkeys(header, ())
    cols = {c: _floats(list(by_col[c]), c, line_arr, path, bad_rows) for c in NUMERIC if c in by_col}
    serial = np.asarray([v.strip() for v in by_col["serial"]], dtype=object)
    change = np.flatnonzero(serial[1:] != serial[:-1]) + 1 if n_rows else np.zeros(0, int)
    starts = np.concatenate([[0], change, [n_rows]]).astype(np.int64)
    bad: list[str | None] = [None] * (len(starts) - 1)
    if bad_rows:
        board_of = np.searchsorted(starts, np.fromiter(bad_rows, int), side="right") - 1
        for msg, b in zip(bad_rows.values(), board_of, strict=True):
            bad[b] = bad[b] or msg
    names = np.asarray([v.strip() for v in by_col["pose"]], dtype=object)
    return LotChunk([str(serial[s]) for s in starts[:-1]], starts, cols, names, bad, row0 + starts[:-1] + 1)


def _csv_rows(f: Iterable[str], path: Path, header: list[str], line0: int) -> Iterator[tuple[int, list[str]]]:
    """(file line, fields) of each data row; a row of the wrong width or without a serial is refused
    by its line (its fields cannot be given to columns, or to a board)."""
    s_idx = header.index("serial")
    reader = csv.reader(_lines(f, path))
    try:
        for r in reader:
            line = line0 + reader.line_num
            if not r or (r[0].lstrip().startswith("#")) or not any(c.strip() for c in r):
                continue
            if len(r) != len(header):
                raise DataError(f"{path}: line {line}: {len(r)} fields; the header has {len(header)}")
            if not r[s_idx].strip():
                raise missing_serial(path, f"line {line}")
            yield line, r
    except (UnicodeDecodeError, csv.Error) as e:
        raise DataError(f"{path}: line {line0 + reader.line_num}: unreadable ({e})") from None


def read_csv_chunks(path: str | Path, chunk_boards: int = 4096, block_bytes: int = BLOCK_BYTES,
                    gather: bool = True) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """The lot file's ``# key: value`` metadata, and its boards in chunks of about ``chunk_boards``
    (through pyarrow: ``block_bytes`` of the file parsed at once; ``gather`` False: a chunk per block)."""
    path = Path(path)
    f = io.TextIOWrapper(open_regular(path, "a CSV lot file"), encoding="utf-8-sig", newline="")
    try:
        header, meta, line_no = _header(_lines(f, path), path)
    except UnicodeDecodeError:
        f.close()
        raise DataError(f"{path}: not a text file (expected a CSV lot file)") from None
    except BaseException:
        f.close()
        raise
    if arrow_available():
        f.close()
        return meta, read_csv_arrow(path, header, line_no, chunk_boards, block_bytes, gather)

    def gen() -> Iterator[LotChunk]:
        rows: list[list[str]] = []
        lines: list[int] = []
        boards = row0 = 0
        last: str | None = None
        with f:
            for line, r in _csv_rows(f, path, header, line_no):
                s = r[header.index("serial")].strip()
                if s != last:
                    if boards >= chunk_boards:
                        yield _chunk(rows, lines, header, path, row0)
                        row0 += len(rows)
                        rows, lines, boards = [], [], 0
                    boards += 1
                    last = s
                rows.append(r)
                lines.append(line)
            if rows:
                yield _chunk(rows, lines, header, path, row0)

    return meta, gen()


def open_lot(path: str | Path, chunk_boards: int = 4096, block_bytes: int = BLOCK_BYTES, gather: bool = True
             ) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """Metadata and chunks of a lot file (a regular file), CSV or Parquet by its extension
    (``gather`` False: a CSV lot in one chunk per ``block_bytes`` block, for the least memory)."""
    p = Path(path)
    check_regular(p, "a lot file (CSV or Parquet)")
    if p.suffix.lower() in (".parquet", ".pq"):
        return read_parquet_chunks(p, chunk_boards)
    return read_csv_chunks(p, chunk_boards, block_bytes, gather)


def lot_site_g(meta: dict[str, str], path: str | Path, gravity_mps2: float | None) -> float:
    """The site's gravity in standard g (--gravity, else the file's ``# gravity_mps2:`` or ``# gravity:``
    line, else 1): the factor every reference is scaled by (config/site.py)."""
    for key in ("gravity_mps2", "gravity"):
        if gravity_mps2 is None and meta.get(key):
            try:
                gravity_mps2 = float(meta[key])
            except ValueError:
                raise UnitsError(f"{path}: # {key}: {meta[key]!r}; allowed: a number, m/s^2") from None
    if gravity_mps2 is None:
        return 1.0
    try:
        return units_per_g("mps2", gravity_mps2=gravity_mps2) / STANDARD_GRAVITY_MPS2
    except UnitsError as e:
        raise UnitsError(f"{path}: {e}") from None


def lot_scale(meta: dict[str, str], path: str | Path, units: str | None, counts_per_g: float | None,
              gravity_mps2: float | None, model: str) -> tuple[str, float | None]:
    """Units and input units per g (None: model 9 on counts estimates it per board); m/s^2 are standard
    g by 9.80665 (the site's gravity scales the references instead: ``lot_site_g``)."""
    units = units or meta.get("units", "counts")
    try:
        check_units(units)
    except UnitsError as e:
        raise UnitsError(f"{path}: {e}") from None
    for key, val in (("counts_per_g", counts_per_g),):  # gravity_mps2: the site's (lot_site_g), not a scale
        if val is None and meta.get(key):
            try:
                v = decimal_float(meta[key])
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and v > 0):
                raise UnitsError(f"{path}: # {key}: {meta[key]!r}; allowed: a positive number")
            counts_per_g = v
    if units == "counts" and counts_per_g is None:
        if model == "9":
            return units, None
        raise UnitsError(f"{path}: model {model} on counts needs counts per g: add '# counts_per_g: N' to the "
                         "lot file or pass --counts-per-g N")
    return units, units_per_g(units, counts_per_g)


def design_references(pitch_deg: np.ndarray, roll_deg: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """AN4399 references (rows, 3) of every row's pitch/roll (conventions.an4399_reference), computed
    once per distinct design: boards of one pose count whose angle rows are equal (a lot's fixture)
    share one computation, broadcast back (elementwise, so the same numbers as row by row)."""
    sizes = np.diff(starts)
    n = len(pitch_deg)
    if not n or len(sizes) < 2 or np.any(sizes != sizes[0]):
        return an4399_reference(pitch_deg, roll_deg).reshape(-1, 3)
    P = int(sizes[0])
    ang = np.stack([pitch_deg.reshape(-1, P), roll_deg.reshape(-1, P)], axis=1).reshape(-1, 2 * P)
    bits = ang.view(np.int64)  # designs compared bit for bit: -0.0 and 0.0 (or two NaNs) stay apart
    if np.array_equal(bits, np.broadcast_to(bits[0], bits.shape)):
        designs, inverse = ang[:1], np.zeros(len(ang), dtype=np.intp)
    else:
        _, first, inverse = np.unique(bits, axis=0, return_index=True, return_inverse=True)
        if len(first) * 2 > len(ang):  # mostly distinct: no gain in grouping
            return an4399_reference(pitch_deg, roll_deg).reshape(-1, 3)
        designs = ang[first]
    refs = an4399_reference(designs[:, :P], designs[:, P:])  # (U, P, 3)
    return refs[np.asarray(inverse).reshape(-1)].reshape(-1, 3)


def board_arrays(chunk: LotChunk, model: str
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, list[str | None]]:
    """Per-row readings (rows, 3), references (rows, 3) or None, noise (rows, 3) or None, and
    per-board reasons a board cannot be fitted (None where it can)."""
    c = chunk.cols
    x = np.stack([c["x"], c["y"], c["z"]], axis=1)
    ref = None
    if {"ref_x", "ref_y", "ref_z"} <= c.keys():
        ref = np.stack([c["ref_x"], c["ref_y"], c["ref_z"]], axis=1)
    if {"pitch_deg", "roll_deg"} <= c.keys():
        ang = design_references(c["pitch_deg"], c["roll_deg"], chunk.starts)
        ref = ang if ref is None else np.where(np.isnan(ref), ang, ref)
    noise = None
    if {"std_x", "std_y", "std_z", "n"} <= c.keys():
        noise = np.stack([c["std_x"], c["std_y"], c["std_z"]], axis=1) / np.sqrt(c["n"])[:, None]
    starts = chunk.starts
    B = len(starts) - 1
    reasons = list(chunk.bad)
    # values out of range were made NaN, their boards bad, by the reader (lotchunk.screen)
    checks = [(nonfinite_rows(x), "reading is empty, NaN or infinite")]
    if model != "9":
        no_ref = np.ones(len(x), bool) if ref is None else nonfinite_rows(ref)
        checks.append((no_ref, f"has no reference; model {model} needs pitch_deg/roll_deg or ref_x/ref_y/ref_z "
                               "(only model 9 fits without)"))
    for rows_bad, what in checks:
        if rows_bad is not None and rows_bad.any():
            first = np.flatnonzero(rows_bad)
            boards = np.searchsorted(starts, first, side="right") - 1
            for r, b in zip(first[::-1], boards[::-1], strict=True):  # reversed: the first bad row of a board wins
                if chunk.bad[b] is None:
                    reasons[b] = f"pose {str(chunk.names[r])!r}: {what}"
    if "temp_c" in c:
        t = c["temp_c"]
        have = np.isfinite(t)
        n_have = np.add.reduceat(have.astype(int), starts[:-1]) if B else np.zeros(0, int)
        span = np.zeros(B)
        if B:
            tt = np.where(have, t, np.nan)
            with np.errstate(invalid="ignore"):
                hi = np.fmax.reduceat(tt, starts[:-1])
                lo = np.fmin.reduceat(tt, starts[:-1])
            span = np.where(n_have > 0, hi - lo, 0.0)
        sizes = np.diff(starts)
        for b in np.flatnonzero((n_have > 0) & (n_have < sizes)):
            reasons[b] = reasons[b] or "some poses have temp_c and others not; give temp_c for every pose or for none"
        for b in np.flatnonzero(span > TEMP_TOLERANCE_C):
            reasons[b] = reasons[b] or (f"poses span {span[b]:.3g} C of temperature: a temperature table; fit it "
                                        "from the board's pose table with accelcal batch FILE or accelcal fit")
    bad_noise = None if noise is None else nonfinite_rows(noise)
    if noise is not None and bad_noise is not None and bad_noise.any():
        # a board whose std/n are not all given is fitted without measured noise
        per_board = np.logical_and.reduceat(~bad_noise, starts[:-1]) if B else bad_noise[:0]
        noise = np.where(np.repeat(per_board, np.diff(starts))[:, None], noise, np.nan)
    return x, ref, noise, reasons


def nonfinite_rows(a: np.ndarray) -> np.ndarray | None:
    """(rows,) rows of ``a`` (rows, k) with a NaN or infinite value, or None when there is none:
    decided for most chunks by one sum (finite only when every value is, or when it overflows
    to infinity, then checked row by row), without a (rows, k) mask."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(a.sum()):
            return None
    return ~np.all(np.isfinite(a), axis=1)

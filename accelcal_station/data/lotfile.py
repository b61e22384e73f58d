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
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..conventions import an4399_reference, check_units, units_per_g
from ..errors import DataError, UnitsError
from .posetable import COLUMNS as POSE_COLUMNS
from .posetable import read_preamble

COLUMNS = ("serial",) + POSE_COLUMNS
NUMERIC = tuple(c for c in POSE_COLUMNS if c != "pose")
TEMP_TOLERANCE_C = 2.0  # as models.fit_temperature groups poses


@dataclass
class LotChunk:
    """Whole boards read from a lot file: rows as column arrays, boards as row ranges.

    ``bad[b]`` is the reason board b's rows cannot be used (a cell that is not a
    number), or None.  ``first_row`` is each board's first data row (1-based, after the header).
    """

    serials: list[str]
    starts: np.ndarray  # (B + 1,) row offsets
    cols: dict[str, np.ndarray]  # numeric columns (rows,), NaN where empty
    names: np.ndarray  # pose names (rows,)
    bad: list[str | None]
    first_row: np.ndarray


def _header(lines_iter: Iterable[str], path: Path) -> tuple[list[str], dict[str, str], int]:
    """The header's columns, the metadata before it and its line number; errors name the line."""
    meta, _, index, s = read_preamble(lines_iter, path, f"serial,{','.join(POSE_COLUMNS[:6])}")
    line_no = index + 1
    header = [c.strip() for c in next(csv.reader([s]))]
    for c in header:
        if c not in COLUMNS:
            raise DataError(f"{path}: line {line_no}: unknown column {c!r}; allowed: {', '.join(COLUMNS)}")
    if len(set(header)) != len(header):
        raise DataError(f"{path}: line {line_no}: a column appears twice in the header")
    for c in ("serial", "pose", "x", "y", "z"):
        if c not in header:
            raise DataError(f"{path}: line {line_no}: missing column {c!r}; a lot file needs "
                            "serial,pose,x,y,z (and pitch_deg,roll_deg or ref_x,ref_y,ref_z for models 6/12/15)")
    return header, meta, line_no


def _floats(cells: list[str], col: str, lines: np.ndarray, path: Path, bad_rows: dict[int, str]) -> np.ndarray:
    """A column's cells as floats (NaN where empty); a non-number marks its row bad."""
    try:
        return np.array(cells, dtype=float) if "" not in cells else \
            np.array([float(v) if v else math.nan for v in cells])
    except ValueError:
        out = np.empty(len(cells))
        for i, v in enumerate(cells):
            try:
                out[i] = float(v) if v.strip() else math.nan
            except ValueError:
                out[i] = math.nan
                bad_rows.setdefault(i, f"{path}: line {lines[i]}, column {col}: {v!r} is not a number")
        return out


def _chunk(rows: list[list[str]], lines: list[int], header: list[str], path: Path, row0: int) -> LotChunk:
    """Whole boards from CSV rows (their file lines given); a row of the wrong width marks its board bad."""
    n_rows = len(rows)
    bad_rows: dict[int, str] = {}
    width = len(header)
    for i, r in enumerate(rows):
        if len(r) != width:
            bad_rows[i] = f"{path}: line {lines[i]}: {len(r)} fields; the header has {width}"
            rows[i] = (r + [""] * width)[:width]
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


def read_csv_chunks(path: str | Path, chunk_boards: int = 4096) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """The lot file's ``# key: value`` metadata, and its boards in chunks of about ``chunk_boards``."""
    path = Path(path)
    try:
        f = open(path, newline="", encoding="utf-8-sig")  # noqa: SIM115 - the chunk generator closes it (with f)
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        header, meta, line_no = _header(f, path)
    except UnicodeDecodeError:
        f.close()
        raise DataError(f"{path}: not a text file (expected a CSV lot file)") from None
    except BaseException:
        f.close()
        raise
    s_idx = header.index("serial")
    if arrow_available():
        f.close()
        return meta, read_csv_arrow(path, header, line_no, chunk_boards)

    def gen() -> Iterator[LotChunk]:
        nonlocal line_no
        rows: list[list[str]] = []
        lines: list[int] = []
        boards = row0 = 0
        last: str | None = None
        with f:
            reader = csv.reader(f)
            try:
                for r in reader:
                    line_no += 1
                    if not r or (r[0].lstrip().startswith("#")) or not any(c.strip() for c in r):
                        continue
                    s = r[s_idx].strip() if len(r) > s_idx else ""
                    if s != last:
                        if boards >= chunk_boards:
                            yield _chunk(rows, lines, header, path, row0)
                            row0 += len(rows)
                            rows, lines, boards = [], [], 0
                        boards += 1
                        last = s
                    rows.append(r)
                    lines.append(line_no)
            except (UnicodeDecodeError, csv.Error) as e:
                raise DataError(f"{path}: line {line_no}: unreadable ({e})") from None
            if rows:
                yield _chunk(rows, lines, header, path, row0)

    return meta, gen()


def arrow_available() -> bool:
    try:
        import pyarrow.csv  # noqa: F401
    except ImportError:
        return False
    return True


def read_parquet_chunks(path: str | Path, chunk_boards: int = 4096) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """A Parquet lot file (needs pyarrow: pip install 'accelcal-station[parquet]')."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise DataError(f"{path}: reading Parquet needs pyarrow; pip install 'accelcal-station[parquet]'") from None
    path = Path(path)
    try:
        pf = pq.ParquetFile(path)
    except (OSError, Exception) as e:  # pyarrow raises its own ArrowInvalid for a non-Parquet file
        raise DataError(f"{path}: not a readable Parquet file ({e})") from None
    names = pf.schema_arrow.names
    for c in names:
        if c not in COLUMNS:
            raise DataError(f"{path}: unknown column {c!r}; allowed: {', '.join(COLUMNS)}")
    meta = {k.decode(): v.decode() for k, v in (pf.schema_arrow.metadata or {}).items()
            if k.decode() in ("units", "counts_per_g", "gravity")}

    return meta, _arrow_chunks(pf.iter_batches(batch_size=chunk_boards * 16), names, path)


def _arrow_chunks(batches: Iterable[Any], names: list[str], path: Path) -> Iterator[LotChunk]:
    """Whole-board chunks from Arrow record batches (a board may span two batches)."""
    tail: dict[str, np.ndarray] | None = None
    row0 = 0
    for batch in batches:
        bad_rows: dict[int, str] = {}
        d = {c: _arrow_column(batch.column(c), c, path, row0 + (len(tail["serial"]) if tail else 0), bad_rows)
             for c in names}
        d["_bad"] = np.zeros(len(d["serial"]), dtype=object)
        for i, msg in bad_rows.items():
            d["_bad"][i] = msg
        if tail is not None:
            d = {c: np.concatenate([tail[c], d[c]]) for c in d}
        serial = d["serial"].astype(str)
        change = np.flatnonzero(serial[1:] != serial[:-1]) + 1
        cut = int(change[-1]) if len(change) else 0  # the last board may continue in the next batch
        tail = {c: d[c][cut:] for c in d}
        if cut:
            yield _arrays_chunk({c: d[c][:cut] for c in d}, row0)
            row0 += cut
    if tail is not None and len(tail["serial"]):
        yield _arrays_chunk(tail, row0)


def _arrow_column(col: Any, name: str, path: Path, row0: int, bad_rows: dict[int, str]) -> np.ndarray:
    """An Arrow column as numpy: text columns as str, numeric ones as float (NaN for null)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    if name in ("serial", "pose"):
        return np.asarray(pc.utf8_trim_whitespace(col.cast(pa.string())).to_numpy(zero_copy_only=False)).astype(str)
    if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
        try:
            col = pc.cast(pc.utf8_trim_whitespace(col), pa.float64())
        except pa.ArrowInvalid:  # mark the rows with a bad cell; their boards are reported, not fitted
            out = np.full(len(col), np.nan)
            for i, v in enumerate(col.to_pylist()):
                if v is None or not v.strip():
                    continue
                if _is_float(v):
                    out[i] = float(v)
                else:
                    bad_rows.setdefault(i, f"{path}: data row {row0 + i + 1}, column {name}: {v!r} is not a number")
            return out
    return col.cast(pa.float64()).to_numpy(zero_copy_only=False)


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


def _comment_row(row: Any) -> str:
    """pyarrow: a '#' line after the header is skipped (as pose tables allow); other bad rows fail."""
    return "skip" if (row.text or "").lstrip().startswith("#") else "error"


def read_csv_arrow(path: Path, header: list[str], skip: int, chunk_boards: int) -> Iterator[LotChunk]:
    """The CSV body through pyarrow's streaming reader (several times faster than csv)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv
    types = {c: pa.string() for c in header}
    reader = pcsv.open_csv(path, read_options=pcsv.ReadOptions(skip_rows=skip, column_names=header,
                                                               block_size=1 << 20),
                           parse_options=pcsv.ParseOptions(ignore_empty_lines=True, invalid_row_handler=_comment_row),
                           convert_options=pcsv.ConvertOptions(column_types=types, strings_can_be_null=True))
    try:
        yield from _arrow_chunks(reader, header, path)
    except pa.ArrowInvalid as e:
        raise DataError(f"{path}: unreadable CSV ({e})") from None


def _arrays_chunk(d: dict[str, np.ndarray], row0: int) -> LotChunk:
    """Whole boards from column arrays (``_bad``: a reason per row, 0 where none)."""
    serial = d["serial"].astype(str)
    n = len(serial)
    change = np.flatnonzero(serial[1:] != serial[:-1]) + 1
    starts = np.concatenate([[0], change, [n]]).astype(np.int64)
    cols = {c: np.asarray(d[c], dtype=float) for c in NUMERIC if c in d}
    bad: list[str | None] = [None] * (len(starts) - 1)
    if "_bad" in d:
        for i in np.flatnonzero(d["_bad"] != 0):
            b = int(np.searchsorted(starts, i, side="right") - 1)
            bad[b] = bad[b] or d["_bad"][i]
    return LotChunk([str(serial[s]) for s in starts[:-1]], starts, cols, np.asarray(d["pose"]).astype(str),
                    bad, row0 + starts[:-1] + 1)


def open_lot(path: str | Path, chunk_boards: int = 4096) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """Metadata and chunks of a lot file, CSV or Parquet by its extension."""
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: no such lot file")
    if p.suffix.lower() in (".parquet", ".pq"):
        return read_parquet_chunks(p, chunk_boards)
    return read_csv_chunks(p, chunk_boards)


def lot_scale(meta: dict[str, str], path: str | Path, units: str | None, counts_per_g: float | None,
              gravity_mps2: float | None, model: str) -> tuple[str, float | None]:
    """Units and input units per g (None: model 9 on counts estimates it per board)."""
    units = units or meta.get("units", "counts")
    try:
        check_units(units)
    except UnitsError as e:
        raise UnitsError(f"{path}: {e}") from None
    for key, val in (("counts_per_g", counts_per_g), ("gravity", gravity_mps2)):
        if val is None and meta.get(key):
            try:
                v = float(meta[key])
            except ValueError:
                v = math.nan
            if not (math.isfinite(v) and v > 0):
                raise UnitsError(f"{path}: # {key}: {meta[key]!r}; allowed: a positive number")
            counts_per_g, gravity_mps2 = (v, gravity_mps2) if key == "counts_per_g" else (counts_per_g, v)
    if units == "counts" and counts_per_g is None:
        if model == "9":
            return units, None
        raise UnitsError(f"{path}: model {model} on counts needs counts per g: add '# counts_per_g: N' to the "
                         "lot file or pass --counts-per-g N")
    return units, units_per_g(units, counts_per_g, gravity_mps2)


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
        ang = an4399_reference(c["pitch_deg"], c["roll_deg"]).reshape(-1, 3)
        ref = ang if ref is None else np.where(np.isnan(ref), ang, ref)
    noise = None
    if {"std_x", "std_y", "std_z", "n"} <= c.keys():
        noise = np.stack([c["std_x"], c["std_y"], c["std_z"]], axis=1) / np.sqrt(c["n"])[:, None]
    starts = chunk.starts
    B = len(starts) - 1
    reasons = list(chunk.bad)
    row_bad_x = ~np.all(np.isfinite(x), axis=1)
    checks = [(row_bad_x, "reading is empty, NaN or infinite")]
    if model != "9":
        no_ref = np.ones(len(x), bool) if ref is None else ~np.all(np.isfinite(ref), axis=1)
        checks.append((no_ref, f"has no reference; model {model} needs pitch_deg/roll_deg or ref_x/ref_y/ref_z "
                               "(only model 9 fits without)"))
    for rows_bad, what in checks:
        if rows_bad.any():
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
    if noise is not None:
        good = np.all(np.isfinite(noise), axis=1)
        if not good.all():  # a board whose std/n are not all given is fitted without measured noise
            per_board = np.logical_and.reduceat(good, starts[:-1]) if B else good[:0]
            noise = np.where(np.repeat(per_board, np.diff(starts))[:, None], noise, np.nan)
    return x, ref, noise, reasons

"""Lot files through pyarrow (the ``parquet`` extra): Parquet lots, and the CSV body of a lot
when pyarrow is installed (several times faster than the csv module).

Hostile files are refused before any cast: a Parquet schema's every column is checked
against what the lot format allows (text columns: strings or integers; numeric columns:
integers, floats or decimals), a row of the wrong width in a CSV lot is named by its line,
a row without a serial is refused, never made into a board called "None".
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..errors import DataError
from ..fileguard.numbers import ALLOWED, is_decimal
from ..fileguard.regular import open_regular
from ..models.threads import usable_cpus
from .arrow_arrays import strings, to_numpy
from .lotchunk import COLUMNS, TEXT, Labels, LotChunk, arrays_chunk, missing_serial

# CSV bytes parsed at once.  Arrow's streaming reader holds buffers that grow with the block:
# opening it and reading the first block raised the RSS by 31 MiB at 256 KiB, 56 at 1 MiB and 109
# at 4 MiB (pyarrow 26, mimalloc pool), and its read-ahead holds more of a long file than of a short
# one at 1 MiB blocks (12 blocks into the 108 MB 200,000-board lot: 108 MB RSS against 99 MB for the
# 27 MB 50,000-board lot; 103 / 102 MB at 768 KiB, 93 / 93 at 640 KiB).  `accelcal batch` parses
# 768 KiB blocks: its peak RSS is flat in the lot's size (bench_resources: 125 / 128 MB at 50,000 /
# 200,000 boards, 1.02; 128 / 144 MB, 1.12, at 1 MiB) for 2-3 % more CPU than 1 MiB; `twin fit`,
# whose memory has a stated bound, reads 256 KiB (100,000 boards: 246 MB peak, 271 with 1 MiB).
BLOCK_BYTES = 768 << 10
SMALL_BLOCK_BYTES = 256 << 10
MAX_ROW_GROUP_BYTES = 1 << 30  # one row group's columns are decoded at once: at most 1 GiB of them
REQUIRED = ("serial", "pose", "x", "y", "z")
Where = Callable[[int], str]  # data row n (1-based) -> where it is, for errors: "line 13" or "data row 12"


def arrow_available() -> bool:
    try:
        import pyarrow.csv  # noqa: F401
    except ImportError:
        return False
    return True


def _type_allowed(name: str, t: Any) -> bool:
    """Text columns: strings, integers or a dictionary of them; numeric ones: integers, floats, decimals, null."""
    import pyarrow as pa

    if name in TEXT:
        if pa.types.is_dictionary(t):
            t = t.value_type
        return bool(pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_integer(t))
    return bool(pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_decimal(t) or pa.types.is_null(t))


def check_schema(schema: Any, path: Path) -> list[str]:
    """The column names of a Parquet lot whose every column is known, once, and of an allowed type."""
    names = list(schema.names)
    for field in schema:
        if field.name not in COLUMNS:
            raise DataError(f"{path}: unknown column {field.name!r}; allowed: {', '.join(COLUMNS)}")
        if names.count(field.name) > 1:
            raise DataError(f"{path}: column {field.name!r} appears twice")
        if not _type_allowed(field.name, field.type):
            allowed = "strings or integers" if field.name in TEXT else "numbers (integer, float or decimal)"
            raise DataError(f"{path}: column {field.name!r} is of type {field.type}; allowed: {allowed}")
    for c in REQUIRED:
        if c not in names:
            raise DataError(f"{path}: missing column {c!r}; a lot file needs {', '.join(REQUIRED)}")
    return names


def read_parquet_chunks(path: str | Path, chunk_boards: int = 4096) -> tuple[dict[str, str], Iterator[LotChunk]]:
    """A Parquet lot file (needs pyarrow: pip install 'accelcal-station[parquet]')."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise DataError(f"{path}: reading Parquet needs pyarrow; pip install 'accelcal-station[parquet]'") from None
    path = Path(path)
    f = open_regular(path, "a Parquet lot file")
    try:
        pf = pq.ParquetFile(f, pre_buffer=False)  # pre-buffered column chunks pile up: RSS grew with the lot
        names = check_schema(pf.schema_arrow, path)
        for i in range(pf.metadata.num_row_groups):
            size = pf.metadata.row_group(i).total_byte_size
            if size > MAX_ROW_GROUP_BYTES:
                raise DataError(f"{path}: row group {i} holds {size} bytes; allowed: at most "
                                f"{MAX_ROW_GROUP_BYTES >> 20} MiB per row group (each is decoded in memory at once)")
        meta = {k.decode(errors="replace"): v.decode(errors="replace")
                for k, v in (pf.schema_arrow.metadata or {}).items()}
    except (pa.ArrowException, OSError) as e:  # not Parquet, or a damaged footer
        f.close()
        raise DataError(f"{path}: not a readable Parquet file ({e})") from None
    except BaseException:
        f.close()
        raise
    meta = {k: v for k, v in meta.items() if k in ("units", "counts_per_g", "gravity", "gravity_mps2")}
    return meta, _closing(f, _guarded(pf.iter_batches(batch_size=chunk_boards * 16, use_threads=False), names, path,
                                              "Parquet data"))


def _closing(f: BinaryIO, chunks: Iterator[LotChunk]) -> Iterator[LotChunk]:
    with f:
        yield from chunks


def _guarded(batches: Iterable[Any], names: list[str], path: Path, what: str, bad_row: list[str] | None = None,
             where: Where | None = None, row0: int = 0, gather_boards: int = 0) -> Iterator[LotChunk]:
    """Chunks of whole boards; an Arrow error while decoding is one DataError (``bad_row``: a CSV row
    of the wrong width, recorded by the reader, named instead)."""
    import pyarrow as pa

    try:
        yield from _arrow_chunks(batches, names, path, where or _data_row, row0, gather_boards)
    except (pa.ArrowException, OSError) as e:
        if bad_row:
            raise DataError(bad_row[0]) from None
        raise DataError(f"{path}: damaged {what} ({e})") from None


def _data_row(n: int) -> str:
    return f"data row {n}"


@dataclass
class _Rows:
    """Decoded rows of a lot not yet given out: the text columns as Labels, the numbers, and a
    reason per row (0 where none; a clean block: bool zeros, no object array)."""

    serial: Labels
    pose: Labels
    num: dict[str, np.ndarray]
    bad: np.ndarray

    def __getitem__(self, rows: slice) -> _Rows:
        return _Rows(self.serial[rows], self.pose[rows], {c: v[rows] for c, v in self.num.items()}, self.bad[rows])

    def carried(self) -> _Rows:
        """These rows (the start of a board the next block continues) with tables of their own."""
        return _Rows(self.serial.compact(), self.pose.compact(), self.num, self.bad)

    def chunk(self, row0: int) -> LotChunk:
        return arrays_chunk(self.serial, self.pose, self.num, self.bad, row0)

    @staticmethod
    def joined(parts: list[_Rows]) -> _Rows:
        if len(parts) == 1:
            return parts[0]
        # a clean part's bad is bool, a damaged one's object: joined as object when any is
        return _Rows(Labels.joined([p.serial for p in parts]), Labels.joined([p.pose for p in parts]),
                     {c: np.concatenate([p.num[c] for p in parts]) for c in parts[0].num},
                     np.concatenate([p.bad for p in parts]))


def _decoded(batch: Any, names: list[str], path: Path, row0: int, where: Where) -> _Rows:
    """One Arrow record batch as _Rows (its first row being data row ``row0`` + 1)."""
    bad_rows: dict[int, str] = {}
    text = {c: _arrow_text(batch.column(c), c, path, row0, where) for c in TEXT}
    num = {c: _arrow_number(batch.column(c), c, path, row0, bad_rows) for c in names if c not in TEXT}
    bad = np.zeros(batch.num_rows, dtype=object if bad_rows else bool)
    for i, msg in bad_rows.items():
        bad[i] = msg
    return _Rows(text["serial"], text["pose"], num, bad)


def _arrow_chunks(batches: Iterable[Any], names: list[str], path: Path, where: Where,
                  row0: int = 0, gather_boards: int = 0) -> Iterator[LotChunk]:
    """Whole-board chunks from Arrow record batches (a board may span two batches), the first
    batch's first row being data row ``row0`` + 1; ``where`` names data row n (1-based) in errors.

    Small batches (the CSV reader's blocks are kept small so its read-ahead stays small) are
    gathered to about ``gather_boards`` boards first (rows per board taken from the first batch):
    the fitters' cost per chunk is partly fixed numpy overhead."""
    pending: list[_Rows] = []  # decoded rows not yet given out, from data row row0 + 1
    rows, gather_rows = 0, 0
    for batch in batches:
        pending.append(_decoded(batch, names, path, row0 + rows, where))
        rows += batch.num_rows
        if rows < gather_rows:
            continue
        d = _Rows.joined(pending)
        change = d.serial.changes()
        if gather_boards and not gather_rows:  # the first batch: its rows per board size the chunks
            per_board = change[-1] / len(change) if len(change) else rows  # rows of its whole boards
            gather_rows = int(gather_boards * max(1.0, per_board))
            if rows < gather_rows:
                continue
        cut = int(change[-1]) if len(change) else 0  # the last board may continue in the next batch
        pending, rows = [d[cut:].carried()], rows - cut
        if cut:
            yield d[:cut].chunk(row0)
            row0 += cut
    if rows:
        yield _Rows.joined(pending).chunk(row0)


def _arrow_text(col: Any, name: str, path: Path, row0: int, where: Where) -> Labels:
    """A text column as Labels: values trimmed, null or blank cells "" (a blank serial refused)."""
    import pyarrow as pa

    if pa.types.is_dictionary(col.type) and pa.types.is_string(col.type.value_type):
        labels = _dictionary_text(col)
    else:
        import pyarrow.compute as pc

        # through a dictionary: a Python str per distinct value (a serial per board, a few pose
        # names), not one per row; "" as an Arrow scalar (a Python one goes through pa.scalar: pandas)
        blank = strings([""])[0]
        enc = pc.dictionary_encode(pc.utf8_trim_whitespace(col.cast(pa.string())).fill_null(blank))
        labels = Labels(np.array(enc.dictionary.to_pylist(), dtype=str),
                        np.asarray(_numpy(enc.indices), dtype=np.intp))
    if name == "serial":
        blank = np.flatnonzero(labels.table == "")
        if blank.size:
            empty = np.isin(labels.codes, blank)
            if empty.any():
                raise missing_serial(path, where(row0 + int(np.argmax(empty)) + 1))
    return labels


def _arrow_number(col: Any, name: str, path: Path, row0: int, bad_rows: dict[int, str]) -> np.ndarray:
    """A numeric Arrow column as float numpy (NaN for null); cells that are not numbers recorded in ``bad_rows``."""
    import pyarrow as pa

    if col.type == pa.float64():  # the typed CSV read's numbers: no cast (and no pyarrow.compute import)
        return _finite(col, name, path, row0, bad_rows)
    import pyarrow.compute as pc

    if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
        try:  # a clean column casts as it is (no trimmed copy of every cell); else trimmed, else cell by cell
            col = pc.cast(col, pa.float64())
        except pa.ArrowInvalid:
            try:
                col = pc.cast(pc.utf8_trim_whitespace(col), pa.float64())
            except pa.ArrowInvalid:
                return _cells(col, name, path, row0, bad_rows)
    if col.type != pa.float64():  # integers beyond 2**53 and wide decimals lose digits as floats: a
        col = pc.cast(col, pa.float64(), safe=False)  # calibration number never has them
    return _finite(col, name, path, row0, bad_rows)


def _finite(col: Any, name: str, path: Path, row0: int, bad_rows: dict[int, str]) -> np.ndarray:
    """A float64 Arrow column as numpy, NaN for null (an empty cell); a NaN or infinite value that is
    not null (a 'nan' or 'inf' cell, a Parquet NaN) marks its row bad, as a pose table refuses it."""
    out = np.asarray(_numpy(col), dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(out.sum()) or (not np.isinf(out).any() and int(np.isnan(out).sum()) == col.null_count):
            return out
    null = np.asarray(col.is_null().to_numpy(zero_copy_only=False), dtype=bool)
    for i in np.flatnonzero(~np.isfinite(out) & ~null):
        bad_rows.setdefault(int(i), f"{path}: data row {row0 + i + 1}, column {name}: {out[i]} is not a finite "
                                    "number; allowed: a finite number (an empty cell for none)")
    return np.where(null | np.isfinite(out), out, np.nan)


def _dictionary_text(col: Any) -> Labels:
    """A text column read as a dictionary (the CSV lot's serial and pose: a value per board or per
    pose name, not per row) as Labels: the dictionary's values trimmed, null rows "".  numpy's
    strings.strip trims exactly what Arrow's utf8_trim_whitespace (the text path's) trims, the
    Unicode White_Space characters (tests/test_lot.py checks every code point), in one call, with
    no pyarrow.compute."""
    # to_pylist, not to_numpy: Arrow turns a string array into numpy through pandas where pandas is
    # installed (0.5 s of imports at start-up, issue 51); the dictionary is a few thousand values a chunk
    values = np.strings.strip(np.array(col.dictionary.to_pylist(), dtype=str))
    idx = _numpy(col.indices)
    if col.null_count:  # nulls come out as NaN: the table's last entry, ""
        return Labels(np.append(values, ""), np.asarray(np.where(np.isnan(idx), len(values), idx), dtype=np.intp))
    return Labels(values, np.asarray(idx, dtype=np.intp))


def _cells(col: Any, name: str, path: Path, row0: int, bad_rows: dict[int, str]) -> np.ndarray:
    """A text column with a cell that is not a number, cell by cell: the rows with a bad cell are
    marked (their boards are reported, not fitted); blank cells are NaN."""
    out = np.full(len(col), np.nan)
    for i, v in enumerate(col.to_pylist()):
        if v is None or not v.strip():
            continue
        if is_decimal(v):
            out[i] = float(v)
        else:
            bad_rows.setdefault(i, f"{path}: data row {row0 + i + 1}, column {name}: {v[:40]!r} is not a number; "
                                   f"allowed: {ALLOWED}")
    return out


class _RowCheck:
    """pyarrow's invalid-row handler: a '#' line after the header is skipped (as pose tables allow);
    a row of the wrong width is recorded, to be named by its line, and stops the read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.bad: list[str] = []

    def __call__(self, row: Any) -> str:
        text = row.text or ""
        if text.lstrip().startswith("#"):
            return "skip"
        self.bad.append(f"{self.path}: line {_line_of(self.path, text)}: {row.actual_columns} fields; the header has "
                        f"{row.expected_columns}")
        return "error"


def _data_line(path: Path, skip: int, n: int) -> str:
    """The file line of data row ``n`` of a CSV lot whose first ``skip`` lines are the preamble and
    header (an error path: the file is read once more; blank and '#' lines are not rows)."""
    try:
        with open_regular(path, "a CSV lot file") as f:
            rows = 0
            for i, raw in enumerate(f, 1):
                s = raw.strip()
                if i > skip and s and not s.startswith(b"#"):
                    rows += 1
                    if rows == n:
                        return f"line {i}"
    except (DataError, OSError):
        pass
    return f"data row {n}"


def _line_of(path: Path, text: str) -> str:
    """The file line holding ``text`` (an error path: the file is read once more, line by line)."""
    try:
        with open_regular(path, "a CSV lot file") as f:
            for i, raw in enumerate(f, 1):
                if raw.decode("utf-8", "replace").rstrip("\r\n") == text:
                    return str(i)
    except (DataError, OSError):
        pass
    return "?"


def read_csv_arrow(path: Path, header: list[str], skip: int, chunk_boards: int,
                   block_bytes: int = BLOCK_BYTES, gather: bool = True) -> Iterator[LotChunk]:
    """The CSV body through pyarrow's streaming reader, ``block_bytes`` of CSV parsed at once,
    in chunks of about ``chunk_boards`` boards (``gather`` False: one chunk per block, the least
    memory).

    Numeric columns are parsed as float64 by the reader itself (no text column and cast per
    block); a cell that is not a number stops that read, and the rest of the file, from the
    first row not yet given out, is read again as text, where ``_arrow_column`` names the bad
    cells.  Both give the same numbers for every cell the typed read accepts (Arrow's one float
    parser; surrounding blanks, which the typed read skips, are trimmed before the text cast)."""
    done = 0  # data rows given out in chunks so far
    boards = chunk_boards if gather else 0
    try:
        for chunk in _read_csv_arrow(path, header, skip, block_bytes, typed=True, gather_boards=boards):
            done = chunk.row_end
            yield chunk
    except _TypedCellError:  # the rows gathered but not given out are read again, as text
        yield from _read_csv_arrow(path, header, skip, block_bytes, typed=False, row0=done, gather_boards=boards)


class _TypedCellError(Exception):
    """A numeric cell the typed read could not parse: read the rest as text."""


def _read_csv_arrow(path: Path, header: list[str], skip: int, block_bytes: int, typed: bool,
                    row0: int = 0, gather_boards: int = 0) -> Iterator[LotChunk]:
    """One pass of pyarrow's streaming reader from data row ``row0`` on (earlier rows dropped)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    # typed: numbers as float64, the serial and pose names as dictionaries (a few distinct values per block)
    types = {c: (pa.dictionary(pa.int32(), pa.string()) if c in TEXT else pa.float64()) if typed else pa.string()
             for c in header}
    check = _RowCheck(path)
    # One thread, and the reader closed before the file: a background read-ahead thread of Arrow's
    # reading a Python file object that an abandoned generator has already closed crashes the process.
    with open_regular(path, "a CSV lot file") as f:
        try:
            reader = pcsv.open_csv(f, read_options=pcsv.ReadOptions(skip_rows=skip, column_names=header,
                                                                    block_size=block_bytes, use_threads=False),
                                   parse_options=pcsv.ParseOptions(ignore_empty_lines=True, invalid_row_handler=check),
                                   convert_options=pcsv.ConvertOptions(column_types=types, strings_can_be_null=True,
                                                                       null_values=[""]),  # 'nan', 'NA': no
                                   memory_pool=_pool())
        except pa.ArrowInvalid as e:
            if typed and not check.bad and "conversion error" in str(e).lower():
                raise _TypedCellError from None
            raise DataError(check.bad[0] if check.bad else f"{path}: unreadable CSV ({e})") from None
        except (pa.ArrowException, OSError) as e:
            raise DataError(check.bad[0] if check.bad else f"{path}: unreadable CSV ({e})") from None
        try:
            batches = _typed_batches(_ahead(reader), check) if typed else _after(_ahead(reader), row0)
            yield from _guarded(batches, header, path, "CSV", check.bad, lambda n: _data_line(path, skip, n), row0,
                                gather_boards)
        finally:
            reader.close()


def _pool() -> Any:
    """The C library's allocator for the CSV reader: it returns a block's memory when the block is
    freed, where Arrow's default pool (mimalloc) keeps more of a long lot's read-ahead (peak RSS
    1.08-1.10x from 50,000 to 200,000 boards with mimalloc, 1.03x with malloc; same speed)."""
    import pyarrow as pa

    return pa.system_memory_pool()


def _ahead(batches: Iterable[Any]) -> Iterator[Any]:
    """The batches, the next one parsed by one background thread while the caller works on this
    one (Arrow's parser runs without the GIL: reading overlaps the fit on a second core).  The
    thread is done before this generator ends, however it ends, so the reader and its file are
    never used after they are closed.  On one CPU nothing overlaps: no thread (its hand-overs
    cost `accelcal batch` 3-4 % of its CPU time pinned to one core)."""
    it = iter(batches)
    if usable_cpus() == 1:
        yield from it
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="accelcal-csv") as ex:
        pending = ex.submit(next, it, None)
        try:
            while (batch := pending.result()) is not None:
                pending = ex.submit(next, it, None)
                yield batch
        finally:
            pending.cancel()
            wait([pending])


def _typed_batches(reader: Iterable[Any], check: _RowCheck) -> Iterator[Any]:
    """The typed reader's batches; a conversion error (a cell that is not a number) as _TypedCellError."""
    import pyarrow as pa

    it = iter(reader)
    while True:
        try:
            batch = next(it)
        except StopIteration:
            return
        except pa.ArrowInvalid as e:
            if not check.bad and "conversion error" in str(e).lower():
                raise _TypedCellError from None
            raise
        yield batch


def _after(batches: Iterable[Any], row0: int) -> Iterator[Any]:
    """The batches without their first ``row0`` rows (given out already by the typed read)."""
    left = row0
    for batch in batches:
        if left >= batch.num_rows:
            left -= batch.num_rows
            continue
        yield batch.slice(left) if left else batch
        left = 0


def _numpy(col: Any) -> np.ndarray:
    """An Arrow array as numpy: through its buffers when it can (arrow_arrays: no pandas imported),
    else Arrow's own conversion (nulls: NaN in a float copy)."""
    out = to_numpy(col)
    return col.to_numpy(zero_copy_only=False) if out is None else out

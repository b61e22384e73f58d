"""The results table of a lot: one row per board (fitted or not), CSV, Parquet or JSON lines.

Columns (RESULT_COLUMNS): serial, first_row (the board's first data row, 1-based), ok,
model, pose_count, input_units, input_per_g, W00..W22, V0..V2, Gamma0..Gamma2 (AN4399
form: calibrated_g = W reading/input_per_g + V + Gamma (reading/input_per_g)^3),
residual_rms_mg, residual_max_mg, crossval_rms_mg, crossval_by_orientation_rms_mg (every pose of
one distinct orientation left out at a time, models/crossval.py; the judged figure where
orientations repeat), condition_number, held (the terms the
fit held at nominal because the board's poses do not determine them, e.g. ``M_xy``,
models/held.py; "; "-joined, a list in JSON lines), verdict, reasons ("; "-joined, each
starting with its code) and message (why a board was not fitted).  Empty cells (null in
JSON/Parquet) where a value does not exist.

The table is written to a temporary file beside the output, flushed once per chunk, and
fsynced and renamed over the output when complete (atomic.atomic_write): it is whole or
absent.  (A temporary file left by a crash is never the output, so fsyncing it per chunk
would buy nothing: on the development machine it was a quarter of `accelcal batch`'s time.)
Where the process may use a second CPU, Arrow's CSV and Parquet writes run on a thread of their
own, one chunk behind the fit (`accelcal batch` on 2 CPUs: 1.53 -> 1.33 s for 200,000 boards);
the bytes are the same as written in line (tests/test_results_writer.py).
"""
from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import AbstractContextManager
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TypedDict

import numpy as np

from ..atomic import atomic_write
from ..calibration import PARAM_NAMES
from ..errors import DataError
from ..fileguard.cells import safe_texts
from ..models.threads import usable_cpus

if TYPE_CHECKING:
    from ..models.held import Held
    from .lotfile import LotChunk

FLOAT_COLUMNS = ("input_per_g", *PARAM_NAMES, "residual_rms_mg", "residual_max_mg", "crossval_rms_mg",
                 "crossval_by_orientation_rms_mg", "condition_number")
RESULT_COLUMNS = ("serial", "first_row", "ok", "model", "pose_count", "input_units", *FLOAT_COLUMNS, "held",
                  "verdict", "reasons", "message")
TEXT_COLUMNS = ("serial", "model", "input_units", "held", "verdict", "reasons", "message")
FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".jsonl": "jsonl", ".ndjson": "jsonl"}


class ChunkFit(TypedDict):
    """A chunk's fit, one entry per board (results_table.RESULT_COLUMNS' sources); NaN, 0 or
    empty where a board was not fitted (``ok`` False, ``message`` says why)."""

    ok: np.ndarray  # (B,) bool
    W: np.ndarray  # (B, 3, 3)
    V: np.ndarray  # (B, 3) g
    Gamma: np.ndarray  # (B, 3) 1/g^2
    residual_rms_g: np.ndarray  # (B,)
    residual_max_g: np.ndarray  # (B,)
    crossval_rms_g: np.ndarray  # (B,) leave-one-pose-out
    crossval_by_orientation_rms_g: np.ndarray  # (B,) leave-one-orientation-out
    distinct_orientations: np.ndarray  # (B,) int
    condition_number: np.ndarray  # (B,)
    stderr_V_max: np.ndarray  # (B,) g
    stderr_W_max: np.ndarray  # (B,)
    input_per_g: np.ndarray  # (B,) input units per g
    pose_count: np.ndarray  # (B,) int
    distinct_poses: np.ndarray  # (B,) int
    held: list[list[Held]]  # (B,) terms held at nominal (models/held.py)
    message: list[str]  # (B,) why a board was not fitted, "" where it was


# a results table's chunk: one column per RESULT_COLUMNS name, numbers as arrays, texts as str sequences
ResultColumns = dict[str, np.ndarray | Sequence[str]]


def _columns(chunk: LotChunk, res: ChunkFit, model: str, units: str, verdicts: Sequence[str],
             reasons: Sequence[Sequence[str]]) -> ResultColumns:
    """The chunk's results as one sequence per RESULT_COLUMNS column."""
    B = len(chunk.serials)
    params = np.concatenate([res["W"].reshape(B, 9), res["V"], res["Gamma"]], axis=1)
    cols: ResultColumns = {
        "serial": chunk.serials, "first_row": chunk.first_row, "ok": res["ok"], "model": [model] * B,
        "pose_count": res["pose_count"], "input_units": [units] * B, "input_per_g": res["input_per_g"]}
    for j, name in enumerate(PARAM_NAMES):
        cols[name] = params[:, j]
    cols.update(residual_rms_mg=res["residual_rms_g"] * 1e3, residual_max_mg=res["residual_max_g"] * 1e3,
                crossval_rms_mg=res["crossval_rms_g"] * 1e3,
                crossval_by_orientation_rms_mg=res["crossval_by_orientation_rms_g"] * 1e3,
                condition_number=res["condition_number"],
                held=(["; ".join(h.term for h in hs) for hs in res["held"]] if any(res.get("held", ()))
                      else [""] * B),  # a lot where no board holds a term: no per-board join
                verdict=verdicts, reasons=list(map("; ".join, reasons)), message=res["message"])
    return cols


def _safe_column(cells: np.ndarray | Sequence[str]) -> list[str]:
    """fileguard.cells.safe_texts of a text column; a column of one repeated value (the model, the
    units, an empty message) is screened once."""
    if isinstance(cells, list) and cells and cells.count(cells[0]) == len(cells):
        return [safe_texts(cells[:1])[0]] * len(cells)
    return safe_texts(cells)


def _text(a: np.ndarray) -> np.ndarray:
    """Floats as the shortest text that reads back exactly; '' for NaN."""
    s = a.astype(str)
    return np.where(np.isnan(a), "", s)


class ResultsWriter:
    """Append chunks to a results table at ``path`` (format from the extension)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.fmt = FORMATS.get(self.path.suffix.lower())
        if self.fmt is None:
            raise DataError(f"--out {self.path}: unknown format; allowed extensions: {', '.join(FORMATS)}")
        if self.path.is_symlink():
            raise DataError(f"--out {self.path}: is a symbolic link; give the real file (never written through)")
        if self.path.exists() and not self.path.is_file():
            raise DataError(f"--out {self.path}: exists and is not a file")
        if not self.path.resolve().parent.is_dir():
            raise DataError(f"--out {self.path}: cannot write (no such directory {self.path.parent})")
        if self.fmt == "parquet":
            try:
                import pyarrow  # noqa: F401
            except ImportError:
                raise DataError(f"--out {self.path}: Parquet needs pyarrow; pip install "
                                "'accelcal-station[parquet]', or write .csv / .jsonl") from None
        self._cm: AbstractContextManager[IO[Any]] | None = None
        self._f: IO[Any] | None = None
        self._pq: Any = None  # pyarrow's CSV or Parquet writer, once the first chunk is written
        self._arrow_csv: bool | None = None
        self._ex: ThreadPoolExecutor | None = None  # Arrow's writes, behind the caller (_behind)
        self._pending: Future[None] | None = None
        if self.fmt == "csv":
            from .lotfile import arrow_available
            self._arrow_csv = arrow_available()  # pyarrow's CSV writer: formats floats ~10x faster

    def __enter__(self) -> ResultsWriter:
        binary = bool(self.fmt == "parquet" or self._arrow_csv)
        self._cm = atomic_write(self.path, binary=binary)  # a private temp beside the output, renamed when whole
        try:
            self._f = self._cm.__enter__()
        except OSError as e:
            raise DataError(f"--out {self.path}: cannot write ({e.strerror})") from None
        if self.fmt == "csv" and not self._arrow_csv:
            self._f.write(",".join(RESULT_COLUMNS) + "\r\n")
        if (self.fmt == "parquet" or self._arrow_csv) and usable_cpus() > 1:
            self._ex = ThreadPoolExecutor(max_workers=1, thread_name_prefix="accelcal-results")
        return self

    @property
    def _out(self) -> IO[Any]:
        """The temporary file being written (open between __enter__ and __exit__)."""
        if self._f is None:
            raise DataError(f"--out {self.path}: not open; write chunks inside 'with ResultsWriter(...)'")
        return self._f

    def write_chunk(self, chunk: LotChunk, res: ChunkFit, model: str, units: str, verdicts: Sequence[str],
                    reasons: Sequence[Sequence[str]]) -> None:
        """Append one chunk's rows, flushed (fsynced once, when the table is complete)."""
        cols = _columns(chunk, res, model, units, verdicts, reasons)
        if self.fmt == "csv":  # a spreadsheet opens it: no text cell may be a formula (fileguard/cells.py)
            cols.update({c: _safe_column(cols[c]) for c in TEXT_COLUMNS})
        if self.fmt == "csv" and self._arrow_csv:
            self._write_arrow_csv(cols)
        elif self.fmt == "csv":
            buf = io.StringIO()
            text = {k: (_text(np.asarray(v, float)) if k in FLOAT_COLUMNS else
                        (np.asarray(v).astype(int).astype(str) if k in ("ok", "first_row", "pose_count") else v))
                    for k, v in cols.items()}
            csv.writer(buf).writerows(zip(*(text[c] for c in RESULT_COLUMNS), strict=True))
            self._out.write(buf.getvalue())
        elif self.fmt == "jsonl":
            B = len(chunk.serials)
            lists = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else list(v)) for k, v in cols.items()}
            lines = []
            for b in range(B):
                row = {c: lists[c][b] for c in RESULT_COLUMNS}
                row["ok"] = bool(row["ok"])
                for c in FLOAT_COLUMNS:
                    if row[c] != row[c]:  # NaN: no value
                        row[c] = None
                row["reasons"] = list(reasons[b])
                row["held"] = [h.term for h in res.get("held", [[]] * B)[b]]
                lines.append(json.dumps(row, allow_nan=False))
            self._out.write("\n".join(lines) + "\n")
        else:
            self._write_parquet(cols)
        if self._ex is None:
            self._out.flush()

    def _write_arrow_csv(self, cols: ResultColumns) -> None:
        import pyarrow.csv as pcsv
        table = _arrow_table(cols, csv=True)
        if self._pq is None:
            self._pq = pcsv.CSVWriter(self._out, table.schema,
                                      write_options=pcsv.WriteOptions(quoting_style="needed", eol="\r\n"))
        self._behind(self._pq.write_table, table)

    def _write_parquet(self, cols: ResultColumns) -> None:
        import pyarrow.parquet as pq
        table = _arrow_table(cols)
        if self._pq is None:
            self._pq = pq.ParquetWriter(self._out, table.schema)
        self._behind(self._pq.write_table, table)

    def _behind(self, write: Callable[[Any], None], table: Any) -> None:
        """Arrow's ``write(table)``, on a thread where a second CPU is free: Arrow formats and writes
        without the GIL, so the caller fits the next chunk meanwhile (`accelcal batch` on 2 CPUs).
        One write at a time, in order, at most one pending (memory stays a chunk's); its error
        is raised here, at the next chunk, or on leaving the ``with``."""
        self._wait()
        if self._ex is None:
            write(table)
        else:  # flushed by the writing thread, after its write, never midway
            self._pending = self._ex.submit(self._written_flushed, write, table)

    def _written_flushed(self, write: Callable[[Any], None], table: Any) -> None:
        write(table)
        self._out.flush()

    def _wait(self) -> None:
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: Any) -> None:
        assert self._cm is not None, "__exit__ after __enter__"
        try:
            try:
                self._wait()  # before the file is closed or removed, however the block ended
            finally:
                if self._ex is not None:
                    self._ex.shutdown()
            if self._pq is not None:
                self._pq.close()
        except BaseException as e:
            if exc is not None:  # the block's own error is the one said; the file is dropped either way
                self._cm.__exit__(exc_type, exc, tb)
                return
            self._cm.__exit__(type(e), e, e.__traceback__)
            raise
        try:
            self._cm.__exit__(exc_type, exc, tb)
        except OSError as e:
            raise DataError(f"--out {self.path}: cannot write ({e.strerror})") from None


def _arrow_table(cols: ResultColumns, csv: bool = False) -> Any:
    """The chunk as an Arrow table (null where a value does not exist); ok as 0/1 in CSV."""
    import pyarrow as pa

    from .arrow_arrays import booleans, numbers, strings  # not pa.array: no pandas imported (issue 51)
    arrays = []
    for c in RESULT_COLUMNS:
        v = cols[c]
        if c in FLOAT_COLUMNS:
            a = np.asarray(v, float)
            arrays.append(numbers(a, mask=np.isnan(a)))
        elif c == "ok":
            arrays.append(numbers(np.asarray(v, np.int8)) if csv else booleans(np.asarray(v, bool)))
        elif c in ("first_row", "pose_count"):
            arrays.append(numbers(np.asarray(v, np.int64)))
        else:
            arrays.append(strings(list(v)))
    return pa.Table.from_arrays(arrays, names=list(RESULT_COLUMNS))

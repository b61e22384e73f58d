"""Whole boards of a lot file as column arrays (the unit every lot reader yields), and the
checks every reader applies to a row before a board is formed from it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from .posetable import COLUMNS as POSE_COLUMNS
from .posetable import MAX_ABS_STD, MAX_SAMPLES
from .rawlog import MAX_ABS_READING

COLUMNS = ("serial",) + POSE_COLUMNS
NUMERIC = tuple(c for c in POSE_COLUMNS if c != "pose")
TEXT = ("serial", "pose")
# the values a pose can have, as a pose table allows them (posetable._pose): (columns, low, high, what)
RANGES: tuple[tuple[tuple[str, ...], float, float, str], ...] = (
    (("x", "y", "z"), -MAX_ABS_READING, MAX_ABS_READING, "reading"),
    (("pitch_deg", "roll_deg"), -360.0, 360.0, "angle (deg)"),
    (("ref_x", "ref_y", "ref_z"), -10.0, 10.0, "reference (g)"),
    (("std_x", "std_y", "std_z"), 0.0, MAX_ABS_STD, "std"),
    (("n",), 1.0, MAX_SAMPLES, "sample count n"),
    (("temp_c",), -273.15, 1000.0, "temperature (C)"),
)


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

    def __post_init__(self) -> None:
        screen(self)

    @property
    def row_end(self) -> int:
        """Data rows of the lot up to this chunk's last row (the next chunk's first row - 1)."""
        return int(self.first_row[0]) - 1 + int(self.starts[-1]) if len(self.first_row) else 0


def screen(chunk: LotChunk) -> None:
    """Every lot reader's one check of values, as boards are formed (so no later computation sees
    them, and no numpy warning is raised): a value outside its RANGES (infinity included) or a
    sample count that is not whole makes its board bad, naming the pose, column and value of its
    first such row, and is set to NaN; NaN is an empty cell (the readers refuse a 'nan' cell).
    A column whose extremes lie inside its range (most chunks) is cleared by two reductions."""
    c, starts = chunk.cols, chunk.starts
    first: dict[int, tuple[int, str]] = {}  # board -> (row, reason) of its first bad row
    with np.errstate(invalid="ignore"):
        for cols, lo, hi, what in RANGES:
            for k in (k for k in cols if k in c and len(c[k])):
                v = c[k]
                whole = k != "n" or bool(np.all(np.isnan(v) | (v == np.floor(v))))
                if whole and np.fmin.reduce(v) >= lo and np.fmax.reduce(v) <= hi:
                    continue
                out = (v < lo) | (v > hi) | (np.isfinite(v) & (v != np.floor(v)) if k == "n" else False)
                rows = np.flatnonzero(out)
                for r, b in zip(rows.tolist(), (np.searchsorted(starts, rows, side="right") - 1).tolist(),
                                strict=True):
                    if b not in first or r < first[b][0]:
                        allowed = f"{lo:g} to {hi:g}" if k != "n" else f"a whole number {lo:g} to {hi:g}"
                        first[b] = (r, f"pose {str(chunk.names[r])!r}: {k} {v[r]:g}: {what} out of range; "
                                       f"allowed {allowed}")
                c[k] = np.where(out, np.nan, v)
    for b, (_, why) in first.items():
        chunk.bad[b] = chunk.bad[b] or why


def missing_serial(path: Path, where: str) -> DataError:
    """The refusal of a row without a serial: it belongs to no board, and must not make one."""
    return DataError(f"{path}: {where}, column serial: empty or null; every row of a lot file needs its "
                     "board's serial (a row without one is not merged into any board)")


@dataclass(frozen=True)
class Labels:
    """A text column as codes into a table of its values: a lot's serials repeat for every pose
    and its pose names for every board, so no per-row string is built (a 200,000-board lot's
    1.6 million serials).  Two codes may name the same text (tables joined from several
    blocks, or cells equal once trimmed): compare texts, not codes."""

    table: np.ndarray  # (K,) str
    codes: np.ndarray  # (rows,) intp into table

    def __len__(self) -> int:
        return len(self.codes)

    def __getitem__(self, rows: slice) -> Labels:
        return Labels(self.table, self.codes[rows])

    def text(self) -> np.ndarray:
        """Every row's text (rows,)."""
        return self.table[self.codes]

    def compact(self) -> Labels:
        """The same rows with a table of their own texts (the rows carried over to the next block:
        their codes would otherwise keep every earlier block's table alive)."""
        return Labels(self.text(), np.arange(len(self.codes), dtype=np.intp))

    def changes(self) -> np.ndarray:
        """The rows i >= 1 whose text differs from row i - 1's: texts compared only where codes differ."""
        c = np.flatnonzero(self.codes[1:] != self.codes[:-1]) + 1
        return c[self.table[self.codes[c]] != self.table[self.codes[c - 1]]]

    @staticmethod
    def joined(parts: list[Labels]) -> Labels:
        """The rows of ``parts`` one after another."""
        offsets = np.cumsum([0] + [len(p.table) for p in parts[:-1]])
        return Labels(np.concatenate([p.table for p in parts]),
                      np.concatenate([p.codes + o for p, o in zip(parts, offsets, strict=True)]))


def arrays_chunk(serial: Labels, pose: Labels, cols: dict[str, np.ndarray], bad_rows: np.ndarray,
                 row0: int) -> LotChunk:
    """Whole boards from column arrays (``bad_rows``: a reason per row, 0 where none; bool zeros: none)."""
    n = len(serial)
    starts = np.concatenate([[0], serial.changes(), [n]]).astype(np.int64)
    bad: list[str | None] = [None] * (len(starts) - 1)
    if bad_rows.dtype == object:
        for i in np.flatnonzero(bad_rows.astype(bool)):  # 0 or a reason (a non-empty text) per row
            b = int(np.searchsorted(starts, i, side="right") - 1)
            bad[b] = bad[b] or bad_rows[i]
    return LotChunk(serial.table[serial.codes[starts[:-1]]].tolist(), starts,
                    {c: np.asarray(cols[c], dtype=float) for c in NUMERIC if c in cols}, pose.text(),
                    bad, row0 + starts[:-1] + 1)

"""Whole boards of a lot file as column arrays (the unit every lot reader yields), and the
checks every reader applies to a row before a board is formed from it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError
from .posetable import COLUMNS as POSE_COLUMNS

COLUMNS = ("serial",) + POSE_COLUMNS
NUMERIC = tuple(c for c in POSE_COLUMNS if c != "pose")
TEXT = ("serial", "pose")


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

    @property
    def row_end(self) -> int:
        """Data rows of the lot up to this chunk's last row (the next chunk's first row - 1)."""
        return int(self.first_row[0]) - 1 + int(self.starts[-1]) if len(self.first_row) else 0


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

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


def arrays_chunk(d: dict[str, np.ndarray], row0: int) -> LotChunk:
    """Whole boards from column arrays (``_bad``: a reason per row, 0 where none; bool zeros: none)."""
    serial = d["serial"].astype(str, copy=False)
    n = len(serial)
    change = np.flatnonzero(serial[1:] != serial[:-1]) + 1
    starts = np.concatenate([[0], change, [n]]).astype(np.int64)
    cols = {c: np.asarray(d[c], dtype=float) for c in NUMERIC if c in d}
    bad: list[str | None] = [None] * (len(starts) - 1)
    if "_bad" in d and d["_bad"].dtype == object:
        for i in np.flatnonzero(d["_bad"].astype(bool)):  # 0 or a reason (a non-empty text) per row
            b = int(np.searchsorted(starts, i, side="right") - 1)
            bad[b] = bad[b] or d["_bad"][i]
    return LotChunk(serial[starts[:-1]].tolist(), starts, cols, np.asarray(d["pose"]).astype(str, copy=False),
                    bad, row0 + starts[:-1] + 1)

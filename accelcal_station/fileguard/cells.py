"""Cells a spreadsheet would run, made inert before they are exported (CSV, HTML tables).

A spreadsheet opening a CSV or HTML table evaluates a cell that starts with ``=``, ``+``,
``-`` or ``@`` as a formula (``=cmd|' /C calc'!A0`` runs a program), and tab or carriage
return at the start can smuggle one in; OWASP's CSV-injection guidance: prefix such a cell
with a single quote so it is shown as text.  Only text cells are touched: a number, or a
text that is a number (``-0.5``, ``+1e-3``), stays a number.  Control characters (C0, DEL,
C1: an ESC from an operator name) are written as ``\\xNN`` so no terminal or viewer acts on them.
"""
from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_LINE_FORMULA = re.compile(r"^[=+\-@]", re.MULTILINE)  # a formula start (\t and \r are control characters)
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(inf|nan)", re.IGNORECASE)


def safe_text(text: str) -> str:
    """``text`` as an inert cell: a leading formula character quoted, control characters escaped."""
    if text.startswith(FORMULA_START) and not _NUMBER.fullmatch(text):
        text = "'" + text
    return _CONTROL.sub(lambda m: f"\\x{ord(m[0]):02x}", text)


def safe_texts(values: Sequence[Any] | np.ndarray) -> list[str]:
    """A column of cells, each as ``safe_text(str(cell))``, with the per-cell Python only for the
    cells that need it: control characters are looked for in the joined column, formula starts
    at the line starts of the column joined by newlines (two regex passes, no per-cell call)."""
    cells = values.tolist() if isinstance(values, np.ndarray) else list(values)
    try:
        joined = "".join(cells)
    except TypeError:  # a cell that is not text
        joined = "\x00"
    if _CONTROL.search(joined):
        return [safe_text(str(c)) for c in cells]
    # no cell holds a newline (a control character), so line starts are cell starts
    starts = [m.start() for m in _LINE_FORMULA.finditer("\n".join(cells))]
    if starts:
        lens = np.fromiter(map(len, cells), dtype=np.int64, count=len(cells)) + 1
        offsets = np.cumsum(lens) - lens  # where each cell starts in the joined text
        for i in np.searchsorted(offsets, starts).tolist():
            cells[i] = safe_text(cells[i])
    return cells


def safe_cell(value: Any) -> Any:
    """A text cell made inert (safe_text); any other value (a number, None) as it is."""
    return safe_text(value) if isinstance(value, str) else value


def safe_row(row: Iterable[Any]) -> list[Any]:
    """Every cell of a row through safe_cell."""
    return [safe_cell(v) for v in row]

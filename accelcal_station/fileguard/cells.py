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
from collections.abc import Iterable
from typing import Any

FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(inf|nan)", re.IGNORECASE)


def safe_text(text: str) -> str:
    """``text`` as an inert cell: a leading formula character quoted, control characters escaped."""
    if text.startswith(FORMULA_START) and not _NUMBER.fullmatch(text):
        text = "'" + text
    return _CONTROL.sub(lambda m: f"\\x{ord(m[0]):02x}", text)


def safe_cell(value: Any) -> Any:
    """A text cell made inert (safe_text); any other value (a number, None) as it is."""
    return safe_text(value) if isinstance(value, str) else value


def safe_row(row: Iterable[Any]) -> list[Any]:
    """Every cell of a row through safe_cell."""
    return [safe_cell(v) for v in row]

"""A number read from a file or an option is finite ASCII decimal notation, nothing else.

Python's ``float``/``int`` (and numpy's string conversion) also take ``4_096``, Arabic-Indic
(``٤٠٩٦``) or full-width digits and the words ``nan``/``inf``/``infinity``: a cell a spreadsheet,
a logger or another tool would not read as that number.  Every reader and numeric option checks
its text with :func:`is_decimal` (``[+-]digits[.digits][e[+-]digits]``, ASCII only, blanks around
allowed) so such a value is refused in one line, never read as a number.
"""
from __future__ import annotations

import re

_DECIMAL = re.compile(r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*", re.ASCII)
ALLOWED = "a finite number in ASCII decimal notation (digits, '.', an exponent; no '_', no other digits)"


def is_decimal(text: str) -> bool:
    """Whether ``text`` is a number in ASCII decimal notation (module doc)."""
    return _DECIMAL.fullmatch(text) is not None


def all_decimal(cells: list[str]) -> bool:
    """Whether every non-empty cell may be decimal notation, judged on the joined text in one pass:
    ASCII, no '_' and no letter but an exponent's (a False sends the caller to check cell by cell)."""
    joined = "".join(cells)
    return joined.isascii() and "_" not in joined and not any(c.isalpha() and c not in "eE" for c in set(joined))


def decimal_float(text: str) -> float:
    """``float(text)`` when ``text`` is decimal notation; ValueError otherwise (as ``float`` raises)."""
    if not is_decimal(text):
        raise ValueError(f"{text!r} is not {ALLOWED}")
    return float(text)

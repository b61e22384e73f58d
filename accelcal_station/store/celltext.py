"""Text cells decoded one by one: a byte that is not UTF-8 damages its cell, never the query.

SQLite stores whatever bytes it is given in a TEXT column; Python's sqlite3 decodes every
text value of a result as UTF-8 and raises for the whole query at the first bad byte, so
one hand-edited cell would make the whole store unreadable.  ``decode_text`` is the
connection's ``text_factory``: a good cell is a ``str``, a bad one a ``BadText`` (a ``str``
showing its bad bytes as ``\\xNN``) that rowcheck names as a ``damaged_row``.
"""
from __future__ import annotations


class BadText(str):
    """A text cell whose bytes are not UTF-8, shown with the bad bytes escaped; ``problem`` says where."""

    problem: str

    def __new__(cls, raw: bytes, error: UnicodeDecodeError) -> BadText:
        self = super().__new__(cls, raw.decode("utf-8", "backslashreplace"))
        self.problem = f"text not UTF-8 (byte 0x{raw[error.start]:02x} at offset {error.start})"
        return self


def decode_text(raw: bytes) -> str:
    """A TEXT value as ``str``; a ``BadText`` when its bytes are not UTF-8 (module doc)."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        return BadText(raw, e)

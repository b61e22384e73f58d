"""What kind of file an existing output target is, sniffed from its first bytes.

A writing command may replace a file of the kind it writes (a CSV with a CSV), never a
results store or a file of another kind (a calibration JSON where a CSV goes, a CSV where
a JSON goes, an SQLite database anywhere): ``refuse_kind`` says so in one line (exit 2)
before anything is written, unless the command was given ``--force``.

Sniffing reads at most HEAD_BYTES of a regular file: magic numbers first (SQLite's
"SQLite format 3\\0", PNG, Parquet's PAR1, PDF, ZIP), then text: markup (``<``), JSON
(``{`` or ``[``), YAML (``---`` or a ``key:`` first line), CSV (a first data line with a
comma, semicolon or tab) or other text; NUL bytes or bytes that are not UTF-8 make a
binary file.  An empty or absent file has no kind and may be written.
"""
from __future__ import annotations

import codecs
import contextlib
import os
import re
import stat
from pathlib import Path

from ..errors import DataError

HEAD_BYTES = 4096
SQLITE_MAGIC = b"SQLite format 3\x00"
_MAGIC = ((SQLITE_MAGIC, "sqlite"), (b"\x89PNG\r\n\x1a\n", "png"), (b"PAR1", "parquet"), (b"%PDF", "pdf"),
          (b"PK\x03\x04", "zip"))
_YAML_KEY = re.compile(r"^[A-Za-z_][\w.-]*:(\s|$)")

# what each output kind may replace ("text": a text file of no stronger kind, e.g. one CSV column)
COMPATIBLE: dict[str, frozenset[str]] = {
    "csv": frozenset({"csv", "text"}),
    "json": frozenset({"json"}),
    "jsonl": frozenset({"json"}),
    "yaml": frozenset({"yaml", "text"}),
    "html": frozenset({"html"}),
    "png": frozenset({"png"}),
    "parquet": frozenset({"parquet"}),
    "markdown": frozenset({"text", "csv", "yaml"}),  # prose: any text file but JSON or markup
    "store": frozenset({"sqlite"}),
}
DESCRIBED = {"sqlite": "an SQLite database (a results store)", "png": "a PNG image", "parquet": "a Parquet file",
             "pdf": "a PDF document", "zip": "a ZIP archive", "binary": "a binary file", "html": "an HTML/XML file",
             "json": "a JSON file", "yaml": "a YAML file", "csv": "a CSV table", "text": "a text file",
             "markdown": "a Markdown file", "jsonl": "a JSON-lines file", "store": "a results store",
             "directory": "a directory"}


def _text_kind(text: str) -> str:
    """The kind of a text file's head (module doc)."""
    lines = [ln.strip() for ln in text.lstrip("\ufeff").splitlines()]
    first = next((ln for ln in lines if ln), "")
    if first.startswith("<"):
        return "html"
    if first.startswith(("{", "[")):
        return "json"
    if first == "---" or first.startswith("%YAML"):
        return "yaml"
    data = next((ln for ln in lines if ln and not ln.startswith("#")), "")
    if _YAML_KEY.match(data):
        return "yaml"
    if any(c in data for c in ",;\t"):
        return "csv"
    return "text"


def sniff(path: str | Path) -> str | None:
    """The kind of the existing regular file ``path`` (module doc); None when absent, empty or not a
    regular file (those are refused, or written, by the writers' own checks)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    if not stat.S_ISREG(st.st_mode) or st.st_size == 0:
        return None
    head = b""
    with contextlib.suppress(OSError), open(path, "rb") as f:
        head = f.read(HEAD_BYTES)
    if not head:
        return None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if b"\x00" in head:
        return "binary"
    try:  # a multi-byte character cut at the end of the head is still text (final only for a whole file)
        text = codecs.getincrementaldecoder("utf-8")().decode(head, final=len(head) < HEAD_BYTES)
    except UnicodeDecodeError:
        return "binary"
    return _text_kind(text)


def is_sqlite(path: str | Path) -> bool:
    """Whether ``path`` is an existing file that starts with SQLite's header (a store, whatever its name)."""
    return sniff(path) == "sqlite"


def refuse_kind(label: str, path: str | Path, kind: str | None, force: bool = False) -> None:
    """One DataError (exit 2) when ``path`` names a database URL, or an existing file that is an SQLite
    database or not of a kind an output of ``kind`` may replace (COMPATIBLE); ``force`` allows the
    latter two.  ``kind`` None: only the URL and SQLite checks."""
    text = str(path)
    if "://" in text:
        raise DataError(f"{label} {text}: a database URL, not a file name; refusing to write a file named so "
                        "(nothing written); give a file path")
    found = sniff(path)
    if found is None or force:
        return
    if kind != "store" and found == "sqlite":
        raise DataError(f"{label} {text}: an existing SQLite database (a results store); refusing to overwrite "
                        "it (nothing written); choose another file, or add --force to replace it")
    if kind is not None and found not in COMPATIBLE.get(kind, frozenset({kind})):
        raise DataError(f"{label} {text}: an existing file of another kind ({DESCRIBED.get(found, found)}, "
                        f"not {DESCRIBED.get(kind, kind)}); refusing to overwrite it (nothing written); "
                        "choose another file, or add --force to replace it")

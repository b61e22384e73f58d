"""JSON documents from files that may be hostile: nesting and size bounded before parsing.

Python's json module recurses once per nesting level (a few thousand ``[`` raise
RecursionError) and turns a 5,000-digit integer into a ValueError of its own; both are
refused here as one error line naming the file, as is anything that is not JSON.
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import AccelcalError, DataError
from .regular import read_bytes

MAX_DEPTH = 64  # every document the station writes nests under 6 levels
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)


def nesting_depth(text: str) -> int:
    """How deep ``[`` and ``{`` nest outside strings (vectorised: linear in the text)."""
    bare = _STRING.sub("", text).encode("utf-8", "surrogatepass")
    b = np.frombuffer(bare, dtype=np.uint8)
    step = np.isin(b, (ord("["), ord("{"))).astype(np.int64) - np.isin(b, (ord("]"), ord("}")))
    return int(np.cumsum(step).max(initial=0))


def parse_json(text: str, source: str, what: str, error: type[AccelcalError] = DataError) -> Any:
    """``text`` parsed, or one ``error``: "SOURCE: not WHAT (not JSON, line N: ...)", too deep, a bad number."""
    depth = nesting_depth(text)
    if depth > MAX_DEPTH:
        raise error(f"{source}: not {what} (nested {depth} levels deep; at most {MAX_DEPTH})")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error(f"{source}: not {what} (not JSON, line {e.lineno}: {e.msg})") from None
    except (ValueError, RecursionError) as e:  # e.g. an integer of more digits than Python converts
        raise error(f"{source}: not {what} (unreadable JSON: {str(e)[:80]})") from None


def read_json(path: str | Path, what: str, limit_bytes: int, why: str,
              error: type[AccelcalError] = DataError) -> Any:
    """A JSON document from a regular file of at most ``limit_bytes`` (regular.read_bytes)."""
    data = read_bytes(path, what, limit_bytes, why, error)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"{path}: not {what} (not a text file)") from None
    return parse_json(text, str(path), what, error)

"""Reading a configuration file: size, encoding and YAML errors as one line naming the file.

The keys themselves are checked by the declared models (schema.py, parts.py); ``check_keys``
and ``number`` remain for sim/population.py, whose keys are the quantities a population names."""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, overload

import yaml

from ..errors import ConfigError
from ..fileguard.regular import read_bytes
from ..jsontypes import JsonObject
from .safe_yaml import MAX_BYTES, HostileYAML, safe_load


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; errors name the file and line."""
    return load_yaml_text(path)[0]


def load_yaml_text(path: str | Path) -> tuple[dict[str, Any], str]:
    """A YAML mapping and the text it was parsed from (read once: a run records the very text
    its configuration came from, not a second read that may see another file)."""
    p = Path(path)
    # a regular file only (a FIFO, device or /proc entry would block or never end), sized before it is read
    raw = read_bytes(p, "a configuration", MAX_BYTES, "a station config is a few kB", ConfigError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text file (expected a YAML configuration)") from None
    try:
        data = safe_load(text)
    except HostileYAML as e:
        raise ConfigError(f"{p}: refused ({e})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}:{where} not valid YAML ({getattr(e, 'problem', e)})") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: must be a YAML mapping at top level")
    return data, text


def check_keys(d: object, allowed: Iterable[str], path: str) -> JsonObject:
    """Refuse unknown keys (typos must not be silently ignored)."""
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError(f"{path}: must be a mapping")
    allowed = list(allowed)
    for k in d:
        if k not in allowed:
            raise ConfigError(f"{path}.{k}: unknown key; allowed: {', '.join(allowed)}")
    return d


@overload
def number(d: Mapping[str, object], key: str, path: str, default: float | None = None, lo: float | None = None,
           hi: float | None = None, integer: Literal[False] = False) -> float: ...


@overload
def number(d: Mapping[str, object], key: str, path: str, default: int | None = None, lo: float | None = None,
           hi: float | None = None, *, integer: Literal[True]) -> int: ...


def number(d: Mapping[str, object], key: str, path: str, default: float | None = None, lo: float | None = None,
           hi: float | None = None, integer: bool = False) -> float:
    """A number within [lo, hi]; ``default`` when absent (None means required)."""
    if key not in d or d[key] is None:
        if default is None:
            raise ConfigError(f"{path}.{key}: required")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(f"{path}.{key}: {v!r} is not a number")
    if v != v or v in (float("inf"), float("-inf")):
        raise ConfigError(f"{path}.{key}: {v!r} is not a finite number")
    if integer and int(v) != v:
        raise ConfigError(f"{path}.{key}: {v!r} must be a whole number")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        rng = f"{'-inf' if lo is None else lo} to {'inf' if hi is None else hi}"
        raise ConfigError(f"{path}.{key}: {v!r} out of range; allowed {rng}")
    return int(v) if integer else float(v)

"""Reading a configuration file: size, encoding and YAML errors as one line naming the file.

The keys themselves are checked by the declared models (schema.py, parts.py)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from ..errors import ConfigError
from .safe_yaml import MAX_BYTES, HostileYAML, safe_load


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; errors name the file and line."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if p.is_file() and size > MAX_BYTES:  # refused by its size before a byte is read
            raise ConfigError(f"{p}: {size} bytes; a configuration is at most {MAX_BYTES} bytes")
        with open(p, encoding="utf-8") as f:
            text = f.read(MAX_BYTES + 1)  # a FIFO or device is never read without end
    except OSError as e:
        raise ConfigError(f"{p}: cannot read ({e.strerror})") from None
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
    return data

"""Where a results store is: the store of a station config, a store the user names (a file
path or a URL) and a store's identity (what makes two targets the same store).
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from ..config.parts import parse
from ..config.schema import StoreSection
from ..errors import ConfigError
from .database import DEFAULT_STORE as DEFAULT_STORE  # its home before issue 51; callers import it here
from .database import describe_target, is_url


def store_path(config: Mapping[str, object] | StoreSection | None, base_dir: str | Path = ".") -> Path | str:
    """The store of a station config: ``store: {path: FILE or URL}`` (default DEFAULT_STORE),
    a relative path taken from ``base_dir`` (the config file's folder); a URL
    (``postgresql://...``, ``sqlite:///...``) is returned as it is.  ``config``: a config
    mapping not yet validated, or its validated ``store`` section."""
    p = _store_section(config).path
    if not p.strip():
        raise ConfigError(f"store.path: {p!r}; allowed: a file path, sqlite:///PATH or postgresql://...")
    return store_target(p, base_dir)


def store_target(p: str | Path, base_dir: str | Path = ".") -> Path | str:
    """A store given by the user: a URL as it is, a path taken from ``base_dir``."""
    if is_url(p):
        return str(p)
    return Path(base_dir) / Path(p).expanduser()


def store_identity(target: str | Path) -> str:
    """A store's identity: the resolved file of an SQLite store, the URL of a server store."""
    if is_url(target) and not str(target).startswith("sqlite:///"):
        return describe_target(target)
    p = str(target)[len("sqlite:///"):] if str(target).startswith("sqlite:///") else target
    return str(Path(p).resolve())


def outbox_of(config: Mapping[str, object] | StoreSection | None, base_dir: str | Path = ".") -> Path | None:
    """``store: {outbox: FILE}``: where a station keeps results while its line database is
    unreachable (outbox.py; default None: outbox.default_outbox())."""
    p = _store_section(config).outbox
    if p is None:
        return None
    if not p.strip() or is_url(p):
        raise ConfigError(f"store.outbox: {p!r}; allowed: a file path (a local SQLite file)")
    return Path(base_dir) / Path(p).expanduser()


def _store_section(config: Mapping[str, object] | StoreSection | None) -> StoreSection:
    """A validated ``store`` section: as given, or checked from a config mapping."""
    if isinstance(config, StoreSection):
        return config
    return parse(None if config is None else config.get("store"), StoreSection, "store")

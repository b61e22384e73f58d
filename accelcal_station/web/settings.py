"""What a web server reads: the store, the limits to draw, the token; and the store for one request."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from ..store.reader import StoreReader


@dataclass
class WebSettings:
    """What a server reads: the store, the token for writes, the read token.  ``limits`` (the first
    --config's) is kept for callers only: every chart draws each run against its own limits."""

    store: str
    limits: dict[str, float] = field(default_factory=dict)
    token: str | None = None
    poll_s: float = 0.5  # how often the events stream looks for finished runs
    read_token: str | None = None  # web.read_token: every request needs it (Bearer, or Basic with it as password)
    heavy_lanes: int = 1  # lot and board pages served at once, each in a worker process; more wait their turn


@contextmanager
def open_store(settings: WebSettings) -> Iterator[StoreReader]:
    """The store for one request, a StoreReader: never created, migrated or written (SQLite opened
    ``mode=ro``; a store at another schema version is one error naming the command that upgrades it)."""
    with StoreReader(settings.store) as st:
        yield st

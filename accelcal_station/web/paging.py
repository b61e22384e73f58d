"""Pages of runs for the lot and reason pages, on the MES API's cursors (api.py: ``a``/``d`` and the
last id delivered): newest first, "older" and "newer" links, each page one keyset read on id (no
OFFSET, so the thousandth page costs what the first does).

Order: by run id, the order the store recorded the runs (unique, so stable; the API's order too).
A page is fetched with one run more than it shows, to know whether an older (or newer) page exists;
a page reached by "newer" is read oldest first from its cursor and shown reversed.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TypedDict

from .api import PAGE_CURSOR, decode_cursor, encode_cursor
from .views import RunView

# a page's cursor as the pages take it: an API cursor, "oldest" (the oldest page), or empty (the newest)
PAGE_PARAM = rf"^({PAGE_CURSOR[1:-1]}|oldest)?$"
PAGE_SIZE = 100
PAGE_SIZE_MAX = 1000

# fetch(order "asc"/"desc", after id (exclusive) or None, at most n) -> runs in that order
Fetch = Callable[[str, int | None, int], list[RunView]]


class RunsPage(TypedDict):
    """One page of runs, newest first, and the cursors of its neighbours (None: there is none)."""

    runs: list[RunView]
    older: str | None
    newer: str | None
    limit: int
    cursor: str


def _ids(runs: list[RunView]) -> list[int]:
    return [i for r in runs if (i := r["id"]) is not None]


def page_of(fetch: Fetch, cursor: str, limit: int) -> RunsPage:
    """The page ``cursor`` names (PAGE_PARAM): "" the newest, "oldest" the oldest, an API cursor the
    page after its id in its order."""
    if cursor in ("", "oldest"):
        order, after = ("asc", None) if cursor == "oldest" else ("desc", None)
    else:
        order, after = decode_cursor(cursor)
    got = fetch(order, after, limit + 1)
    more, shown = len(got) > limit, got[:limit]
    ids = _ids(shown)
    if order == "desc":
        older = encode_cursor("desc", ids[-1]) if more and ids else None
        newer = encode_cursor("asc", ids[0]) if after is not None and ids and fetch("asc", ids[0], 1) else None
        runs = shown
    else:
        newer = encode_cursor("asc", ids[-1]) if more and ids else None
        older = encode_cursor("desc", ids[0]) if ids and fetch("desc", ids[0], 1) else None
        runs = shown[::-1]
    return {"runs": runs, "older": older, "newer": newer, "limit": limit, "cursor": cursor}

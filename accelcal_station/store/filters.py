"""The run filters of the store's reads (``Store.list_runs``, ``Store.runs``, ...) as SQL clauses.

device, station, lot, operator, verdict, status, model: a value or a list of values; since,
until: unix seconds, a datetime or ISO 8601 text (records.timestamp); run_ids: a list of ids.
An unknown filter is a TypeError, as an unknown keyword is.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping

from sqlalchemy import ColumnElement

from .records import timestamp
from .tables import runs

_COLUMNS = {"device": runs.c.device_serial, "station": runs.c.station_id, "lot": runs.c.lot,
            "operator": runs.c.operator, "verdict": runs.c.verdict, "status": runs.c.status, "model": runs.c.model}
_TIMES = ("since", "until", "run_ids")


def _values(name: str, v: object) -> list[object]:
    if isinstance(v, (str, int)):
        return [v]
    if not isinstance(v, Iterable):
        raise TypeError(f"filter {name}={v!r}: allowed a value or a list of values")
    return list(v)


def where(filters: Mapping[str, object]) -> list[ColumnElement[bool]]:
    """The clauses selecting the runs that match ``filters`` (None: not filtered)."""
    unknown = set(filters) - set(_COLUMNS) - set(_TIMES)
    if unknown:
        raise TypeError(f"unknown run filter(s) {', '.join(sorted(unknown))}; allowed: "
                        f"{', '.join([*_COLUMNS, *_TIMES])}")
    clauses: list[ColumnElement[bool]] = [col.in_([str(x) for x in _values(name, v)])
                                          for name, col in _COLUMNS.items() if (v := filters.get(name)) is not None]
    for name in ("since", "until"):
        t = timestamp(filters.get(name), name)
        if t is not None:
            clauses.append(runs.c.started_at >= t if name == "since" else runs.c.started_at < t)
    ids = filters.get("run_ids")
    if ids is not None:
        clauses.append(runs.c.id.in_([int(str(i)) for i in _values("run_ids", ids)]))
    return clauses

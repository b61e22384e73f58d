"""The MES JSON API under /api/v1 (documented by the OpenAPI schema at /openapi.json).

Runs (list with filters, one run with its calibration and reasons), yields per station and
shift, and the feed of finished runs (feed.py): ``GET /events?after=CURSOR`` (JSON, long
poll) and ``GET /events/stream`` (server-sent events; resume with the Last-Event-ID
header).  Read-only: nothing here writes the store.  Errors are JSON ``{code, message}``
(errors.ErrorBody), declared on every endpoint; every number is bounded by its type
(run ids int64), so an out-of-range value is a 4xx answer, never a 500.
"""
from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

from fastapi import APIRouter, Depends, Header, Query
from fastapi import Path as FPath
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field, WithJsonSchema
from typing_extensions import TypedDict  # response models: pydantic on 3.11 wants this one

from ..errors import DataError
from ..store.records import RunLabels, RunNotFound, RunSetup, RunTimes, StoredPose, timestamp
from ..store.rowcheck import T_MAX_S
from . import queries
from .errors import ERROR_RESPONSES, ApiError
from .feed import Cursor, Step, advance, head
from .settings import open_store
from .views import RunFigures, RunFilters, RunView, ShiftYield, StationYield

if TYPE_CHECKING:
    from .settings import WebSettings


# the OpenAPI has always documented these as open objects: their values are typed for validation,
# the schema stays what clients were given
_OPEN_OBJECT = WithJsonSchema({"additionalProperties": True, "type": "object"})
YieldRow = Annotated[dict[str, float | int | str | None], _OPEN_OBJECT]  # queries.StationYield / ShiftYield


class RunId(TypedDict):
    """A run's id as the API gives it: an integer (the web's RunView reads a damaged id as None)."""

    id: int


class RunSummary(RunId, RunTimes, RunLabels, RunFigures):
    """A run without its poses; a damaged stored value reads as null and is named in ``damage``
    (table, id, column, problem: the store's ``damaged_row``).  ``limits``: the acceptance limits
    the run was judged by ({key: number}; keys and units as the config's ``acceptance`` section),
    ``limits_source`` "stored" (recorded with the run), "config" (an older run: its own config's
    acceptance section) or null."""

    # [] when nothing is damaged: the API always gives the key (the web's RunView only when damaged)
    damage: Annotated[list[dict[str, str]], Field(default=[])]


class RunPage(BaseModel):
    """One page of runs; ``next_cursor`` (null on the last page) fetches the next one in the same order."""

    runs: list[RunSummary]
    order: str
    next_cursor: str | None
    total: int | None = None  # the runs matching the filters, when asked for (total=true)


class Pose(StoredPose):
    pass  # the stored pose under the name the OpenAPI has always given it


class RunEvent(TypedDict):
    t: float | None
    kind: str | None
    message: str | None
    data: Annotated[Any, Field(default=None)]  # any JSON, as logged (StoredEvent.data: a JsonValue)


class RunDetailPart(RunSetup):
    """What a run in full adds to its summary: its setup, the stored JSON documents, poses and events."""

    # stored JSON documents: JsonObject where they are built (checked by mypy); Any here keeps the
    # OpenAPI's open object (pydantic's own JsonValue would add a schema of its own to it)
    nvm_outcome: dict[str, Any] | None
    calibration: dict[str, Any] | None
    fit_summary: dict[str, Any] | None
    poses: list[Pose]
    events: list[RunEvent]


class RunDetail(RunSummary, RunDetailPart):
    """One run in full: its poses (session units), events, calibration (AN4399 W, V, Gamma), the fit
    summary and NVM outcome as recorded."""


class Event(BaseModel):
    """A finished run; ``id`` is the cursor to resume after it."""

    id: str
    run: RunSummary


class EventPage(BaseModel):
    events: list[Event]
    next: str


class EventHead(BaseModel):
    next: str


class YieldSummary(BaseModel):
    window_from: float | None
    stations: list[YieldRow]
    shifts: list[YieldRow]
    failure_reasons: dict[str, int]


# what the endpoints return, checked by mypy here and by the response models above at run time
class RunPageOut(TypedDict):
    runs: list[RunView]
    order: str
    next_cursor: str | None
    total: int | None


class RunDetailOut(RunView, RunDetailPart):
    """RunDetail as built from the web's RunView (the response model checks the id at run time)."""


class YieldOut(TypedDict):
    window_from: float | None
    stations: list[StationYield]
    shifts: list[ShiftYield]
    failure_reasons: dict[str, int]


class EventOut(TypedDict):
    id: str
    run: RunView


class EventPageOut(TypedDict):
    events: list[EventOut]
    next: str


ID_MIN, ID_MAX = -(2**63), 2**63 - 1  # run ids are BIGINT (int64): negative ones too, as SQLite stores them
TEXT_MAX = 200  # a station, serial or lot filter
# every parameter's pattern, declared in the OpenAPI, so a request that matches it is answered (issue 53)
_INT = r"-?[0-9]{1,19}"
EVENT_ID = rf"^({_INT}(:({_INT}(,{_INT})*)?)?)?$"  # a feed cursor: low[:done,done,...] (feed.Cursor)
PAGE_CURSOR = r"^[ad](0|-?[1-9][0-9]{0,18})$"  # a page cursor: its order (a/d) and the last id delivered
NO_CONTROL = r"^[^\x00-\x1f\x7f]*$"  # a text filter: no control characters
_MD = r"((0[13578]|1[02])-(0[1-9]|[12][0-9]|3[01])|(0[469]|11)-(0[1-9]|[12][0-9]|30)|02-(0[1-9]|1[0-9]|2[0-8]))"
_LEAP = r"(19(7[26]|8[048]|9[26])|[2-9][0-9](0[48]|[2468][048]|[13579][26])|([2468][048]|[3579][26])00)"
_CLOCK = r"(T([01][0-9]|2[0-3])(:[0-5][0-9](:[0-5][0-9](\.[0-9]{1,6})?)?)?(Z|[+-]([01][0-9]|2[0-3]):[0-5][0-9])?)?"
# unix seconds, or an ISO 8601 calendar date (1970-9999, 29 February in leap years only) with an optional time
TIME = rf"^(-?[0-9]{{1,20}}(\.[0-9]{{1,20}})?|((19[7-9][0-9]|[2-9][0-9]{{3}})-{_MD}|{_LEAP}-02-29){_CLOCK})$"


def _feed(settings: WebSettings, cursor: Cursor, limit: int) -> tuple[list[Step], list[RunView]]:
    """The next steps of the feed after ``cursor`` and their runs (one store open, read only)."""
    with open_store(settings) as st:
        steps = advance(cursor, queries.feed_rows(st, cursor.low), time.time(), limit)
        runs = queries.summaries(st, [s.run_id for s in steps])
    return steps, runs


def api_router(settings: WebSettings) -> APIRouter:
    r = APIRouter(responses=ERROR_RESPONSES)
    _runs_routes(r, settings)
    _feed_routes(r, settings)
    return r


def encode_cursor(order: str, last_id: int) -> str:
    """A page cursor: the order ("a" ascending, "d" descending) and the last id delivered."""
    return f"{'a' if order == 'asc' else 'd'}{int(last_id)}"


def decode_cursor(text: str) -> tuple[str, int]:
    """(order, last id) of a cursor matching PAGE_CURSOR (checked by the route); an id past the
    int64 range pages on as past every id a store holds."""
    return ("asc" if text[0] == "a" else "desc"), int(text[1:])


def _text(name: str, v: str | None) -> str | None:
    if v is not None and any(ord(c) < 32 for c in v):
        raise ApiError(400, "invalid_request", f"{name}: control characters are not allowed")
    return v


@dataclass(frozen=True)
class RunPageQuery:
    """GET /runs' query: the filters, the order by id, the page (cursor, limit) and whether to count."""

    since: str | None = Query(None, max_length=64, pattern=TIME,
                              description="started at or after (ISO 8601 1970-9999, or unix s)")
    until: str | None = Query(None, max_length=64, pattern=TIME,
                              description="started before (ISO 8601 1970-9999, or unix s)")
    station: str | None = Query(None, max_length=TEXT_MAX, pattern=NO_CONTROL)
    serial: str | None = Query(None, max_length=TEXT_MAX, pattern=NO_CONTROL)
    verdict: str | None = Query(None, pattern="^(PASS|FAIL)$")
    lot: str | None = Query(None, max_length=TEXT_MAX, pattern=NO_CONTROL)
    status: str | None = Query(None, pattern="^(running|complete|interrupted|error|stale)$")
    order: str = Query("desc", pattern="^(asc|desc)$", description="by id: desc newest first")
    cursor: str | None = Query(None, max_length=21, pattern=PAGE_CURSOR,
                               description="next_cursor of the previous page (it carries its order)")
    limit: int = Query(100, ge=1, le=1000)
    total: bool = Query(False, description="count the runs matching the filters")


def _runs_routes(r: APIRouter, settings: WebSettings) -> None:
    @r.get("/runs", response_model=RunPage, summary="Runs, a page at a time (keyset on id; newest first by default)")
    def list_runs(q: Annotated[RunPageQuery, Depends()]) -> RunPageOut:
        f: RunFilters = {"since": _time(q.since, "since"), "until": _time(q.until, "until"),
                         "station": _text("station", q.station), "serial": _text("serial", q.serial),
                         "verdict": q.verdict, "lot": _text("lot", q.lot), "status": q.status}
        order, cursor, limit, total = q.order, q.cursor, q.limit, q.total
        after = None
        if cursor is not None:  # a cursor continues the order it was made for
            order, after = decode_cursor(cursor)
        with open_store(settings) as st:
            runs = queries.run_page(st, f, order, after, limit + 1)
            n = queries.run_count(st, f) if total else None
        more = len(runs) > limit
        runs = runs[:limit]
        last = runs[-1]["id"] if runs else None
        return {"runs": runs, "order": order, "total": n,
                "next_cursor": encode_cursor(order, last) if more and last is not None else None}

    @r.get("/runs/{run_id}", response_model=RunDetail,
           summary="One run with its calibration, reasons, poses and events")
    def one_run(run_id: int = FPath(ge=ID_MIN, le=ID_MAX)) -> RunDetailOut:
        with open_store(settings) as st:
            try:
                rec = st.get_run(run_id)
            except RunNotFound:  # a store that cannot be read is 503 (errors.py), not a missing run
                raise ApiError(404, "not_found", f"no run {run_id}") from None
            one = queries.summaries(st, [run_id])
        if not one:  # the run read a moment ago is gone
            raise ApiError(404, "not_found", f"no run {run_id}")
        d = rec.to_dict()
        # the summary's own damage (its row's values) when it has any, else every damaged value of the run
        return {**one[0], "damage": one[0].get("damage", d["damage"]), "config_hash": d["config_hash"],
                "config_text": d["config_text"], "units": d["units"], "counts_per_g": d["counts_per_g"],
                "gravity_mps2": d["gravity_mps2"], "panel_id": d["panel_id"], "nvm_outcome": d["nvm_outcome"],
                "calibration": d["calibration"], "fit_summary": d["fit_summary"], "poses": d["poses"],
                "events": rec.events}

    @r.get("/yield", response_model=YieldSummary, summary="Yield and first-pass yield per station and shift")
    def yields() -> YieldOut:
        with open_store(settings) as st:
            t0 = queries.window_start(st)
            if t0 is None:
                return {"window_from": None, "stations": [], "shifts": [], "failure_reasons": {}}
            stations = queries.station_yields(queries.station_rows(st, t0))
            return {"window_from": t0, "stations": stations, "shifts": queries.shift_rows(st, t0),
                    "failure_reasons": dict(queries.reason_counts(st, t0))}


def _time(v: str | None, what: str) -> float | None:
    """Unix seconds from a number or an ISO 8601 time (TIME, checked by the route; naive: local time),
    held to the years 1970-9999 a store's times can have (an earlier bound matches every run)."""
    if v is None:
        return None
    try:
        t = float(v)  # unix seconds (the pattern's numbers); a date otherwise
    except ValueError:
        t = None
    try:
        t = timestamp(v, what) if t is None else t
    except (DataError, OverflowError, OSError, ValueError):  # a date the pattern allows that Python cannot place
        raise ApiError(400, "invalid_request", f"{what} {v[:40]!r}: allowed: unix seconds or an ISO 8601 time "
                       "from 1970 to 9999") from None
    return min(max(float(t or 0.0), 0.0), T_MAX_S)


def _cursor(text: str) -> Cursor:
    """A feed cursor (EVENT_ID, checked by the route); one past what a server sends is 400 invalid_cursor."""
    try:
        return Cursor.parse(text)
    except DataError as e:
        raise ApiError(400, "invalid_cursor", str(e)) from None


def _feed_routes(r: APIRouter, settings: WebSettings) -> None:
    @r.get("/events", response_model=EventPage, summary="Finished runs after a cursor (long poll)")
    async def events(after: str = Query("", max_length=200_000, pattern=EVENT_ID,
                                        description="an event id (cursor) as sent; empty: from the start"),
                     wait_s: float = Query(0.0, ge=0, le=25),
                     limit: int = Query(500, ge=1, le=5000)) -> EventPageOut:
        cursor = _cursor(after)
        deadline = time.monotonic() + wait_s
        while True:
            steps, runs = await asyncio.to_thread(_feed, settings, cursor, limit)
            if steps or time.monotonic() >= deadline:
                break
            await asyncio.sleep(settings.poll_s)
        by_id = {x["id"]: x for x in runs}
        out: list[EventOut] = [{"id": s.cursor.text(), "run": by_id[s.run_id]} for s in steps if s.run_id in by_id]
        return {"events": out, "next": steps[-1].cursor.text() if steps else cursor.text()}

    @r.get("/events/head", response_model=EventHead,
           summary="The cursor at the present end of the feed (skip the past)")
    def events_head() -> dict[str, str]:
        with open_store(settings) as st:
            return {"next": head(*queries.head_rows(st)).text()}

    @r.get("/events/stream", summary="Server-sent events: one `run` event per finished run",
           response_class=StreamingResponse,
           responses={200: {"content": {"text/event-stream": {}},
                            "description": "`id:` is the cursor; reconnect with Last-Event-ID to resume"}})
    async def stream(after: str = Query("", max_length=200_000, pattern=EVENT_ID),
                     last_event_id: str = Header("", max_length=200_000, pattern=EVENT_ID)) -> StreamingResponse:
        cursor = _cursor(last_event_id or after)
        return StreamingResponse(_sse(settings, cursor), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


async def _sse(settings: WebSettings, cursor: Cursor) -> AsyncIterator[str]:
    """Finished runs as SSE ``run`` events; a comment every 15 s keeps idle proxies open.
    Each poll reads a bounded page and holds nothing between polls (memory stays flat)."""
    yield "retry: 2000\n\n"
    quiet = 0.0
    while True:
        steps, runs = await asyncio.to_thread(_feed, settings, cursor, 500)
        by_id = {x["id"]: x for x in runs}
        for s in steps:
            if s.run_id in by_id:
                yield f"id: {s.cursor.text()}\nevent: run\ndata: {queries.dumps(by_id[s.run_id])}\n\n"
            cursor = s.cursor
        if steps:
            quiet = 0.0
            continue
        await asyncio.sleep(settings.poll_s)
        quiet += settings.poll_s
        if quiet >= 15.0:
            quiet = 0.0
            yield ": keep-alive\n\n"

"""The MES JSON API under /api/v1 (documented by the OpenAPI schema at /openapi.json).

Runs (list with filters, one run with its calibration and reasons), yields per station and
shift, and the feed of finished runs (feed.py): ``GET /events?after=CURSOR`` (JSON, long
poll) and ``GET /events/stream`` (server-sent events; resume with the Last-Event-ID
header).  Read-only: nothing here writes the store.  Errors are JSON ``{code, message}``.
"""
from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from typing import TYPE_CHECKING, Any

from fastapi import APIRouter, Header, Query
from fastapi.responses import StreamingResponse
from pydantic import BaseModel

from ..store.records import RunNotFound
from . import queries
from .errors import ApiError
from .feed import Cursor, Step, advance, head
from .settings import open_store

if TYPE_CHECKING:
    from .settings import WebSettings


class Reason(BaseModel):
    code: str
    message: str


class RunSummary(BaseModel):
    """A run without its poses; a damaged stored value reads as null and is named in ``damage``
    (table, id, column, problem: the store's ``damaged_row``)."""

    id: int
    started_at: float | None
    finished_at: float | None
    status: str | None
    status_reason: str | None
    device_serial: str | None
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    model: str | None
    verdict: str | None
    reasons: list[Reason]
    reason_codes: list[str]
    nvm_status: str | None
    residual_rms_mg: float | None
    measured: dict[str, float]
    damage: list[dict[str, str]] = []


class Event(BaseModel):
    """A finished run; ``id`` is the cursor to resume after it."""

    id: str
    run: RunSummary


class EventPage(BaseModel):
    events: list[Event]
    next: str


class YieldSummary(BaseModel):
    window_from: float | None
    stations: list[dict[str, Any]]
    shifts: list[dict[str, Any]]
    failure_reasons: dict[str, int]


def _rows(settings: WebSettings, sql_filters: dict[str, Any], limit: int) -> list[dict[str, Any]]:
    with open_store(settings) as st:
        ids = [r["id"] for r in st.list_runs(limit=limit, **sql_filters)]
        return queries.summaries(st, ids)


def _feed(settings: WebSettings, cursor: Cursor, limit: int) -> tuple[list[Step], list[dict[str, Any]]]:
    """The next steps of the feed after ``cursor`` and their runs (one store open, read only)."""
    with open_store(settings) as st:
        steps = advance(cursor, queries.feed_rows(st, cursor.low), time.time(), limit)
        runs = queries.summaries(st, [s.run_id for s in steps])
    return steps, runs


def api_router(settings: WebSettings) -> APIRouter:
    r = APIRouter()
    _runs_routes(r, settings)
    _feed_routes(r, settings)
    return r


def _runs_routes(r: APIRouter, settings: WebSettings) -> None:
    @r.get("/runs", response_model=list[RunSummary], summary="List runs (oldest first)")
    def list_runs(since: str | None = Query(None, description="started at or after (ISO 8601 or unix s)"),
                  until: str | None = None, station: str | None = None, serial: str | None = None,
                  verdict: str | None = Query(None, pattern="^(PASS|FAIL)$"), lot: str | None = None,
                  status: str | None = Query(None, pattern="^(running|complete|interrupted|error|stale)$"),
                  limit: int = Query(1000, ge=1, le=10000)) -> list[dict[str, Any]]:
        f = {"since": _time(since), "until": _time(until), "station": station, "device": serial,
             "verdict": verdict, "lot": lot, "status": status}
        return _rows(settings, {k: v for k, v in f.items() if v is not None}, limit)

    @r.get("/runs/{run_id}", summary="One run with its calibration, reasons, poses and events")
    def one_run(run_id: int) -> dict[str, Any]:
        with open_store(settings) as st:
            try:
                rec = st.get_run(run_id)
            except RunNotFound:  # a store that cannot be read is 503 (errors.py), not a missing run
                raise ApiError(404, "not_found", f"no run {run_id}") from None
        return rec.to_dict()

    @r.get("/yield", response_model=YieldSummary, summary="Yield and first-pass yield per station and shift")
    def yields() -> dict[str, Any]:
        with open_store(settings) as st:
            t0 = queries.window_start(st)
            if t0 is None:
                return {"window_from": None, "stations": [], "shifts": [], "failure_reasons": {}}
            stations = [{k: v for k, v in s.items() if k != "latest"} for s in queries.station_rows(st, t0)]
            return {"window_from": t0, "stations": stations, "shifts": queries.shift_rows(st, t0),
                    "failure_reasons": dict(queries.reason_counts(st, t0))}


def _time(v: str | None) -> float | str | None:
    """A number stays unix seconds; anything else the store parses as ISO 8601 (or refuses)."""
    if v is None:
        return None
    try:
        return float(v)
    except ValueError:
        return v


def _feed_routes(r: APIRouter, settings: WebSettings) -> None:
    @r.get("/events", response_model=EventPage, summary="Finished runs after a cursor (long poll)")
    async def events(after: str = Query("", max_length=200_000), wait_s: float = Query(0.0, ge=0, le=25),
                     limit: int = Query(500, ge=1, le=5000)) -> dict[str, Any]:
        cursor = Cursor.parse(after)
        deadline = time.monotonic() + wait_s
        while True:
            steps, runs = await asyncio.to_thread(_feed, settings, cursor, limit)
            if steps or time.monotonic() >= deadline:
                break
            await asyncio.sleep(settings.poll_s)
        by_id = {x["id"]: x for x in runs}
        out = [{"id": s.cursor.text(), "run": by_id[s.run_id]} for s in steps if s.run_id in by_id]
        return {"events": out, "next": steps[-1].cursor.text() if steps else cursor.text()}

    @r.get("/events/head", summary="The cursor at the present end of the feed (skip the past)")
    def events_head() -> dict[str, str]:
        with open_store(settings) as st:
            return {"next": head(*queries.head_rows(st)).text()}

    @r.get("/events/stream", summary="Server-sent events: one `run` event per finished run",
           response_class=StreamingResponse,
           responses={200: {"content": {"text/event-stream": {}},
                            "description": "`id:` is the cursor; reconnect with Last-Event-ID to resume"}})
    async def stream(after: str = Query("", max_length=200_000),
                     last_event_id: str | None = Header(None, max_length=200_000)) -> StreamingResponse:
        cursor = Cursor.parse(last_event_id or after)
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

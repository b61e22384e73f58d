"""The `accelcal serve` application: the line, board and lot pages and the MES API (api.py).

Every page is rendered by Jinja2 with autoescape on, so a serial, operator or reason from
the store shows as text; scripts and styles come from this package (assets.py) by name,
never from a path in the request.  Each request opens the store for itself (one Store per
thread, as the store wants) and reads it; stations write it independently, so a slow or
broken client holds no lock and no station waits on it.

Bounded work: the lot, board and reason pages (the ones whose work grows with a lot or a
board's history) take turns in ``settings.heavy_lanes`` lanes; a request waiting for a lane
waits on the event loop, holding no worker thread, so the line page and the API are
answered meanwhile.  Once the application has started (its lifespan), each lane is a worker
process (lanes.py), so their Python does not share the line page's interpreter.

With ``settings.read_token`` every request must carry it (``Authorization: Bearer TOKEN``; a
browser may send it as the password of HTTP Basic).
"""
from __future__ import annotations

import base64
import hmac
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import AbstractAsyncContextManager, asynccontextmanager

from fastapi import FastAPI, Query, Request
from fastapi.responses import HTMLResponse, Response

from . import assets, linepage, pages
from .api import api_router
from .errors import error_response, install_errors
from .lanes import HeavyLanes
from .paging import PAGE_PARAM, PAGE_SIZE, PAGE_SIZE_MAX
from .settings import WebSettings, open_store

API_VERSION = "v1"


def create_app(settings: WebSettings) -> FastAPI:
    """The whole application over one store."""
    lanes = HeavyLanes(settings.heavy_lanes)
    app = FastAPI(title="accelcal station line", version=API_VERSION, lifespan=_lifespan(lanes),
                  description="Runs (paged by cursor), yields and a finished-runs event stream from the results "
                              "store. Every error is JSON {code, message}.",
                  openapi_url="/openapi.json", docs_url=None, redoc_url=None)
    app.state.settings = settings
    install_errors(app)
    if settings.read_token:
        _require_token(app, settings.read_token)
    app.include_router(api_router(settings), prefix=f"/api/{API_VERSION}")
    app.include_router(assets.router)
    _pages(app, settings, lanes)
    return app


def _lifespan(lanes: HeavyLanes) -> Callable[[FastAPI], AbstractAsyncContextManager[None]]:
    """The heavy pages' worker processes live as long as the server: started with it, stopped with it."""
    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        lanes.start()
        try:
            yield
        finally:
            lanes.close()
    return lifespan


def token_of(header: str) -> str:
    """The token an Authorization header carries: Bearer TOKEN, or Basic with TOKEN as the password."""
    kind, _, value = header.strip().partition(" ")
    if kind.lower() == "bearer":
        return value.strip()
    if kind.lower() == "basic":
        try:
            return base64.b64decode(value.strip(), validate=True).decode("utf-8").partition(":")[2]
        except (ValueError, UnicodeDecodeError):
            return ""
    return ""


def _require_token(app: FastAPI, token: str) -> None:
    want = token.encode()

    @app.middleware("http")
    async def read_token(request: Request, call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        got = token_of(request.headers.get("authorization", "")).encode()
        if hmac.compare_digest(got, want):
            return await call_next(request)
        return error_response(401, "unauthorized", "this server needs its read token: Authorization: Bearer TOKEN "
                              "(web.read_token of its config)",
                              headers={"WWW-Authenticate": 'Basic realm="accelcal (password: the read token)"'})


def _pages(app: FastAPI, settings: WebSettings, lanes: HeavyLanes) -> None:
    render = assets.render

    def line(day: str, shift: str) -> linepage.LineContext:
        with open_store(settings) as st:
            return linepage.line_context(st, day, shift)

    day_q = Query("", max_length=10, pattern=r"^(\d{4}-\d{2}-\d{2})?$", description="production day YYYY-MM-DD")
    shift_q = Query("", pattern="^[ABC]?$", description="shift A, B or C of that day")
    cursor_q = Query("", max_length=21, pattern=PAGE_PARAM, description="a page of runs: an API cursor or 'oldest'")
    per_q = Query(PAGE_SIZE, ge=1, le=PAGE_SIZE_MAX, description="runs per page")

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def line_page(day: str = day_q, shift: str = shift_q) -> Response:
        return render("line.html", title="Line", page="line", **line(day, shift))

    @app.get("/fragment/line", response_class=HTMLResponse, include_in_schema=False)
    def line_fragment(day: str = day_q, shift: str = shift_q) -> Response:
        return render("line_body.html", **line(day, shift))

    @app.get("/station", response_class=HTMLResponse, include_in_schema=False)
    def station_page(station: str = Query("", max_length=200), day: str = day_q, shift: str = shift_q) -> Response:
        with open_store(settings) as st:
            ctx = linepage.station_context(st, station or None, day, shift)
        return render("station.html", title=f"Station {station}", page="line", **ctx)

    @app.get("/reason", response_class=HTMLResponse, include_in_schema=False)
    async def reason_page(code: str = Query(..., max_length=64), day: str = day_q, shift: str = shift_q,
                          station: str | None = Query(None, max_length=200), cursor: str = cursor_q,
                          per: int = per_q) -> Response:
        ctx = await lanes.run(pages.reason_page, settings, code, day, shift, station, cursor, per)
        return render("reason.html", title=f"Reason {code}", page="line", **ctx)

    @app.get("/board", response_class=HTMLResponse, include_in_schema=False)
    async def board_page(serial: str = Query("", max_length=64)) -> Response:
        ctx: pages.BoardContext = (await lanes.run(pages.board_page, settings, serial) if serial
                                   else {"serial": serial, "runs": [], "nvm": [], "similar": []})
        return render("board.html", title=f"Board {serial}" if serial else "Board", page="board", **ctx)

    @app.get("/lot", response_class=HTMLResponse, include_in_schema=False)
    async def lot_page(lot: str = Query("", max_length=64), cursor: str = cursor_q, per: int = per_q) -> Response:
        ctx = await lanes.run(pages.lot_page, settings, lot, cursor, per)
        return render("lot.html", title=f"Lot {lot}" if lot else "Lots", page="lot", **ctx)

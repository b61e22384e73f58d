"""The `accelcal serve` application: the line, board and lot pages and the MES API (api.py).

Every page is rendered by Jinja2 with autoescape on, so a serial, operator or reason from
the store shows as text; scripts and styles come from this package (assets.py) by name,
never from a path in the request.  Each request opens the store for itself (one Store per
thread, as the store wants) and reads it; stations write it independently, so a slow or
broken client holds no lock and no station waits on it.
"""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from fastapi import FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, Response
from starlette.exceptions import HTTPException

from ..errors import AccelcalError
from ..store.runs import Store
from . import assets, pages
from .api import api_router

API_VERSION = "v1"


@dataclass
class WebSettings:
    """What a server reads: the store, the acceptance limits to draw, the token for writes."""

    store: str
    limits: dict[str, float] = field(default_factory=dict)
    token: str | None = None
    poll_s: float = 0.5  # how often the events stream looks for finished runs


class ApiError(Exception):
    """An error the API answers as JSON {code, message}."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status, self.code, self.message = status, code, message


@contextmanager
def open_store(settings: WebSettings) -> Iterator[Store]:
    """The store for one request, read-only (never created by a reader)."""
    with Store(settings.store, create=False) as st:
        yield st


def _error(status: int, code: str, message: str) -> JSONResponse:
    return JSONResponse({"code": code, "message": message}, status_code=status)


def _install_errors(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def api_error(_r: Request, e: ApiError) -> JSONResponse:
        return _error(e.status, e.code, e.message)

    @app.exception_handler(AccelcalError)
    async def accelcal_error(_r: Request, e: AccelcalError) -> JSONResponse:
        return _error(400 if e.exit_code == 2 else 503, type(e).__name__, str(e))

    @app.exception_handler(RequestValidationError)
    async def bad_request(_r: Request, e: RequestValidationError) -> JSONResponse:
        first = e.errors()[0] if e.errors() else {}
        where = ".".join(str(x) for x in first.get("loc", ()))
        return _error(422, "invalid_request", f"{where}: {first.get('msg', 'invalid')}")

    @app.exception_handler(HTTPException)
    async def http_error(_r: Request, e: HTTPException) -> JSONResponse:
        return _error(e.status_code, "not_found" if e.status_code == 404 else "http_error", str(e.detail))


def create_app(settings: WebSettings) -> FastAPI:
    """The whole application over one store."""
    app = FastAPI(title="accelcal station line", version=API_VERSION,
                  description="Runs, yields and a finished-runs event stream from the results store.",
                  openapi_url="/openapi.json", docs_url=None, redoc_url=None)
    app.state.settings = settings
    _install_errors(app)
    app.include_router(api_router(settings), prefix=f"/api/{API_VERSION}")
    app.include_router(assets.router)
    _pages(app, settings)
    return app


def _pages(app: FastAPI, settings: WebSettings) -> None:
    render = assets.render

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def line_page() -> Response:
        with open_store(settings) as st:
            ctx = pages.line_context(st, settings.limits)
        return render("line.html", title="Line", page="line", **ctx)

    @app.get("/fragment/line", response_class=HTMLResponse, include_in_schema=False)
    def line_fragment() -> Response:
        with open_store(settings) as st:
            ctx = pages.line_context(st, settings.limits)
        return render("line_body.html", **ctx)

    @app.get("/board", response_class=HTMLResponse, include_in_schema=False)
    def board_page(serial: str = Query("", max_length=64)) -> Response:
        ctx: dict[str, Any] = {"serial": serial, "runs": [], "nvm": [], "similar": []}
        if serial:
            with open_store(settings) as st:
                ctx = pages.board_context(st, serial)
        return render("board.html", title=f"Board {serial}" if serial else "Board", page="board", **ctx)

    @app.get("/lot", response_class=HTMLResponse, include_in_schema=False)
    def lot_page(lot: str = Query("", max_length=64)) -> Response:
        with open_store(settings) as st:
            ctx = pages.lot_context(st, lot) if lot else {"lot": "", "summary": None, "charts": [],
                                                           "lots": pages.queries.lots(st)}
        return render("lot.html", title=f"Lot {lot}" if lot else "Lots", page="lot", **ctx)

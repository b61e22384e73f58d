"""The `accelcal serve` application: the line, board and lot pages and the MES API (api.py).

Every page is rendered by Jinja2 with autoescape on, so a serial, operator or reason from
the store shows as text; scripts and styles come from this package (assets.py) by name,
never from a path in the request.  Each request opens the store for itself (one Store per
thread, as the store wants) and reads it; stations write it independently, so a slow or
broken client holds no lock and no station waits on it.
"""
from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Query
from fastapi.responses import HTMLResponse, Response

from . import assets, pages
from .api import api_router
from .errors import install_errors
from .settings import WebSettings, open_store

API_VERSION = "v1"


def create_app(settings: WebSettings) -> FastAPI:
    """The whole application over one store."""
    app = FastAPI(title="accelcal station line", version=API_VERSION,
                  description="Runs, yields and a finished-runs event stream from the results store.",
                  openapi_url="/openapi.json", docs_url=None, redoc_url=None)
    app.state.settings = settings
    install_errors(app)
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

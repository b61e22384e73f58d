"""The web layer's errors: every one answered as JSON ``{code, message}`` (``ErrorBody``), and
declared so in the OpenAPI schema of every endpoint (``ERROR_RESPONSES``).

A store the server cannot read (a table dropped, a column renamed, a damaged page, a schema
to migrate) is ``503 store_unreadable`` naming the damage: JSON under /api, one short HTML
page elsewhere; never a 500 with a traceback.  A heavy page's worker process that stopped
(lanes.py) is ``503 worker_lost`` the same way.
"""
from __future__ import annotations

import html
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, Response
from pydantic import BaseModel
from sqlalchemy.exc import SQLAlchemyError
from starlette.exceptions import HTTPException

from ..errors import AccelcalError
from ..store.records import StoreError


class ErrorBody(BaseModel):
    """Every error the server answers: a stable ``code`` and one line saying what and what is allowed."""

    code: str
    message: str


_WHAT = {400: "a parameter's value is refused (a date, a cursor, a filter)",
         401: "the server needs its read token: Authorization: Bearer TOKEN",
         404: "no such run or path", 422: "a parameter out of its type or range",
         503: "the results store cannot be read now"}
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {k: {"model": ErrorBody, "description": v} for k, v in _WHAT.items()}


class ApiError(Exception):
    """An error the API answers as JSON {code, message}."""

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status, self.code, self.message = status, code, message


def error_response(status: int, code: str, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"code": code, "message": message}, status_code=status, headers=headers)


def _driver_line(e: BaseException) -> str:
    """The database driver's own first line (SQLAlchemy wraps it with the statement)."""
    orig = getattr(e, "orig", None)
    return (str(orig if orig is not None else e).strip().splitlines() or [type(e).__name__])[0]


class WorkerLost(Exception):
    """The worker process computing a heavy page stopped (killed, out of memory); a new one replaces it."""


def unavailable(request: Request, code: str, title: str, heading: str, message: str) -> Response:
    """503: JSON {code, message} for the API, a one-paragraph page for a browser."""
    if request.url.path.startswith("/api/") or "text/html" not in request.headers.get("accept", "text/html"):
        return error_response(503, code, message)
    body = (f"<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>"
            f"</head><body><h1>{heading}</h1><p>{html.escape(message)}</p></body></html>")
    return HTMLResponse(body, status_code=503)


def store_unreadable(request: Request, message: str) -> Response:
    """503 naming why the store cannot be read: JSON for the API, a one-paragraph page for a browser."""
    return unavailable(request, "store_unreadable", "Store unreadable", "The results store cannot be read", message)


def install_errors(app: FastAPI) -> None:
    @app.exception_handler(StoreError)
    async def store_error(r: Request, e: StoreError) -> Response:
        return store_unreadable(r, str(e))

    @app.exception_handler(SQLAlchemyError)
    async def store_damaged(r: Request, e: SQLAlchemyError) -> Response:
        store = getattr(r.app.state, "settings", None)
        where = f"{store.store}: " if store is not None else ""
        return store_unreadable(r, f"{where}cannot read the results store ({_driver_line(e)}); "
                                   "`accelcal report check` names the damage")

    @app.exception_handler(WorkerLost)
    async def worker_lost(r: Request, e: WorkerLost) -> Response:
        return unavailable(r, "worker_lost", "Page interrupted", "This page's worker process stopped", str(e))

    @app.exception_handler(ApiError)
    async def api_error(_r: Request, e: ApiError) -> JSONResponse:
        return error_response(e.status, e.code, e.message)

    @app.exception_handler(AccelcalError)
    async def accelcal_error(_r: Request, e: AccelcalError) -> JSONResponse:
        return error_response(400 if e.exit_code == 2 else 503, type(e).__name__, str(e))

    @app.exception_handler(RequestValidationError)
    async def bad_request(_r: Request, e: RequestValidationError) -> JSONResponse:
        first = e.errors()[0] if e.errors() else {}
        where = ".".join(str(x) for x in first.get("loc", ()))
        return error_response(422, "invalid_request", f"{where}: {first.get('msg', 'invalid')}"[:300])

    @app.exception_handler(HTTPException)
    async def http_error(_r: Request, e: HTTPException) -> JSONResponse:
        # a 405 keeps Starlette's Allow header (RFC 9110: the methods the resource has)
        return error_response(e.status_code, "not_found" if e.status_code == 404 else "http_error", str(e.detail),
                              headers=dict(e.headers) if e.headers else None)

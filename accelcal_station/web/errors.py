"""The web layer's errors: every one answered as JSON ``{code, message}`` (``ErrorBody``), and
declared so in the OpenAPI schema of every endpoint (``ERROR_RESPONSES``)."""
from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException

from ..errors import AccelcalError


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


def install_errors(app: FastAPI) -> None:
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
        return error_response(e.status_code, "not_found" if e.status_code == 404 else "http_error", str(e.detail))

"""The operator page's application (served by `accelcal run --ui web` beside the station).

``GET /`` the page; ``GET /operator/state`` what to show now; ``POST /operator/answer``
the operator's button or key (JSON only, so another site's form cannot press it);
``POST /api/v1/station/abort`` aborts the run for the MES, with the config's web.token
as a bearer token (refused without one: the API is read-only by default).

With a page token (web.operator_token, else web.read_token: required to listen beyond localhost),
every request of the page needs it: ``GET /?token=TOKEN`` (the link the station prints) sets it as
an HttpOnly, SameSite=Strict cookie and redirects to ``/``; a client may send it as
``Authorization: Bearer TOKEN`` instead.  Without it: 401 (docs/security.md, "The operator page").
"""
from __future__ import annotations

import hmac
from typing import Annotated, Literal

from fastapi import Depends, FastAPI, Header, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from pydantic import BaseModel, Field, WithJsonSchema

from . import assets
from .errors import ApiError, install_errors
from .operator import WebOperator
from .operator_text import page_texts_json

# {"ok": true}; documented as an open object, as the OpenAPI has always had it
Done = Annotated[dict[str, bool], WithJsonSchema({"additionalProperties": True, "type": "object"})]


class AnswerIn(BaseModel):
    answer: Literal["accept", "replace", "skip", "abort", "serial", "end"]
    serial: str | None = Field(None, max_length=200)


def _json_only(request: Request) -> None:
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        raise ApiError(415, "unsupported_media_type", "send the answer as application/json")


PAGE_COOKIE = "accelcal_operator"


def _given(request: Request) -> str:
    """The page token a request carries: its cookie, else its bearer token."""
    cookie = request.cookies.get(PAGE_COOKIE)
    return cookie if cookie else request.headers.get("authorization", "").removeprefix("Bearer ").strip()


def _same(given: str, token: str) -> bool:
    return hmac.compare_digest(given.encode(), token.encode())


def _refused_page() -> HTMLResponse:
    return HTMLResponse("<!doctype html><meta charset=utf-8><title>accelcal operator</title><p>This operator page "
                        "needs its token: open the link the station printed when it started "
                        "(<code>http://HOST:PORT/?token=...</code>).", status_code=401,
                        headers=assets.SECURITY_HEADERS)


def create_operator_app(ui: WebOperator, token: str | None, page_token: str | None = None) -> FastAPI:
    """The page's app; ``token``: web.token (the MES abort), ``page_token``: what every request of the
    page needs (module docstring), None on loopback without one."""

    def require_page_token(request: Request) -> None:
        if page_token is not None and not _same(_given(request), page_token):
            raise ApiError(401, "unauthorized", "this operator page needs its token: open the link the station "
                                                "printed, or send Authorization: Bearer <web.operator_token>")

    app = FastAPI(title="accelcal operator station", version="v1", openapi_url="/openapi.json",
                  docs_url=None, redoc_url=None)
    install_errors(app)
    app.include_router(assets.router)

    @app.get("/", response_class=HTMLResponse, include_in_schema=False, response_model=None)
    def page(request: Request, token: str | None = None) -> Response:
        if page_token is not None and token is not None and _same(token, page_token):
            done = RedirectResponse("/", status_code=303)  # the token leaves the address bar and history
            done.set_cookie(PAGE_COOKIE, page_token, httponly=True, samesite="strict")
            return done
        if page_token is not None and not _same(_given(request), page_token):
            return _refused_page()
        return assets.render("operator.html", title=f"{ui.tr('Operator')} · {ui.state['station']}", page="operator",
                             station=ui.state["station"], _=ui.tr, texts_json=page_texts_json(ui.tr),
                             lang=ui.language)

    page_only = [Depends(require_page_token)]  # checked before the body is read

    @app.get("/operator/state", summary="What the operator page shows now", dependencies=page_only)
    def state() -> JSONResponse:
        return JSONResponse(ui.snapshot(), headers={"Cache-Control": "no-store"})

    @app.post("/operator/answer", summary="The operator's answer at the current question", dependencies=page_only)
    def answer(body: AnswerIn, request: Request) -> Done:
        _json_only(request)
        if not ui.answer(body.answer, body.serial):
            raise ApiError(409, "not_asked", f"{body.answer}: nothing is being asked that this answers now")
        return {"ok": True}

    @app.post("/api/v1/station/abort", summary="Abort the run at its current question (needs web.token)")
    def abort(authorization: str | None = Header(None)) -> Done:
        if token is None:
            raise ApiError(403, "read_only", "this station has no web.token in its config: the API is read-only")
        given = (authorization or "").removeprefix("Bearer ").strip()
        if not hmac.compare_digest(given.encode(), token.encode()):
            raise ApiError(401, "unauthorized", "Authorization: Bearer <web.token> required")
        if not ui.answer("abort"):
            raise ApiError(409, "not_asked", "the station is not waiting for the operator; abort at the next question")
        return {"ok": True}

    return app

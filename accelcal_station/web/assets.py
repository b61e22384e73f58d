"""The package's own templates, scripts and styles: read once from the package, served by
name from a fixed table (a request names an asset; no request path reaches the file system)."""
from __future__ import annotations

from datetime import UTC, datetime
from functools import cache
from importlib import resources
from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import HTMLResponse, Response
from jinja2 import DictLoader, Environment, select_autoescape

TYPES = {".css": "text/css; charset=utf-8", ".js": "text/javascript; charset=utf-8"}
SECURITY_HEADERS = {"Content-Security-Policy": "default-src 'self'; img-src 'self' data:; style-src 'self'; "
                                               "script-src 'self'; frame-ancestors 'none'",
                    "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer"}


@cache
def _files(folder: str) -> dict[str, str]:
    root = resources.files(__package__) / folder
    return {f.name: f.read_text(encoding="utf-8") for f in root.iterdir() if f.is_file()}


@cache
def environment() -> Environment:
    env = Environment(loader=DictLoader(_files("templates")), autoescape=select_autoescape(default=True),
                      trim_blocks=True, lstrip_blocks=True)
    env.filters["pct"] = lambda v: "–" if v is None else f"{100 * v:.1f} %"
    env.filters["num"] = lambda v, f=".3g": "–" if not isinstance(v, (int, float)) else format(v, f)
    env.filters["utc"] = lambda t: "–" if not isinstance(t, (int, float)) else \
        datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S")
    return env


def render(name: str, **ctx: Any) -> HTMLResponse:
    html = environment().get_template(name).render(**ctx)
    return HTMLResponse(html, headers=SECURITY_HEADERS)


router = APIRouter(include_in_schema=False)


@router.get("/static/{name}")
def static(name: str) -> Response:
    files = _files("static")
    if name not in files:
        raise HTTPException(404, f"no asset {name[:40]!r}")
    kind = TYPES.get(name[name.rfind("."):], "text/plain; charset=utf-8")
    return Response(files[name], media_type=kind.split(";")[0],
                    headers={"Cache-Control": "max-age=300", "Content-Type": kind, **SECURITY_HEADERS})

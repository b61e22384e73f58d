"""`accelcal serve`: the line page, board and lot pages and the MES API over a results store.

Listening beyond this machine is a decision, not a default: an address other than loopback
needs a read token (``web.read_token`` in a --config; every request then sends it as
``Authorization: Bearer TOKEN``) or ``--public``, and the start line says which.
"""
from __future__ import annotations

import ipaddress

import click

from ..errors import ConfigError
from ..station.settings import StationConfig
from ..store.location import store_target
from ._common import Whole


def require_web() -> None:
    """The web extra must be installed; one line saying how when it is not."""
    try:
        import fastapi  # noqa: F401
        import jinja2  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as e:
        raise ConfigError(f"the web front end needs the web extra ({e.name} is missing): "
                          "pip install 'accelcal-station[web]'") from None


def is_loopback(host: str) -> bool:
    """Does ``host`` listen on this machine only (127.0.0.0/8, ::1, localhost)?"""
    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name: it may resolve to any interface
        return False


def exposure(host: str, read_token: str | None, public: bool) -> str:
    """What the start line says about who can read; ConfigError when a non-loopback address has neither
    a read token nor --public."""
    if read_token:
        return "every request needs web.read_token (Authorization: Bearer TOKEN)"
    if is_loopback(host):
        return "this machine only"
    if not public:
        raise ConfigError(f"--host {host}: listening beyond this machine serves every run, operator and config "
                          "to the network; set web.read_token in a --config, or pass --public to mean it")
    return "PUBLIC: anyone who can reach this address reads every run, operator name and config (--public)"


def operator_exposure(host: str, page_token: str | None, public: bool) -> str:
    """Who can answer the operator page (`run --ui web`); ConfigError when a non-loopback address has
    neither a page token (web.operator_token or web.read_token) nor --public."""
    if page_token:
        return "every request needs the page token (open the link above)"
    if is_loopback(host):
        return "this machine only"
    if not public:
        raise ConfigError(f"--ui-host {host}: the operator page answers the run's questions (abort, skip, "
                          "serials) for anyone who reaches it; set web.operator_token in the --config, or pass "
                          "--public to mean it")
    return "PUBLIC: anyone who can reach this address can answer, skip or abort the run (--public)"


@click.command("serve")
@click.option("--db", "db", default=None, metavar="FILE|URL",
              help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB "
                   "(default: the store of the first --config).")
@click.option("--config", "configs", multiple=True, type=click.Path(dir_okay=False),
              help="A station config (repeatable): its store, acceptance limits, web.token and web.read_token.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on; anything but localhost needs web.read_token or --public.")
@click.option("--port", default=8750, show_default=True, type=Whole(1, 65535))
@click.option("--public", is_flag=True, help="Serve reads to anyone who can reach --host, without a read token.")
def command(db: str | None, configs: tuple[str, ...], host: str, port: int, public: bool) -> None:
    """Serve the line page (/), board and lot pages and the JSON API (/api/v1, schema at /openapi.json).

    Read-only: it reads the store the stations write and never writes it.
    """
    cfgs = [StationConfig.load(c) for c in configs]
    if db is None and not cfgs:
        raise ConfigError("--db or --config: name the results store to serve")
    store = store_target(db) if db is not None else cfgs[0].store_file
    limits = dict(cfgs[0].limits.values) if cfgs else {}
    token = next((c.web_token for c in cfgs if c.web_token), None)
    read_token = next((c.web_read_token for c in cfgs if c.web_read_token), None)
    who = exposure(host, read_token, public)
    require_web()
    from ..web.app import create_app
    from ..web.server import serve_forever
    from ..web.settings import WebSettings, open_store

    settings = WebSettings(str(store), limits, token, read_token=read_token)
    with open_store(settings):  # a wrong path or an unreachable server is one line now, not a page error later
        pass
    app = create_app(settings)
    click.echo(f"serving {store} on http://{host}:{port}/ ({who}; Ctrl-C stops)", err=True)
    serve_forever(app, host, port)

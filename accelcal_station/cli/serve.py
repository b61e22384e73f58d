"""`accelcal serve`: the line page, board and lot pages and the MES API over a results store."""
from __future__ import annotations

import click

from ..errors import ConfigError
from ..station.settings import StationConfig
from ..store.location import store_target


def require_web() -> None:
    """The web extra must be installed; one line saying how when it is not."""
    try:
        import fastapi  # noqa: F401
        import jinja2  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as e:
        raise ConfigError(f"the web front end needs the web extra ({e.name} is missing): "
                          "pip install 'accelcal-station[web]'") from None


@click.command("serve")
@click.option("--db", "db", default=None, metavar="FILE|URL",
              help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB "
                   "(default: the store of the first --config).")
@click.option("--config", "configs", multiple=True, type=click.Path(dir_okay=False),
              help="A station config (repeatable): its store, acceptance limits and web.token.")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on (localhost only unless told otherwise).")
@click.option("--port", default=8750, show_default=True, type=click.IntRange(1, 65535))
def command(db: str | None, configs: tuple[str, ...], host: str, port: int) -> None:
    """Serve the line page (/), board and lot pages and the JSON API (/api/v1, schema at /openapi.json).

    Read-only: it reads the store the stations write and never writes it.
    """
    cfgs = [StationConfig.load(c) for c in configs]
    if db is None and not cfgs:
        raise ConfigError("--db or --config: name the results store to serve")
    store = store_target(db) if db is not None else cfgs[0].store_file
    limits = dict(cfgs[0].limits.values) if cfgs else {}
    token = next((c.web_token for c in cfgs if c.web_token), None)
    require_web()
    from ..web.app import create_app
    from ..web.server import serve_forever
    from ..web.settings import WebSettings, open_store

    settings = WebSettings(str(store), limits, token)
    with open_store(settings):  # a wrong path or an unreachable server is one line now, not a page error later
        pass
    app = create_app(settings)
    click.echo(f"serving {store} on http://{host}:{port}/ (Ctrl-C stops)", err=True)
    serve_forever(app, host, port)

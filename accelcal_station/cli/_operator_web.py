"""`accelcal run --ui web`: the station runs here as always; its operator front end is a page
served on localhost beside it (web/operator.py).  The run's exit status is the terminal's."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import click

from ..fixtures.designs import get_design
from ..station.report import RunReport
from ..station.settings import StationConfig
from .serve import require_web

if TYPE_CHECKING:
    from ..web.operator import WebOperator

LINGER_S = 30.0  # after the run, wait this long at most for the page to show the verdict


def finish_reports(ui: WebOperator, reports: list[RunReport]) -> None:
    """The verdict screen of a finished run (one board, or a panel: PASS only if every board passed)."""
    passed = all(r.verdict == "PASS" for r in reports)
    many = len(reports) > 1
    reasons = [{"code": x.code, "message": (f"board {r.serial}: " if many else "") + str(x)}
               for r in reports for x in r.reasons]
    figures: dict[str, Any] = {}
    if not many and reports:
        r = reports[0]
        if r.fit is not None:
            figures["residual_rms_mg"] = r.fit.residual_rms_g * 1e3
        figures["verify_error_max_mg"] = r.verify_error_max_mg
        if r.nvm:
            figures["nvm"] = f"slot {r.nvm.get('slot')}, generation {r.nvm.get('generation')}" + (
                ", verified" if r.nvm_verified else "")
    serial = reports[0].serial if not many and reports else f"panel of {len(reports)}"
    ui.finish("PASS" if passed else "FAIL", serial, reports[0].run_id if not many and reports else None,
              reasons, figures)


@contextmanager
def web_operator(cfg: StationConfig, echo: Callable[[str], None], host: str, port: int) -> Iterator[WebOperator]:
    """Serve the operator page for the length of one run (and until the page has shown its end)."""
    require_web()
    from ..web.operator import WebOperator
    from ..web.operator_app import create_operator_app
    from ..web.server import BackgroundServer

    total = len(get_design(cfg.design)) + cfg.verify_poses
    ui = WebOperator(echo, cfg.station_id, total)
    server = BackgroundServer(create_operator_app(ui, cfg.web_token), host, port)
    try:
        server.start()
    except OSError as e:
        from ..errors import ConfigError
        raise ConfigError(f"--ui-port {port}: {e}") from None
    click.echo(f"operator page: http://{host}:{port}/ (open it in a browser)", err=True)
    try:
        yield ui
    except BaseException as e:
        if ui.state["phase"] != "done":  # an abort or error: the page says so (a FAIL exit is already shown)
            ui.fail(e)
        ui.final_seen.wait(LINGER_S)
        raise
    else:
        ui.final_seen.wait(LINGER_S)
    finally:
        server.stop()

"""`accelcal run --ui web`: the station runs here as always; its operator front end is a page
served on localhost beside it (web/operator.py).  The run's exit status is the terminal's."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING
from urllib.parse import quote

import click

from ..fixtures.designs import get_design
from ..i18n import language_of, translator
from ..station.report import RunReport
from ..station.settings import StationConfig
from ..station.shift import BoardOutcome
from ..station.verification import verification_poses
from .serve import operator_exposure, require_web

if TYPE_CHECKING:
    from ..web.operator import WebOperator

LINGER_S = 30.0  # after the run, wait this long at most for the page to show the verdict
SEEN_GRACE_S = 3.0  # once one page showed it, this long more for the other screens (polling at 1 s in background)


def finish_reports(ui: WebOperator, reports: list[RunReport]) -> None:
    """The verdict screen of a finished run (one board, or a panel: PASS only if every board passed)."""
    passed = all(r.verdict == "PASS" for r in reports)
    many = len(reports) > 1
    reasons = [{"code": x.code, "message": (f"board {r.serial}: " if many else "") + str(x)}
               for r in reports for x in r.reasons]
    figures: dict[str, float | str | None] = {}  # the verdict screen's figures (mg; NVM slot)
    if not many and reports:
        r = reports[0]
        if r.fit is not None:
            figures["residual_rms_mg"] = r.fit.residual_rms_g * 1e3
        figures["verify_error_max_mg"] = r.verify_error_max_mg
        if r.nvm:  # in the operator's language (the page's catalog)
            figures["nvm"] = ui.tr("slot {slot}, generation {generation}").format(
                slot=r.nvm.get("slot"), generation=r.nvm.get("generation")) + (
                ui.tr(", verified") if r.nvm_verified else "")
    serial = reports[0].serial if not many and reports else ui.tr("panel of {n}").format(n=len(reports))
    ui.finish("PASS" if passed else "FAIL", serial, reports[0].run_id if not many and reports else None,
              reasons, figures)


def finish_outcome(ui: WebOperator, b: BoardOutcome, rep: RunReport | None) -> None:
    """A shift's board on every page: its verdict (or ABORTED / ERROR), until the next board starts."""
    if rep is not None:
        finish_reports(ui, [rep])
        return
    reasons = [{"code": c, "message": m} for c, m in zip(b.reason_codes, b.messages, strict=True)]
    ui.finish(b.verdict, b.serial, b.run_id, reasons, {})


def _linger(ui: WebOperator) -> None:
    """Serve the end until a page has shown it, and a moment more for every other screen."""
    if ui.final_seen.wait(LINGER_S):
        time.sleep(SEEN_GRACE_S)


def _url_host(host: str) -> str:
    """An IPv6 address in brackets, as a URL needs it."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


@contextmanager
def web_operator(cfg: StationConfig, echo: Callable[[str], None], host: str, port: int,
                 shift: bool = False, public: bool = False) -> Iterator[WebOperator]:
    """Serve the operator page for the length of one run or a whole shift (and until a page has
    shown its end); beyond loopback only with a page token or ``public`` (serve.operator_exposure)."""
    page_token = cfg.operator_page_token
    who = operator_exposure(host, page_token, public)
    require_web()
    from ..web.operator import WebOperator
    from ..web.operator_app import create_operator_app
    from ..web.server import BackgroundServer

    design = get_design(cfg.design)
    # as BoardSteps.verify_captures (station/verification.py)
    verify = verification_poses(cfg.verify_poses, cfg.schema.verify, cfg.design, design).poses
    plan = [(p, False) for p in design] + [(p, True) for p in verify]
    language = language_of(cfg.schema.station)
    ui = WebOperator(echo, cfg.station_id, len(plan), shift=shift, plan=plan, tr=translator(language),
                     language=language)
    server = BackgroundServer(create_operator_app(ui, cfg.web_token, page_token), host, port)
    try:
        server.start()
    except OSError as e:
        from ..errors import ConfigError
        raise ConfigError(f"--ui-port {port}: {e}") from None
    link = f"http://{_url_host(host)}:{port}/" + ("" if page_token is None else f"?token={quote(page_token)}")
    click.echo(f"operator page: {link} (open it in a browser; {who})", err=True)
    try:
        yield ui
    except BaseException as e:
        if ui.state["phase"] not in ("done", "shift_over"):  # an abort or error: the page says so
            ui.fail(e)
        _linger(ui)
        raise
    else:
        _linger(ui)
    finally:
        server.stop()

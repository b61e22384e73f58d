"""`accelcal run`: calibrate one board end to end."""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import click

from ..config import event_log
from ..config.schema import SimulatedDevice
from ..fileguard.identity import refuse_overwrite
from ..fixtures.operator_ui import OperatorUI
from ..i18n import Translate, language_of, reason_title, translator
from ..station.identity import ask_run_identity, check_run_labels
from ..station.report import RunReport, Timing
from ..station.settings import StationConfig
from ..station.shift import (
    DEVICE_WAIT_S,
    SERIAL_PROMPT,
    SERIAL_PROMPT_PAGE,
    BoardOutcome,
    OnBoard,
    ShiftFrontEnd,
    ShiftSummary,
    board_station,
    check_shift_config,
    run_shift,
    summary_lines,
)
from ._common import Finite, Whole, jsonable
from ._common import store_file as store_file_of
from ._outputs import refuse_output
from .operator_terminal import TerminalOperator


@click.command("run")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Station config YAML (default: the simulated station, configs/sim.yaml).")
@click.option("--serial", default=None, help="Board serial number (default: the device's own).")
@click.option("--operator", default=None, help="Operator name, recorded with the run.")
@click.option("--lot", default=None, help="Production lot, recorded with the run.")
@click.option("--store", "store_file", type=click.Path(dir_okay=False), default=None,
              help="Results store: a file, sqlite:///FILE or postgresql://USER@HOST/DB "
                   "(default: the config's store.path).")
@click.option("--port", default=None, help="Override the device's serial port (or the MMA8451's I2C bus).")
@click.option("--jig-port", default=None, help="Override the motorized jig's serial port.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object (human lines go to stderr).")
@click.option("--ui", "ui_kind", type=click.Choice(["terminal", "web"]), default="terminal", show_default=True,
              help="The operator's front end: prompts here, or a page in a browser (needs the web extra).")
@click.option("--ui-host", default="127.0.0.1", show_default=True, help="With --ui web: the address to listen on.")
@click.option("--ui-port", default=8751, show_default=True, type=Whole(1, 65535),
              help="With --ui web: the port of the operator page.")
@click.option("--dry-run", "dry_run", is_flag=True,
              help="Check the station without a board's run: validate the config, open and identify every "
                   "instrument, read a few samples, move a motorized jig; write nothing (exit 0: all answered).")
@click.option("--public", is_flag=True,
              help="With --ui web on an address beyond this machine: serve the operator page without a token.")
@click.option("--shift", "shift", is_flag=True,
              help="Board after board in one process: each starts with its scanned serial; end of input "
                   "at the serial prompt ends the shift with a summary (exit 0).")
@click.option("--device-wait", "device_wait_s", default=DEVICE_WAIT_S, show_default=True,
              type=Finite(0, 86400),
              help="With --shift: seconds to wait for a device that is gone between boards before the shift "
                   "ends (exit 3).")
def command(**opts: Any) -> None:
    """Calibrate one board: identify, present each pose, capture, fit, judge, write NVM, verify, record.

    Exit status: 0 PASS, 1 FAIL, 2 bad input or configuration, 3 device error,
    4 NVM error, 5 operator abort (the same with --ui web).  With --shift: 0 at the shift's end
    (whatever its boards' verdicts), 3 when the device stayed away longer than --device-wait.
    """
    o = RunCommand.from_click(opts)
    cfg = StationConfig.load(o.config_path, o.store_file, o.port, o.jig_port)
    operator, lot = check_run_labels(o.operator, o.lot, cfg.station_id)  # as serials are: no formula, no control
    _check_run(cfg, o.serial, o.shift)
    if o.dry_run:
        _dry_run(cfg, o.as_json)
        return
    event_log.configure(cfg.event_log, avoid=(cfg.path, cfg.store_file))  # logging: (docs/logging.md)
    as_json = o.as_json

    def echo(text: str) -> None:
        click.echo(text, err=as_json)

    tr = translator(language_of(cfg.schema.station))  # the operator's language (docs/language.md)
    run = RunOutput(cfg, operator, lot, as_json, echo, tr)
    if o.shift and o.ui_kind == "terminal":
        _shift(run, TerminalOperator(echo, tr), o.device_wait_s)
        return
    if o.ui_kind == "web":
        _web(run, o.serial, o.page, o.shift, o.device_wait_s)
        return
    # identity questions and their retries always on stderr (stdout may be the JSON object)
    _run(cfg, operator, o.serial, lot, as_json, echo, TerminalOperator(lambda t: click.echo(t, err=True), tr),
         TerminalOperator(echo, tr), lambda reports: None)


@dataclass(frozen=True)
class OperatorPage:
    """`--ui web`'s operator page: the address and port it listens on, and --public (no token)."""

    host: str
    port: int
    public: bool


@dataclass(frozen=True)
class RunCommand:
    """`accelcal run`'s options: the config and its overrides, the run's labels, the front end, the mode."""

    config_path: str | None
    serial: str | None
    operator: str | None
    lot: str | None
    store_file: str | None
    port: str | None
    jig_port: str | None
    as_json: bool
    ui_kind: str
    page: OperatorPage
    dry_run: bool
    shift: bool
    device_wait_s: float

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> RunCommand:
        return cls(config_path=o["config_path"], serial=o["serial"], operator=o["operator"], lot=o["lot"],
                   store_file=o["store_file"], port=o["port"], jig_port=o["jig_port"], as_json=o["as_json"],
                   ui_kind=o["ui_kind"], page=OperatorPage(o["ui_host"], o["ui_port"], o["public"]),
                   dry_run=o["dry_run"], shift=o["shift"], device_wait_s=o["device_wait_s"])


@dataclass(frozen=True)
class RunOutput:
    """A run's (or a shift's) station, the labels it records (checked) and how it speaks: --json (stdout
    is the JSON), ``echo`` (the human lines), ``tr`` (the operator's language)."""

    cfg: StationConfig
    operator: str | None
    lot: str | None
    as_json: bool
    echo: Callable[[str], None]
    tr: Translate


@dataclass(frozen=True)
class ShiftHooks:
    """What a front end adds to a shift: a board started (its serial), a board ended, the shift's
    summary, and the serial prompt it shows."""

    on_start: Callable[[str], None] | None = None
    on_board: OnBoard | None = None
    on_end: Callable[[ShiftSummary], None] | None = None
    prompt: str = SERIAL_PROMPT


def _web(run: RunOutput, serial: str | None, page: OperatorPage, shift: bool, device_wait_s: float) -> None:
    """`--ui web`: the run (or the shift) with the operator page at ``page``."""
    from ._operator_web import finish_outcome, finish_reports, web_operator

    with web_operator(run.cfg, run.echo, page.host, page.port, shift=shift, public=page.public) as web:
        if shift:
            _shift(run, web, device_wait_s, ShiftHooks(web.start_board, lambda b, rep: finish_outcome(web, b, rep),
                                                       web.end_shift, SERIAL_PROMPT_PAGE))
            return
        _run(run.cfg, run.operator, serial, run.lot, run.as_json, run.echo, web, web,
             lambda reports: finish_reports(web, reports))


def _dry_run(cfg: StationConfig, as_json: bool) -> None:
    """`run --dry-run` (station/dry_run.py): one line per instrument; exit 3 when one did not answer right."""
    from ..station.dry_run import dry_run

    checks = dry_run(cfg)
    ok = all(c.ok for c in checks)
    if as_json:
        click.echo(json.dumps({"dry_run": True, "ok": ok, "checks": [c.to_json() for c in checks]}))
    else:
        for c in checks:
            click.echo(f"{'ok ' if c.ok else 'BAD'} {c.what:12s} {c.detail}")
        click.echo("dry run: every instrument answered; nothing was written" if ok else
                   "dry run: the station is not ready (see BAD above); nothing was written")
    if not ok:
        raise click.exceptions.Exit(3)


def _check_run(cfg: StationConfig, serial: str | None, shift: bool) -> None:
    """Before anything runs: the config is not what the run writes; a shift's config is one board's."""
    _refuse_over_config(cfg)
    if shift:
        check_shift_config(cfg, serial)


def _refuse_over_config(cfg: StationConfig) -> None:
    """What a run writes (the store, the simulated board's EEPROM image) is never its own config."""
    dev = cfg.device
    image = dev.eeprom.image if isinstance(dev, SimulatedDevice) and dev.eeprom is not None else None
    refuse_overwrite([("the store", store_file_of(cfg.store_file), "store")], [("--config", str(cfg.path))])
    refuse_output([("device.eeprom.image", image)], [("--config", str(cfg.path))], has_config=False,
                  stores=[("the store", cfg.store_file)])


def _run(cfg: StationConfig, operator: str | None, serial: str | None, lot: str | None, as_json: bool,
         echo: Callable[[str], None], ident_ui: OperatorUI, ui: OperatorUI,
         on_done: Callable[[list[RunReport]], None]) -> None:
    """Identity, then one board, a panel or a thermal plan; ``on_done`` sees the reports before they print."""
    operator, serial = ask_run_identity(cfg, operator, serial, ident_ui)
    echo(f"station {cfg.station_id}: design {cfg.design}, model {cfg.model}, config {cfg.path}")
    if cfg.is_panel:
        _run_panel(cfg, operator, serial, lot, as_json, echo, ui, on_done)
        return
    rep = board_station(cfg, operator, serial, lot, echo, ui).run()[0]
    on_done([rep])
    if as_json:
        click.echo(json.dumps(jsonable(rep.to_dict()), indent=2, allow_nan=False))
    else:
        _print_board(rep, cfg)
    if rep.verdict != "PASS":
        raise click.exceptions.Exit(1)


def _shift(run: RunOutput, ui: OperatorUI, device_wait_s: float, hooks: ShiftHooks | None = None) -> None:
    """`run --shift`: each board printed as it ends (one JSON line each under --json), then the
    shift's summary (one JSON line); DeviceGone (exit 3) after the summary when the device stayed away."""
    cfg, as_json, echo, tr = run.cfg, run.as_json, run.echo, run.tr
    h = hooks if hooks is not None else ShiftHooks()
    echo(f"station {cfg.station_id}: design {cfg.design}, model {cfg.model}, config {cfg.path}; shift started")

    def board(b: BoardOutcome, rep: RunReport | None) -> None:
        if as_json:
            click.echo(json.dumps(jsonable({"kind": "board", **(b.to_dict() if rep is None else rep.to_dict()),
                                            "retest": b.retest}), allow_nan=False))
        elif rep is not None:
            _print_board(rep, cfg)
        else:
            click.secho(f"{b.verdict} board {b.serial} (run {b.run_id}): " + "; ".join(
                f"{reason_title(c, tr)} ({m})" for c, m in zip(b.reason_codes, b.messages, strict=True)), fg="yellow")
        if h.on_board is not None:
            h.on_board(b, rep)

    tally, gone = run_shift(cfg, run.operator, run.lot, ShiftFrontEnd(ui, echo, tr(h.prompt), tr), board, device_wait_s,
                            h.on_start)
    s = tally.summary()
    if h.on_end is not None:
        h.on_end(s)
    if as_json:
        click.echo(json.dumps(jsonable(s), allow_nan=False))
    else:
        for line in summary_lines(s, tr):
            click.secho(line, bold=True)
    if gone is not None:
        raise gone


def _print_board(rep: RunReport, cfg: StationConfig) -> None:
    """One board's run for the operator: the fit, the thermal table, the verdict and its reasons (in the
    operator's language), the timing."""
    tr = translator(language_of(cfg.schema.station))
    t = rep.timing
    f = rep.fit
    if f is not None:
        click.echo(f"fit: model {rep.model}, {f.pose_count} poses, residual RMS {f.residual_rms_g * 1e3:.3f} mg"
                   + ("" if f.crossval_rms_g is None else f", cross-validated {f.crossval_rms_g * 1e3:.3f} mg"))
    table = (rep.plan_summary() or {}).get("table")
    if table:
        click.echo(f"table: {len(table['temps_c'])} temperatures ("
                   + ", ".join(f"{t:.1f}" for t in table["temps_c"]) + f" C), {table['method']}; "
                   "the fit above is the one at the temperature nearest "
                   f"{_reference_c(cfg):g} C")
    if rep.verify_error_max_mg is not None:
        click.echo(f"verify: max error {rep.verify_error_max_mg:.3f} mg after calibration")
    colour = "green" if rep.verdict == "PASS" else "red"
    click.secho(f"{rep.verdict} board {rep.serial} (run {rep.run_id}, store {rep.store})", fg=colour, bold=True)
    for r in rep.reasons:  # the operator's words for the reason, then its figures
        click.secho(f"  - {reason_title(r.code, tr)}: {r}", fg=colour)
    if t and "soak_s" in t:
        click.echo(f"time per board: soak {t['soak_s']:.0f} s, sampling floor {t['sampling_floor_s']:.1f} s, "
                   f"rest {t['rest_s']:.1f} s of {t['board_time_s']:.0f} s ({t['clock']} clock)")
    else:
        for line in timing_lines(t):
            click.echo(line)


def _reference_c(cfg: StationConfig) -> float:
    """thermal.reference_c: the temperature whose fit a thermal run reports."""
    thermal = cfg.schema.thermal
    return 25.0 if thermal is None else thermal.reference_c


def timing_lines(t: Timing) -> list[str]:
    """Timing a reader can trust: samples at the nominal ODR, operator waiting, host compute,
    each on its own (never a 'floor' compared with a wall time it need not be below)."""
    if not t:
        return []
    out = [f"time: {t['samples_read']} samples read ({t['sampling_s']:.1f} s at the nominal "
           f"{t['odr_hz']:g} Hz), {t['samples_averaged']} averaged"]
    if "board_time_s" in t:
        out.append(f"time: board clock {t['device_time_s']:.1f} s (simulated: moves, settling, sampling, "
                   f"EEPROM); host compute {t['host_compute_s']:.2f} s")
    else:
        out.append(f"time: wall {t['wall_s']:.1f} s = operator waiting {t['operator_wait_s']:.1f} s "
                   f"+ station {t['host_compute_s']:.1f} s (sampling, moves, compute)")
    return out


def _run_panel(cfg: StationConfig, operator: str | None, serial: str | None, lot: str | None, as_json: bool,
               echo: Callable[[str], None], ui: OperatorUI, on_done: Callable[[list[RunReport]], None]) -> None:
    """A panel: one line per board; exit 3 when the station faulted on a board (not judged), else 1 when
    any board failed."""
    from ..errors import ConfigError
    from ..station.flow import make_flow
    from ..station.panel import panel_dict

    if serial is not None:
        raise ConfigError("--serial: a panel's boards keep their own serials; remove --serial "
                          "(or set device.boards[i].serial)")
    station = make_flow(cfg, operator=operator, lot=lot, echo=echo, ui=ui)  # a thermal plan's too
    reports = station.run()
    on_done(reports)
    panel_id = station.panel_id
    assert panel_id is not None, "a panel's flow carries its id (FlowPolicy.for_config)"
    if as_json:
        click.echo(json.dumps(jsonable(panel_dict(panel_id, reports, station.panel)), indent=2, allow_nan=False))
    else:
        for i, rep in enumerate(reports):
            colour = "green" if rep.verdict == "PASS" else "red"
            why = "" if not rep.reasons else ": " + "; ".join(rep.reasons)
            click.secho(f"board {i + 1:2d} {rep.serial or '-':<14} {rep.verdict} (run {rep.run_id}){why}", fg=colour)
        t = station.timing
        passed = sum(r.verdict == "PASS" for r in reports)
        line = f"panel {panel_id}: {passed}/{len(reports)} passed, store {cfg.store_file}"
        if "panel_time_s" in t:
            line += f"; {t['panel_time_s']:.1f} s board time, {t['per_board_s']:.2f} s per board"
        click.echo(line)
        if "per_board" in t:
            pb = t["per_board"]
            click.echo(f"time per board ({t['boards']} boards): soak {pb['soak_s']:.0f} s, sampling floor "
                       f"{pb['sampling_floor_s']:.1f} s, rest {pb['rest_s']:.1f} s of {pb['board_time_s']:.0f} s "
                       f"({t['clock']} clock)")
    if any(r.station_fault for r in reports):  # the station's error (exit 3): those boards are not judged
        raise click.exceptions.Exit(3)
    if any(r.verdict != "PASS" for r in reports):
        raise click.exceptions.Exit(1)

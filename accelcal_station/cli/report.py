"""`accelcal report`: list, show, export and summarise the runs in the results store."""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from ..calibration import PARAM_NAMES
from ..config.checks import load_yaml
from ..errors import DataError
from ..jsontypes import JsonValue
from ..store.location import store_path, store_target
from ..store.records import RunRecord
from ..store.runs import Store
from ._common import MAX_ID, Whole, force_option
from ._mes import JsonGroup
from ._report_filters import RunSelection, filter_options, open_reader, store_target_of
from ._text import clean
from .certificate import certificate_command, verify_certificate_command
from .msa import msa_command


def _name_damage(damage: list[dict[str, str]]) -> None:
    """One line on stderr per damaged value read (the output goes on; `report check` lists all)."""
    for d in damage:
        click.echo(clean(f"damaged_row: {d['table']} {d['id']} {d['column']}: {d['problem']}"), err=True)


def _name_unread(recs: list[RunRecord]) -> None:
    """A SKIP line on stderr per complete run whose poses cannot be read (RunRecord.poses_unread): its
    row is exported, its poses are not, and the export says so."""
    for rec in recs:
        if not rec.damage and (why := rec.poses_unread()) is not None:
            click.echo(clean(f"SKIP run {rec.id}: {why}"), err=True)


class ReportGroup(JsonGroup):
    """`accelcal report [--db F] --json` lists the runs, as `report list --json` does."""

    def describe(self, ctx: click.Context) -> str:
        with open_reader(ctx.params.get("db"), ctx.params.get("config_path")) as store:
            return json.dumps(store.list_runs())


@click.group("report", cls=ReportGroup)
@click.option("--db", default=None, metavar="FILE", help="With --json and no subcommand: the store to list.")
@click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path).")
def command(db: str | None, config_path: str | None) -> None:
    """List, show, export and summarise recorded runs."""


@command.command("list")
@filter_options
@click.option("--limit", default=None, type=Whole(1, 10**9), help="At most this many runs.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def list_cmd(**opts: Any) -> None:
    """Runs matching the filters, oldest first."""
    _list(RunSelection.from_click(opts), opts["limit"], opts["as_json"])


def _list(sel: RunSelection, limit: int | None, as_json: bool) -> None:
    with open_reader(sel.db, sel.config_path) as store:
        runs = store.list_runs(limit, **sel.filters())
    if as_json:
        click.echo(json.dumps(runs, indent=1))
        return
    click.echo(f"{'id':>5}  {'started (UTC)':16}  {'status':11}  {'device':14}  {'lot':8}  verdict  "
               f"{'nvm':7}  poses  {'rms mg':>7}  reasons")
    for r in runs:
        rms = "" if r["residual_rms_g"] is None else f"{r['residual_rms_g'] * 1e3:7.3f}"
        started = (r["started_at"] or "?")[:16].replace("T", " ")
        rid = "?" if r["id"] is None else r["id"]  # a damaged id: named below, the row still shown
        click.echo(clean(f"{rid:>5}  {started:16}  {r['status'] or '?':11}  "
                         f"{r['device_serial'] or '':14}  {r['lot'] or '':8}  {r['verdict'] or '':7}  "
                         f"{r['nvm_status'] or '':7}  {r['pose_count']:5}  {rms:>7}  "
                         f"{'; '.join(r['reasons']) or (r['status_reason'] or '')}")
                   + (f"  DAMAGED ({', '.join(r['damaged'])} unreadable)" if r.get("damaged") else ""))
    click.echo(f"{len(runs)} run(s)")
    _name_damage([d for r in runs for d in r.get("damage", [])])


@command.command("show")
@click.argument("run_id", type=Whole(-MAX_ID - 1, MAX_ID))  # an outbox run is numbered below 0
@click.option("--db", default=None, metavar="FILE|URL", help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB.")
@click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def show_cmd(run_id: int, db: str | None, config_path: str | None, as_json: bool) -> None:
    """Everything recorded for one run."""
    with open_reader(db, config_path) as store:
        rec = store.get_run(run_id).to_dict()
    if as_json:
        click.echo(json.dumps(rec, indent=1))
        return
    for k in ("id", "status", "status_reason", "started_at_iso", "finished_at_iso", "device_serial", "chip",
              "station_id", "operator", "lot", "config_hash", "model", "verdict", "nvm_status"):
        click.echo(f"{k:16} {rec[k] if rec[k] is not None else ''}")
    for d in rec["damage"]:
        click.echo(clean(f"{'DAMAGED':16} damaged_row: {d['table']} {d['id']} {d['column']}: {d['problem']}"))
    for reason in rec["reasons"]:
        click.echo(f"{'reason':16} {clean(reason)}")
    if rec["calibration"]:
        c = rec["calibration"]
        click.echo(f"{'W':16} {c['W']}\n{'V (g)':16} {c['V']}\n{'Gamma (1/g^2)':16} {c['Gamma']}")
        meta = c.get("metadata")
        held = meta.get("held") if isinstance(meta, dict) else None
        for h in held if isinstance(held, list) else []:  # terms the poses did not determine (models/held.py)
            if isinstance(h, dict):
                click.echo(clean(f"{'held':16} {h.get('term')} = {h.get('value')}: {h.get('reason')}; "
                                 f"{h.get('hint')}"))
    for line in _fit_lines(rec.get("fit_summary") or {}):
        click.echo(line)
    click.echo(f"{'poses':16} {len(rec['poses'])} ({rec['units']})")
    for p in rec["poses"]:
        click.echo(f"  {clean(p['name']):10} mean {[round(x, 2) for x in p['mean']]}  n {p['n']}  "
                   f"retries {p['retries']}")
    for e in rec.get("events") or []:
        click.echo(f"{'event':16} {clean(e['kind'] or '')}: {clean(e['message'] or '')}")


def _fit_lines(fit: Mapping[str, JsonValue]) -> list[str]:
    """Residuals, cross-validation, verification error and timing of a recorded run (a stored JSON
    column read back: every value checked before it is printed)."""
    out = []
    for key, label in (("residual_rms_g", "residual rms"), ("residual_max_g", "residual max"),
                       ("crossval_rms_g", "cross-validated")):
        if isinstance(v := fit.get(key), int | float):
            out.append(f"{label:16} {v * 1e3:.3f} mg")
    if isinstance(v := fit.get("condition_number"), int | float):
        out.append(f"{'condition':16} {v:.3g}")
    if isinstance(v := fit.get("verify_error_max_mg"), int | float):
        out.append(f"{'verify error':16} {v:.3f} mg (max, after calibration)")
    if skipped := fit.get("skipped"):
        items = skipped if isinstance(skipped, list | dict | str) else [skipped]  # a damaged value: printed
        out.append(f"{'skipped':16} {', '.join(clean(str(x)) for x in items)}")
    t = fit.get("timing") or {}
    if t and isinstance(t, dict):
        out.append(f"{'timing':16} " + ", ".join(f"{k} {v:.3g}" for k, v in t.items() if isinstance(v, int | float)))
    return out


@command.command("export")
@filter_options
@click.option("-o", "--output", default=None, metavar="FILE", help="Write here (atomically); default stdout.")
@click.option("--format", "fmt", default=None, metavar="csv|json",
              help="Output format (default: from the file name, else csv).")
@click.option("--poses", is_flag=True, help="CSV: one row per pose instead of one per run.")
@click.option("--json", "as_json", is_flag=True, help="With -o, print a JSON line saying what was written.")
@force_option
def export_cmd(**opts: Any) -> None:
    """Export runs as CSV (one row per run, calibration flattened; or per pose) or JSON (everything)."""
    _export(ExportOptions.from_click(opts))


@dataclass(frozen=True)
class ExportOptions:
    """`report export`'s options: the runs, where and how they are written."""

    selection: RunSelection
    output: str | None
    fmt: str | None
    poses: bool
    as_json: bool
    force: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> ExportOptions:
        return cls(selection=RunSelection.from_click(o), output=o["output"], fmt=o["fmt"], poses=o["poses"],
                   as_json=o["as_json"], force=o["force"])


def _export(o: ExportOptions) -> None:
    output, poses, as_json = o.output, o.poses, o.as_json
    fmt = o.fmt
    if fmt is None:  # --json without -o means JSON on stdout
        fmt = "json" if (output and output.lower().endswith(".json")) or (as_json and output is None) else "csv"
    if fmt not in ("csv", "json"):
        raise DataError(f"--format {fmt!r}; allowed: csv, json")
    flt = o.selection.filters()
    with open_reader(o.selection.db, o.selection.config_path, ("-o", output, fmt), force=o.force) as store:
        n = len(store.list_runs(**flt))
        if fmt == "json":
            data = store.export_json(output, **flt)
            text = json.dumps({"schema": "accelcal.runs", "version": 1, "runs": data}, indent=1)
        else:
            text = store.export_csv(output, kind="poses" if poses else "runs", **flt)
        recs = store.runs(**flt)
        _name_damage([d.to_dict() for rec in recs for d in rec.damage])  # poses' and events' too
        _name_unread(recs)
    if output is None:
        click.echo(text.rstrip("\n"))
    elif as_json:
        click.echo(json.dumps({"path": output, "format": fmt, "runs": n}))
    else:
        click.echo(f"wrote {n} run(s) to {output} ({fmt})")


@command.command("summary")
@filter_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@click.option("--html", "html_file", default=None, metavar="FILE",
              help="Also write a lot report (histograms vs limits, pass rate and reasons over time, control "
                   "charts) as one HTML file with embedded PNGs.")
@force_option
def summary_cmd(**opts: Any) -> None:
    """Lot summary: counts, pass rate, failure reasons, parameter distributions."""
    _summary(RunSelection.from_click(opts), opts["as_json"], opts["html_file"], opts["force"])


def _summary(sel: RunSelection, as_json: bool, html_file: str | None, force: bool) -> None:
    flt, lot = sel.filters(), sel.lot
    with open_reader(sel.db, sel.config_path, ("--html", html_file, "html"), force=force) as store:
        s = store.lot_summary(**flt)
        if html_file is not None:
            from ..lot.report import write_lot_html

            write_lot_html(store.runs(**flt), html_file, f"accelcal lot report{f' - lot {lot}' if lot else ''}")
            click.echo(f"lot report written to {html_file}", err=True)
    if as_json:
        click.echo(json.dumps(s, indent=1))
        return
    _name_damage(s["damaged_rows"])
    rate = "n/a" if s["pass_rate"] is None else f"{100 * s['pass_rate']:.1f} %"
    click.echo(f"runs {s['runs']} ({', '.join(f'{k} {v}' for k, v in s['by_status'].items())}), "
               f"devices {s['devices']}, {s['first_started'] or '-'} .. {s['last_started'] or '-'}")
    click.echo(f"PASS {s['pass']}  FAIL {s['fail']}  pass rate {rate}")
    for code, n in s["failure_reasons"].items():
        click.echo(f"  fail: {code:24} {n}")
    for why, n in s["interruptions"].items():
        click.echo(f"  interrupted: {why} ({n})")
    click.echo("nvm: " + (", ".join(f"{k} {v}" for k, v in s["nvm"].items()) or "-"))
    if s["parameters"]:
        n = s["parameters"]["W00"]["n"]
        click.echo(f"{'parameter':14} {'mean':>12} {'std':>12} {'min':>12} {'max':>12}   (n {n})")
        for name in PARAM_NAMES:
            d = s["parameters"][name]
            click.echo(f"{name:14} {d['mean']:12.6g} {d['std']:12.6g} {d['min']:12.6g} {d['max']:12.6g}")
    for name, d in s["fit"].items():
        click.echo(f"{name:14} {d['mean']:12.6g} {d['std']:12.6g} {d['min']:12.6g} {d['max']:12.6g}")


@command.command("check")
@click.option("--db", default=None, metavar="FILE|URL", help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB.")
@click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@click.pass_context
def check_cmd(ctx: click.Context, db: str | None, config_path: str | None, as_json: bool) -> None:
    """List every damaged row (table, id, column, what is wrong) and what SQLite's integrity check
    finds in the file (pages it cannot read); exit 1 when any. Nothing is modified."""
    with open_reader(db, config_path) as store:
        found = [d.to_dict() for d in store.check()]
        pages = store.integrity()
        where = str(store.path)
    if as_json:
        click.echo(json.dumps({"store": where, "damaged": found, "integrity": pages}, indent=1))
    else:
        for d in found:
            click.echo(clean(f"{d['table']:7} {d['id']:>12}  {d['column']:14} {d['problem']}"))
        for line in pages:
            click.echo(clean(f"file    {line}"))
        rows = len({(d["table"], d["id"]) for d in found})
        click.echo(f"{len(found)} damaged value(s) in {rows} row(s) of {where}" if found
                   else f"no damaged rows in {where}")
        if pages:
            click.echo(f"{len(pages)} integrity problem(s) in the file (PRAGMA integrity_check)")
    if found or pages:
        ctx.exit(1)


@command.command("migrate")
@click.option("--db", default=None, metavar="FILE|URL", help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB.")
@click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def migrate_cmd(db: str | None, config_path: str | None, as_json: bool) -> None:
    """Upgrade the store's schema to this station's (Alembic), recording its revision; says what it did.
    A store without a revision is stamped with the schema its columns have. The only reading-side
    command that writes a store."""
    from ..store.schema import SCHEMA_VERSION

    target, _ = store_target_of(db, config_path)
    with Store(target, create=False) as store:
        done = store.notice or f"{store.path}: schema {SCHEMA_VERSION} already, revision recorded; nothing written"
        where = str(store.path)
    if as_json:
        click.echo(json.dumps({"store": where, "schema_version": SCHEMA_VERSION, "message": done}))
    else:
        click.echo(clean(done))


@command.command("sync")
@click.option("--db", default=None, metavar="URL", help="The line database (postgresql://...); default: the "
              "store of --config or of the default station.")
@click.option("--config", "config_path", default=None, metavar="FILE",
              help="Station config (store.path, store.outbox).")
@click.option("--outbox", default=None, metavar="FILE",
              help="The local outbox (default: the config's store.outbox, else "
                   "$XDG_STATE_HOME/accelcal/outbox.sqlite).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def sync_cmd(db: str | None, config_path: str | None, outbox: str | None, as_json: bool) -> None:
    """Replay the runs kept in the local outbox while the line database was unreachable (each once)."""
    from ..config.sections import default_config_path
    from ..store.location import outbox_of
    from ..store.outbox import default_outbox, sync

    cfg = load_yaml(config_path or default_config_path()) if db is None or outbox is None else {}
    target = store_target(db) if db is not None else store_path(cfg, Path.cwd())
    box = Path(outbox) if outbox is not None else (outbox_of(cfg) or default_outbox())
    with Store(target, create=False) as server:
        if not box.is_file():
            res = None
        else:
            with Store(box, create=False) as local:
                res = sync(server, local)
        where = str(server.path)
    done = {"store": where, "outbox": str(box), "replayed": [] if res is None else [s for _, s in res.replayed],
            "already_there": [] if res is None else [s for _, s in res.unchanged],
            "still_running": [] if res is None else res.running}
    if as_json:
        click.echo(json.dumps(done))
        return
    if res is None or not (res.replayed or res.unchanged or res.running):
        click.echo(f"nothing to replay: no run waiting in {box}")
        return
    click.echo(f"replayed {len(res.replayed)} run(s) from {box} into {where}"
               + (f" (runs {', '.join(str(s) for _, s in res.replayed)})" if res.replayed else "")
               + (f"; {len(res.unchanged)} already there in full" if res.unchanged else "")
               + (f"; {len(res.running)} still running locally, not replayed" if res.running else ""))


@command.command("plot")
@click.argument("run_id", type=Whole(-MAX_ID - 1, MAX_ID))  # an outbox run is numbered below 0
@click.option("--db", default=None, metavar="FILE", help="Results store (SQLite file).")
@click.option("--config", "config_path", default=None, metavar="FILE", help="Station config (store.path).")
@click.option("-o", "--output", default=None, metavar="FILE.png", help="Figure file (default run-ID-residuals.png).")
@force_option
def plot_cmd(run_id: int, db: str | None, config_path: str | None, output: str | None, force: bool = False) -> None:
    """Draw one run's residuals per pose and axis (PNG)."""
    from ..lot.report import residual_figure

    out = output or f"run-{run_id}-residuals.png"
    with open_reader(db, config_path, ("-o", out, "png"), force=force) as store:
        rec = store.get_run(run_id)
    residual_figure(rec, out)
    click.echo(f"residuals of run {run_id} drawn in {out}")


command.add_command(msa_command)  # `report msa` (cli/msa.py)
command.add_command(certificate_command)  # `report certificate` (cli/certificate.py)
command.add_command(verify_certificate_command)  # `report verify-certificate`

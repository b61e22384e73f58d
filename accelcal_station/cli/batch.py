"""`accelcal batch`: recalibrate many boards from stored runs or pose tables with one model.

Exit status: 0 every board fitted; 1 some boards skipped (each reported with its
reason; the others' results are written); 2 bad input (no boards, a bad option,
an unreadable store, an unwritable output).
"""
from __future__ import annotations

import json
import sys
from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypedDict

import click

from ..errors import DataError
from ..fileguard.identity import Named, refuse_overwrite
from ._common import check_model_units, force_option, output_kind, parse_int, store_file
from ._common import jsonable as _clean
from ._common import parse_number as _number
from ._outputs import refuse_output, stores_reached
from ._text import clean, error_text

if TYPE_CHECKING:  # a lot file's mode (--out) imports neither the pose-table batch nor the store
    from ..acceptance.rules import Limits
    from ..lot.batch import BatchReport, Source
    from ..lot.batch_json import BatchOutputs


class StoreFilters(TypedDict):
    """--from-store's filters, as sessions_from_store's keyword arguments (None: not filtered)."""

    lot: str | None
    device: list[str] | None
    station: str | None
    since: str | None
    until: str | None
    run_ids: list[int] | None

PROGRESS_MIN_BOARDS = 10  # below this a progress bar is noise


class _Progress(Protocol):
    """What the commands use of a progress bar: advance it by n steps."""

    def update(self, n: int, /) -> None: ...


def _bar(show: bool, length: int, label: str) -> AbstractContextManager[_Progress]:
    """A click progress bar on stderr (stdout stays the report), or a no-op."""
    if not show:
        return _NoBar()
    return click.progressbar(length=length, label=label, file=sys.stderr, show_pos=True)


class _NoBar:
    """A progress bar that shows nothing."""

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def update(self, n: int) -> None:
        pass


def _mg(v: float | None) -> str:
    return "n/a" if v is None else f"{v * 1e3:.3f} mg"


def _text(report: BatchReport, outputs: BatchOutputs, list_all: bool) -> list[str]:
    """The human report: skipped boards (every board with ``list_all``), the tally, the outputs."""
    lines = []
    for r in report.results:
        who = r.source + (f" ({r.serial})" if r.serial else "")
        if r.ok and r.verdict is not None and (list_all or not r.verdict.passed):
            lines.append(click.style(f"{r.verdict.label} ", fg="green" if r.verdict.passed else "red", bold=True)
                         + clean(who) + (f": {'; '.join(r.verdict.reasons)}" if r.verdict.reasons else ""))
        elif not r.ok:
            lines.append(click.style("SKIP ", fg="red", bold=True) + error_text(f"{who}: {r.message}"))
        elif list_all:
            lines.append(click.style("ok   ", fg="green") + f"{clean(who)}: {r.pose_count} poses, residual RMS "
                         f"{_mg(r.residual_rms_g)}, leave-one-out {_mg(r.crossval_rms_g)}"
                         + "".join(f"; held: {h.text}" for h in r.held))
    n, ok = len(report.results), len(report.fitted)
    # a fitted board always has its residual RMS
    rms = sorted(r.residual_rms_g for r in report.fitted if r.residual_rms_g is not None)
    med = f", median residual RMS {_mg(rms[len(rms) // 2])}" if rms else ""
    colour = "green" if ok == n else ("yellow" if ok else "red")
    lines.append(click.style(f"{ok} of {n} boards recalibrated with model {report.model}", fg=colour, bold=True)
                 + f"{med}; {n - ok} skipped; {report.fit_calls} fit call(s), {report.elapsed_s:.2f} s")
    held = [r for r in report.fitted if r.held]
    if held:  # what the poses did not determine, said even when the boards are not listed
        terms = sorted({h.term for r in held for h in r.held})
        lines.append(f"held at nominal on {len(held)} board(s): {', '.join(terms)} "
                     f"({held[0].held[0].text})")
    judged = [r.verdict.passed for r in report.results if r.ok and r.verdict is not None]
    if judged:
        lines.append(f"verdicts: PASS {sum(judged)}, FAIL {len(judged) - sum(judged)}")
    if "out_dir" in outputs:
        lines.append(f"calibrations: {outputs['calibrations']} file(s) in {outputs['out_dir']}")
    if "csv" in outputs:
        lines.append(f"summary: {outputs['csv']}")
    if "store" in outputs:
        st = outputs["store"]
        lines.append(f"store {st['path']}: {st['events']} recalibration event(s) on source runs, "
                     f"{st['runs']} new run(s)")
    return lines


def _arrow_allocator() -> None:
    """This process's Arrow allocations from jemalloc where pyarrow has it (the Linux wheels do):
    a lot's peak RSS 195 -> 173 MB for 200,000 boards from Parquet, 134 -> 131 MB from CSV, at the
    same speed (benchmarks/README.md); Arrow's default, mimalloc, keeps more of freed blocks.
    The command owns its process, so it chooses the allocator; the library leaves it alone."""
    try:
        import pyarrow as pa

        pa.set_memory_pool(pa.jemalloc_memory_pool())
    except (ImportError, NotImplementedError):  # no pyarrow (the csv module reads), or no jemalloc in it
        pass


@dataclass(frozen=True)
class LotRequest:
    """`accelcal batch LOT --out RESULTS`, as given: the lot file(s) named, how to fit them (model, units,
    counts per g, site gravity), the results table, the config whose limits judge, the chunk size."""

    paths: tuple[str, ...]
    model: str
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    out: str
    config_path: str | None
    chunk_boards: int
    as_json: bool
    force: bool


def _lot_mode(ctx: click.Context, req: LotRequest, other: list[str]) -> None:
    """accelcal batch LOT --out RESULTS: stream a lot file into one results table (``other``: the
    options of the other modes given, refused)."""
    from ..lot.streaming import recalibrate_lot

    paths, out, model, config_path, as_json = req.paths, req.out, req.model, req.config_path, req.as_json
    if other:
        raise DataError(f"--out writes a lot file's results table; {', '.join(other)} cannot be combined with it")
    if len(paths) != 1:
        raise DataError(f"--out takes one lot file; got {len(paths)} path(s)")
    refuse_output([("--out", out, output_kind(out))], [("the lot file", paths[0]), ("--config", config_path)],
                  req.force, config=config_path)
    limits = _limits(config_path)
    _arrow_allocator()
    summary = recalibrate_lot(paths[0], out, model, units=req.units, counts_per_g=req.counts_per_g,
                              gravity_mps2=req.gravity_mps2, limits=limits, chunk_boards=req.chunk_boards)
    if as_json:
        click.echo(json.dumps(_clean({**summary.to_dict(), "out": str(out)}), allow_nan=False))
    else:
        for serial, reason in summary.unfitted_examples:
            click.echo(click.style("SKIP ", fg="red", bold=True) + error_text(f"{serial}: {reason}"))
        n, ok = summary.boards, summary.fitted
        verdicts = f"; PASS {summary.passed}, FAIL {summary.failed}" if limits is not None else ""
        click.echo(click.style(f"{ok} of {n} boards recalibrated with model {model}",
                               fg="green" if ok == n else "yellow", bold=True)
                   + f"; {n - ok} skipped{verdicts}; {summary.elapsed_s:.2f} s ({summary.boards_per_s:.0f} boards/s)")
        click.echo(f"results: {out}" + (" (every skipped board is listed there with its reason)"
                                         if n - ok > len(summary.unfitted_examples) else ""))
    if summary.fitted < summary.boards:
        ctx.exit(1)


@click.command("batch")
@click.argument("paths", nargs=-1, metavar="[POSE_TABLE|DIR|GLOB]...")
@click.option("--from-store", "from_store", default=None, metavar="FILE|URL",
              help="Take boards from this results store (complete runs with poses): a file, sqlite:///FILE "
                   "or postgresql://USER@HOST/DB.")
@click.option("--lot", default=None, metavar="LOT", help="--from-store: only this lot.")
@click.option("--device", multiple=True, metavar="SERIAL", help="--from-store: only these serials (repeatable).")
@click.option("--station", default=None, metavar="ID", help="--from-store: only runs of this station.")
@click.option("--since", default=None, metavar="TIME", help="--from-store: started at or after (ISO 8601).")
@click.option("--until", default=None, metavar="TIME", help="--from-store: started before (ISO 8601).")
@click.option("--run", "run_ids", multiple=True, metavar="ID", help="--from-store: only these run ids (repeatable).")
@click.option("--model", default="12", show_default=True, metavar="6|9|12|15", help="Model to fit.")
@click.option("--units", default=None, metavar="counts|g|mps2", help="Pose tables: units (default: each table's).")
@click.option("--counts-per-g", "counts_per_g", default=None, metavar="N",
              help="Pose tables: counts per g (default: each table's '# counts_per_g:').")
@click.option("--gravity", default=None, metavar="M_S2",
              help="The site's gravity in m/s^2 (default: each file's '# gravity_mps2:' line, else standard): "
                   "references scaled to it, the calibration maps to standard g.")
@click.option("--out-dir", default=None, metavar="DIR", help="Write one calibration JSON per fitted board here.")
@click.option("--csv", "csv_path", default=None, metavar="FILE", help="Write a summary CSV (one row per board).")
@click.option("--to-store", "to_store", default=None, metavar="FILE|URL",
              help="Record results in this results store (events on source runs when it is the --from-store "
                   "file; new runs otherwise).")
@click.option("--out", "out", default=None, metavar="FILE",
              help="Lot file mode: write one results table (.csv, .parquet or .jsonl), a row per board.")
@click.option("--config", "config_path", default=None, metavar="YAML",
              help="Judge every board against this station config's acceptance limits (pose tables, "
                   "--from-store and lot files).")
@click.option("--chunk-boards", "chunk_boards", default="4096", show_default=True, metavar="N",
              help="Lot file mode: boards read, fitted and written per chunk (bounds memory).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@force_option
@click.pass_context
def command(ctx: click.Context, **opts: Any) -> None:
    """Recalibrate many boards with one model (vectorised); unfittable boards are reported and skipped.

    A lot file (one CSV or Parquet table of every pose, with a serial column) is
    streamed in chunks into one results table: accelcal batch LOT.csv --out results.csv.
    --config F: each board judged PASS/FAIL by that station's acceptance limits.

    Exit status 0: all boards fitted; 1: some skipped; 2: bad input.
    """
    o = BatchCommand.from_click(opts)
    check_model_units(o.model, o.units)
    cpg, grav = _number(o.counts_per_g, "--counts-per-g"), _number(o.gravity, "--gravity")
    _check_chunk_boards(ctx, o.out, o.config_path, o.chunk_boards)
    if o.out is not None:
        _lot_mode(ctx, LotRequest(o.paths, o.model, o.units, cpg, grav, o.out, o.config_path,
                                  parse_int(o.chunk_boards, "--chunk-boards") or 0, o.as_json, o.force),
                  _given(("--from-store", o.from_store), ("--out-dir", o.out_dir), ("--csv", o.csv_path),
                         ("--to-store", o.to_store)))
        return
    filters = _store_filters(o.from_store, o.lot, o.device, o.station, o.since, o.until, o.run_ids)
    if _tables_mode(o.paths, o.from_store, filters, (o.model, o.units, cpg, grav), (o.out_dir, o.csv_path, o.to_store),
                    o.config_path, o.as_json, o.force):
        ctx.exit(1)


@dataclass(frozen=True)
class BatchCommand:
    """`accelcal batch`'s options as given (numbers still text: parsed, with their option's name, in
    ``command``): the boards (paths, --from-store and its filters), the fit, the outputs, the mode."""

    paths: tuple[str, ...]
    from_store: str | None
    lot: str | None
    device: tuple[str, ...]
    station: str | None
    since: str | None
    until: str | None
    run_ids: tuple[str, ...]
    model: str
    units: str | None
    counts_per_g: str | None
    gravity: str | None
    out_dir: str | None
    csv_path: str | None
    to_store: str | None
    out: str | None
    config_path: str | None
    chunk_boards: str
    as_json: bool
    force: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> BatchCommand:
        return cls(**{f.name: o[f.name] for f in fields(cls)})


def _tables_mode(paths: tuple[str, ...], from_store: str | None, filters: StoreFilters,
                 how: tuple[str, str | None, float | None, float | None],
                 outs: tuple[str | None, str | None, str | None], config_path: str | None, as_json: bool,
                 force: bool) -> bool:
    """Pose tables or a store's runs: each board fitted (``how``: model, units, counts per g, gravity), the
    outputs (``outs``: --out-dir, --csv, --to-store) written and the report printed; True when boards were
    skipped."""
    out_dir, csv_path, to_store = outs
    protected = _check_inputs(paths, from_store, csv_path, to_store, out_dir, force, config_path)
    report = _fit_boards(paths, from_store, filters, *how, as_json, _limits(config_path))
    outputs, written = _write_outputs(report, out_dir, csv_path, to_store, from_store, config_path, force, protected)
    _print_report(report, outputs, written, as_json)
    return bool(report.skipped)


def _given(*options: tuple[str, str | None]) -> list[str]:
    """The names of the options given (lot file mode refuses them)."""
    return [k for k, v in options if v is not None]


def _check_chunk_boards(ctx: click.Context, out: str | None, config_path: str | None, chunk_boards: str) -> None:
    """Refuse --chunk-boards given outside lot file mode (no --out)."""
    if out is None and \
            ctx.get_parameter_source("chunk_boards") is not click.core.ParameterSource.DEFAULT:
        raise DataError(f"--chunk-boards {chunk_boards}: applies to lot file mode only; add --out FILE "
                        "(a results table) or remove --chunk-boards")


def _store_filters(from_store: str | None, lot: str | None, device: tuple[str, ...], station: str | None,
                   since: str | None, until: str | None, run_ids: tuple[str, ...]) -> StoreFilters:
    """The --from-store filters as keyword arguments of sessions_from_store; refused without --from-store."""
    ids = [n for i in run_ids if (n := parse_int(i, "--run")) is not None]
    store_filters: StoreFilters = {"lot": lot, "device": list(device) or None, "station": station, "since": since,
                                   "until": until, "run_ids": ids or None}
    if from_store is None and any(v is not None for v in store_filters.values()):
        flag = next(k for k, v in store_filters.items() if v is not None).replace("run_ids", "run").replace("_", "-")
        raise DataError(f"--{flag} filters runs of a results store; add --from-store FILE")
    return store_filters


def _check_inputs(paths: tuple[str, ...], from_store: str | None, csv_path: str | None, to_store: str | None,
                  out_dir: str | None = None, force: bool = False, config_path: str | None = None) -> list[Named]:
    """Refuse, before any work, a call with no boards, a --csv file in a folder that does not exist, or
    an output that is one of the inputs (a pose table) or a store the command reaches; returns those
    stores (_outputs.stores_reached), for the files --out-dir will get."""
    from ..lot.batch import expand_paths

    if not paths and from_store is None:
        raise DataError("no boards given; pass pose tables, directories or globs, or --from-store FILE")
    inputs = [("input", str(p)) for p in expand_paths(paths)] if paths else []
    protected = stores_reached(config_path, own=[("--from-store", from_store)])
    refuse_overwrite([("--csv", csv_path, "csv")], [*inputs, *protected], force)
    refuse_overwrite([("--to-store", store_file(to_store), "store")],
                     [*inputs, ("--csv", csv_path)], force)  # may be --from-store
    if out_dir is not None:  # the folder itself: never a store or a file (the files in it: write_calibrations)
        refuse_overwrite([("--out-dir", out_dir, "directory")], [*inputs, *protected])
    for p in (csv_path,):
        if p is not None and not Path(p).resolve().parent.is_dir():
            raise DataError(f"--csv {p}: cannot write (no such directory {Path(p).parent})")
    return protected


def _limits(config_path: str | None) -> Limits | None:
    """The acceptance limits of a station config (--config), checked by the schema; None without one
    (then the schema, pydantic, is not even imported)."""
    if config_path is None:
        return None
    from ..acceptance.rules import Limits
    from ..config.checks import load_yaml

    return Limits.from_config(load_yaml(config_path).get("acceptance"))


def _fit_boards(paths: tuple[str, ...], from_store: str | None, store_filters: StoreFilters, model: str,
                units: str | None, cpg: float | None, grav: float | None, as_json: bool,
                limits: Limits | None = None) -> BatchReport:
    """Read the boards (store runs, then pose tables) and fit them all, with progress bars on a big batch."""
    from ..lot.batch import expand_paths, recalibrate, sessions_from_files, sessions_from_store
    from ..store.location import store_target
    from ..store.reader import StoreReader

    sources: list[Source] = []
    if from_store is not None:
        with StoreReader(store_target(from_store)) as st:  # read-only: never stamped or migrated
            if st.notice:
                click.echo(error_text(st.notice), err=True)
            sources += sessions_from_store(st, **store_filters)
    files = expand_paths(paths)
    show = not as_json and len(files) + len(sources) > PROGRESS_MIN_BOARDS
    with _bar(show and len(files) > PROGRESS_MIN_BOARDS, len(files), "reading pose tables") as bar:
        sources += sessions_from_files(files, units, cpg, grav, model, progress=bar.update)
    if not sources:
        raise DataError(f"{from_store}: no complete runs with poses match the filters")
    with _bar(show, len(sources), f"fitting model {model}") as bar:
        return recalibrate(sources, model, progress=bar.update, limits=limits)


def _write_outputs(report: BatchReport, out_dir: str | None, csv_path: str | None, to_store: str | None,
                   from_store: str | None, config_path: str | None = None, force: bool = False,
                   protected: Sequence[Named] = ()) -> tuple[BatchOutputs, dict[str, Path]]:
    """Write the calibrations, the summary CSV and the store records asked for: (what was written
    where, the calibration file of each board source)."""
    from ..lot.batch import record_in_store, summary_csv, write_calibrations
    from ..store.location import store_target
    from ..store.runs import Store

    outputs: BatchOutputs = {}
    written: dict[str, Path] = {}
    if out_dir is not None:
        written = write_calibrations(report, out_dir, force, protected)
        outputs["out_dir"], outputs["calibrations"] = str(out_dir), len(written)
    if csv_path is not None:
        summary_csv(report, csv_path)
        outputs["csv"] = str(csv_path)
    if to_store is not None:
        with Store(store_target(to_store)) as st:
            config_text = None if config_path is None else Path(config_path).read_text(encoding="utf-8")
            counts = record_in_store(report, st, source_store=from_store, config_text=config_text)
            outputs["store"] = {"path": str(to_store), "events": counts["events"], "runs": counts["runs"]}
    return outputs, written


def _print_report(report: BatchReport, outputs: BatchOutputs, written: dict[str, Path], as_json: bool) -> None:
    """The report on stdout: one JSON object, or the human lines."""
    if as_json:
        doc = report.to_dict()
        doc["outputs"] = outputs
        for d in doc["results"]:
            d["file"] = str(written[d["source"]]) if d["source"] in written else None
        click.echo(json.dumps(_clean(doc), allow_nan=False))
    else:
        click.echo("\n".join(_text(report, outputs, list_all=not outputs)))

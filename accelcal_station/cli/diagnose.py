"""`accelcal diagnose`: find the sim-to-real gap, the catalog effect behind it, and how far it shrinks."""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from ..api import diagnose
from ..data.log_time import check_rate
from ..diagnosis.figures import REPORT_FILES, check_report_dir, write_report
from ..diagnosis.report import selftest_lines, summary_lines
from ..diagnosis.request import DiagnoseRequest
from ..diagnosis.selftest import selftest as run_selftest
from ..errors import DataError
from ._common import MAX_SEED, Whole, parse_int
from ._common import jsonable as _clean
from ._common import parse_number as _number
from ._outputs import refuse_output
from ._text import clean

_REPORT_KIND = {".md": "markdown", ".png": "png"}  # what each report file is (fileguard.kind)


def _selftest(files: tuple[str, ...], report_dir: str | None, config: str | None, seed: int, as_json: bool) -> bool:
    """--selftest: the diagnosis on forward-physics boards it simulates itself; True when it passed."""
    if files or report_dir:
        raise DataError("--selftest simulates its own data; give no FILES and no --report with it")
    result = run_selftest(config, seed)
    click.echo(json.dumps(_clean(result), allow_nan=False) if as_json else "\n".join(selftest_lines(result)))
    return bool(result["passed"])


@click.command("diagnose")
@click.argument("files", nargs=-1, metavar="FILES...")
@click.option("--config", default=None, metavar="FILE",
              help="Station YAML whose simulated device is supposed to describe the boards (default configs/sim.yaml).")
@click.option("--raw", is_flag=True, help="FILES are raw sample logs: find their static poses automatically.")
@click.option("--units", default=None, metavar="counts|g|mps2", help="Units of the readings (default: the file's).")
@click.option("--counts-per-g", "counts_per_g", default=None, metavar="N",
              help="Counts per g of the data (default: the file's, else estimated from the readings' norm).")
@click.option("--gravity", default=None, metavar="M_S2",
              help="The site's gravity in m/s^2 (default: the file's '# gravity_mps2:' line, else standard): "
                   "references scaled to it.")
@click.option("--columns", default=None, metavar="NAMES", help="Raw log columns, e.g. t,x,y,z or -,-,x,y,z.")
@click.option("--skip-rows", default=None, metavar="N", help="Raw log: lines to skip at the top.")
@click.option("--rate", default=None, metavar="HZ",
              help="Sample rate in Hz: of a raw log without a time column, or of the samples behind a pose table's "
                   "std (default: the simulator's ODR); it sets the simulated noise bandwidth.")
@click.option("--samples", default=None, metavar="N",
              help="Samples averaged per pose, when the data do not say (default 1: a per-sample floor).")
@click.option("--norm-only", is_flag=True, help="Ignore references: analyse the norm of the readings only.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of the summary.")
@click.option("--report", "report_dir", default=None, metavar="DIR",
              help="Write PNG figures and summary.md to DIR (needs matplotlib: the report extra).")
@click.option("--selftest", is_flag=True,
              help="Forward-physics boards with each catalog effect withheld from the configuration, "
                   "off-catalog effects, two-effect cases and null boards: check what the diagnosis names "
                   "(exit 1 if a case fails).")
@click.option("--seed", type=Whole(0, MAX_SEED), default=1, show_default=True, help="Self-test seed.")
@click.pass_context
def command(ctx: click.Context, **opts: Any) -> None:
    """Diagnose the sim-to-real gap of real data against the simulator configuration."""
    if not _diagnose_cmd(DiagnoseCommand.from_click(opts)):
        ctx.exit(1)


@dataclass(frozen=True)
class DiagnoseCommand:
    """`accelcal diagnose`'s options as typed: the numbers still as given (parsed by ``request``)."""

    files: tuple[str, ...]
    config: str | None
    raw: bool
    units: str | None
    counts_per_g: str | None
    gravity: str | None
    columns: str | None
    skip_rows: str | None
    rate: str | None
    samples: str | None
    norm_only: bool
    as_json: bool
    report_dir: str | None
    selftest: bool
    seed: int

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> DiagnoseCommand:
        return cls(files=o["files"], config=o["config"], raw=o["raw"], units=o["units"],
                   counts_per_g=o["counts_per_g"], gravity=o["gravity"], columns=o["columns"],
                   skip_rows=o["skip_rows"], rate=o["rate"], samples=o["samples"], norm_only=o["norm_only"],
                   as_json=o["as_json"], report_dir=o["report_dir"], selftest=o["selftest"], seed=o["seed"])

    def request(self) -> DiagnoseRequest:
        """The library's request; a bad number refused naming its option."""
        rate_hz = _number(self.rate, "--rate")
        check_rate(rate_hz)
        return DiagnoseRequest(
            files=self.files, config=self.config, raw=self.raw, units=self.units,
            counts_per_g=_number(self.counts_per_g, "--counts-per-g"), gravity_mps2=_number(self.gravity, "--gravity"),
            columns=self.columns, skip_rows=parse_int(self.skip_rows, "--skip-rows", positive=False),
            rate_hz=rate_hz, samples=parse_int(self.samples, "--samples"), norm_only=self.norm_only)


def _diagnose_cmd(o: DiagnoseCommand) -> bool:
    """The command; False when the self-test failed (exit 1)."""
    if o.selftest:
        return _selftest(o.files, o.report_dir, o.config, o.seed, o.as_json)
    out_dir = check_report_dir(o.report_dir) if o.report_dir else None
    if out_dir is not None:
        refuse_output([("--report file", out_dir / n, _REPORT_KIND[Path(n).suffix]) for n in REPORT_FILES],
                      [*(("FILE", f) for f in o.files), ("--config", o.config)], config=o.config)
    d = diagnose(o.request())
    js = _clean(d.to_json())
    if out_dir is not None:
        written = write_report(d, out_dir, js)
        js["report"] = [str(p) for p in written]
    if o.as_json:
        click.echo(json.dumps(js, allow_nan=False))
    else:
        lines = summary_lines(d)
        if out_dir is not None:
            lines.append(f"report: {out_dir}/summary.md and {len(js['report']) - 1} figures")
        click.echo("\n".join(clean(ln) for ln in "\n".join(lines).split("\n")))  # pose names from files
    return True

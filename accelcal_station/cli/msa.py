"""`accelcal report msa`: a Gage R&R study of the runs in the store, or the plan of one (docs/msa.md)."""
from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import click

from ..errors import DataError
from ..jsontypes import JsonValue
from ..lot.msa_study import PARAMETERS, analyse, build_study, plan, recent
from ..store.reader import StoreReader
from ..store.records import RunRecord
from ._common import Whole, force_option
from ._report_filters import RunFilters, RunSelection, filter_options, open_reader
from ._text import clean

CHUNK = 500  # run ids per query
METHOD = ("ANOVA, two-way crossed random effects with the part x appraiser interaction, pooled into "
          "repeatability when its p-value > 0.25 (AIAG MSA 4th ed.); average and range as a cross-check")


def _tolerances(items: tuple[str, ...]) -> dict[str, float]:
    """--tolerance PARAM=VALUE (in the parameter's unit, the full width USL - LSL)."""
    names = [p.name for p in PARAMETERS]
    out: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            value = float(text) if sep else math.nan
        except ValueError:
            value = math.nan
        if name not in names or not math.isfinite(value) or value <= 0:
            raise DataError(f"--tolerance {item!r}: PARAM=VALUE with VALUE > 0 (USL - LSL, in the parameter's "
                            f"unit); PARAM one of {', '.join(names)}")
        out[name] = value
    return out


def _cell(v: JsonValue, fmt: str) -> str:
    return "-" if v is None else format(v, fmt) if isinstance(v, int | float) else str(v)


def _print(doc: dict[str, JsonValue], results: list[dict[str, JsonValue]]) -> None:
    click.echo(clean(f"Gage R&R: {doc['boards']} parts x {doc['appraisers']} {doc['by']}s "
                     f"({', '.join(doc['appraiser_names'])}) x {doc['trials']} trials"  # type: ignore[arg-type]
                     f"; {doc['method']}"))
    click.echo(f"{'parameter':20} {'EV':>10} {'AV':>10} {'INT':>10} {'GRR':>10} {'PV':>10} {'%GRR':>7} "
               f"{'%tol':>7} {'ndc':>4}  band")
    for r in results:
        pooled = " (interaction pooled)" if r["interaction_pooled"] else ""
        click.echo(f"{r['parameter']!s:20} {_cell(r['ev'], '10.4g')} {_cell(r['av'], '10.4g')} "
                   f"{_cell(r['interaction'], '10.4g')} {_cell(r['grr'], '10.4g')} {_cell(r['pv'], '10.4g')} "
                   f"{_cell(r['pct_grr'], '7.2f')} {_cell(r['pct_tolerance'], '7.2f')} {_cell(r['ndc'], '4d')}  "
                   f"{r['grr_band'] or '-'}{'' if r['ndc_ok'] in (None, True) else ', ndc < 5'}{pooled}")


def _repeated(store: StoreReader, flt: RunFilters) -> tuple[list[RunRecord], int]:
    """Full records (poses and all) of the runs whose serial is in the listing more than once: the
    listing first, so a line's store of 100,000 runs does not load every run's poses; in chunks, so
    no query carries more ids than a database takes."""
    listing = store.list_runs(**flt)
    n = Counter(r["device_serial"] for r in listing if r["status"] == "complete")
    ids = [r["id"] for r in listing if r["id"] is not None and r["device_serial"] and n[r["device_serial"]] > 1]
    recs = [rec for k in range(0, len(ids), CHUNK) for rec in store.runs(**{**flt, "run_ids": ids[k:k + CHUNK]})]
    return recs, sum(1 for r in listing if r["status"] == "complete" and n[r["device_serial"]] == 1)


def _plan(store: StoreReader, by: str, p: StudyPlan, as_json: bool, flt: RunFilters) -> None:
    trials, seed = p.trials, p.seed
    serials, who = recent(store.list_runs(**flt), by, p.parts, p.appraisers)
    order = plan(serials, who, trials, seed)
    if as_json:
        click.echo(json.dumps({"parts": serials, "appraisers": who, "trials": trials, "seed": seed, "by": by,
                               "runs": order}, indent=1))
        return
    click.echo(clean(f"study plan: {len(serials)} parts x {len(who)} {by}s x {trials} trials, seed {seed}"))
    for step in order:
        click.echo(clean(f"{step['order']:4}  trial {step['trial']}  {step['appraiser']!s:16} {step['part']}"))


@click.command("msa")
@filter_options
@click.option("--by", type=click.Choice(["operator", "station"]), default="operator", show_default=True,
              help="Appraisers: the runs' operators, or their stations.")
@click.option("--tolerance", "tolerance", multiple=True, metavar="PARAM=VALUE",
              help="Tolerance width (USL - LSL) of a parameter, in its unit (repeatable); default: from the "
                   "runs' stored acceptance limits (2 x offset_max_mg for V_x, ...).")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@click.option("--html", "html_file", default=None, metavar="FILE",
              help="Also write the report with its charts (by part, by appraiser, range chart) as one HTML "
                   "file (needs the report extra).")
@click.option("--plan", "plan_only", is_flag=True,
              help="Print a study plan instead: which boards to rerun by whom, in a random order.")
@click.option("--parts", default=10, show_default=True, type=Whole(2, 1000), help="With --plan: parts.")
@click.option("--appraisers", default=3, show_default=True, type=Whole(2, 100), help="With --plan: appraisers.")
@click.option("--trials", default=3, show_default=True, type=Whole(2, 100), help="With --plan: trials.")
@click.option("--seed", default=1, show_default=True, type=Whole(0, 2**31 - 1), help="With --plan: the "
              "random order's seed.")
@force_option
def msa_command(**opts: Any) -> None:
    """Gage R&R study (AIAG MSA 4th ed.) of the repeated boards in the store, per calibration parameter."""
    _msa(MsaOptions.from_click(opts))


@dataclass(frozen=True)
class StudyPlan:
    """--plan: the study's size and the seed of its random order."""

    parts: int
    appraisers: int
    trials: int
    seed: int


@dataclass(frozen=True)
class MsaOptions:
    """`report msa`'s options: the runs, the appraisers (``by``), the tolerances, the outputs, the plan."""

    selection: RunSelection
    by: str
    tolerance: tuple[str, ...]
    as_json: bool
    html_file: str | None
    plan_only: bool
    plan: StudyPlan
    force: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> MsaOptions:
        return cls(selection=RunSelection.from_click(o), by=o["by"], tolerance=o["tolerance"], as_json=o["as_json"],
                   html_file=o["html_file"], plan_only=o["plan_only"], force=o["force"],
                   plan=StudyPlan(parts=o["parts"], appraisers=o["appraisers"], trials=o["trials"], seed=o["seed"]))


def _msa(o: MsaOptions) -> None:
    by, as_json, html_file = o.by, o.as_json, o.html_file
    tols = _tolerances(o.tolerance)
    flt = o.selection.filters(status="complete")
    output = ("--html", html_file, "html") if html_file is not None else None
    with open_reader(o.selection.db, o.selection.config_path, output, o.force) as store:  # read-only
        if o.plan_only:
            _plan(store, by, o.plan, as_json, flt)
            return
        recs, once = _repeated(store, flt)
        study = build_study(recs, by, left_out=once)
    results = analyse(study, tols)
    if html_file is not None:
        from ..lot.msa_report import write_msa_html

        write_msa_html(study, results, html_file)
        click.echo(f"Gage R&R report written to {html_file}", err=True)
    doc: dict[str, JsonValue] = {"method": METHOD, "by": by, "boards": len(study.parts),
                                 "appraisers": len(study.appraisers), "trials": study.trials,
                                 "parts": list(study.parts), "appraiser_names": list(study.appraisers),
                                 "excluded_runs": dict(study.excluded), "unbalanced_rule": "refused",
                                 "results": results}  # type: ignore[dict-item]
    if as_json:
        click.echo(json.dumps(doc, indent=1))
    else:
        _print(doc, results)

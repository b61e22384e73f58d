"""`accelcal twin fit | check | whatif`: the population twin of a lot (accelcal_station/twin/)."""
from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import click
import yaml

from ..acceptance.rules import Limits
from ..atomic import atomic_write
from ..config.sections import default_config_path
from ..errors import DataError
from ._common import Whole, force_option
from ._mes import JsonGroup
from ._outputs import refuse_output
from ._text import error_text

if TYPE_CHECKING:  # twin/ is imported on first use (scipy): its records for the checker only
    from ..twin.records import Before, CheckReport, QuantityTest, TwinFitReport, WhatIfReport
    from ..twin.stream import LotStats

F = TypeVar("F", bound=Callable[..., object])


def _emit(as_json: bool, data: TwinFitReport | CheckReport | WhatIfReport, lines: list[str]) -> None:
    click.echo(json.dumps(data, default=float) if as_json else "\n".join(lines))


@click.group("twin", cls=JsonGroup)
def command() -> None:
    """The population twin: fit a lot's population, check it against the lot, predict yield."""


def _stats(source: str | None, db: str | None, since: str | None, station: str | None,
           limits: Limits | None) -> tuple[LotStats, float | None]:
    """A lot file, or with --db the store's complete runs (--since, --station)."""
    from ..twin.fit import lot_stats  # twin/ on first use: it brings scipy (tens of MB) to every command
    from ..twin.store_source import store_stats
    if (source is None) == (db is None):
        raise DataError("give a lot file (SOURCE) or --db FILE|URL, one of them")
    if db is None and (since or station):
        raise DataError("--since and --station filter a store's runs; add --db FILE|URL")
    if db is not None:
        skips: list[tuple[str, str]] = []
        try:
            return store_stats(db, limits, skips=skips, since=since, station=station)
        finally:  # named even when no run is left to fit (stderr: stdout may be the JSON object)
            for label, why in skips:
                click.echo(click.style("SKIP ", fg="red", bold=True) + error_text(f"{label}: {why}"), err=True)
    assert source is not None
    return lot_stats(source, limits)


def _source_options(f: F) -> F:
    f = click.option("--station", default=None, help="--db: only runs of this station.")(f)
    f = click.option("--since", default=None, help="--db: only runs started at or after (ISO 8601).")(f)
    f = click.option("--db", "db", default=None, help="A results store (file, sqlite:///FILE, postgresql://...) "
                     "instead of a lot file.")(f)
    return click.argument("source", required=False, type=click.Path(dir_okay=False))(f)


@command.command("fit")
@_source_options
@click.option("-o", "--out", "out", required=True, type=click.Path(dir_okay=False), help="Twin config YAML to write.")
@click.option("--components", type=Whole(1, 8), default=4, show_default=True,
              help="Most mixture components BIC may choose.")
@click.option("--json", "as_json", is_flag=True, help="Print what was found as JSON.")
@force_option
def fit_cmd(source: str | None, db: str | None, since: str | None, station: str | None, out: str, components: int,
            as_json: bool, force: bool = False) -> None:
    """Fit the population of lot file SOURCE (or --db); write the default config with population: replaced."""
    refuse_output([("-o", out, "yaml")], [("SOURCE", source)], force, has_config=False, stores=[("--db", db)])
    if not Path(out).resolve().parent.is_dir():
        raise DataError(f"{out}: cannot write (no such directory {Path(out).parent})")
    from ..twin.fit import fit_twin

    stats, per_g = _stats(source, db, since, station, None)
    source = source or db
    tw = fit_twin(stats, per_g, max_components=components)
    atomic_write(out, "# twin of " + str(source) + " (accelcal twin fit)\n"
                      + yaml.safe_dump(tw.config, sort_keys=False))
    d: TwinFitReport = {**tw.to_dict(), "out": out}
    lines = [f"{source}: {stats.boards} boards, model {stats.model}; {len(d['components'])} component(s) by BIC"]
    lines += [f"  weight {c['weight']:.4f}" + (f", carries {', '.join(c['carries'])}" if c["carries"] else "")
              for c in d["components"]]
    lines += [f"  {ch['kind']} in {ch['quantity']} at board {ch['at_board']} "
              f"({ch['interval'][0]}-{ch['interval'][1]}), size {ch['size']:.4g}" for ch in d["changes"]]
    n = d["noise"]
    if n:
        lines.append("noise per axis from the lot's residual and leave-one-out RMS: "
                     + ", ".join(f"{v:.4g}" for v in n["fitted_sd_counts"]) + " counts per sample (stated "
                     + ", ".join(f"{v:.4g}" for v in n["stated_sd_counts"]) + ")")
    lines.append(f"wrote {out}")
    for w in tw.warnings:  # on stderr whatever the output format; in --json also under warnings
        click.echo(f"warning: {w}", err=True)
    _emit(as_json, d, lines)


@command.command("check")
@_source_options
@click.option("--config", "config", required=True, type=click.Path(dir_okay=False), help="Twin config to check.")
@click.option("--before", "before", type=click.Path(dir_okay=False), default=None,
              help="Config for the gap before (default: the default simulator config).")
@click.option("--seed", type=Whole(0, None), default=None,
              help="Seed of the simulated lot (default: drawn at random; recorded in the output).")
@click.option("--json", "as_json", is_flag=True, help="Print every test as JSON.")
def check_cmd(source: str | None, db: str | None, since: str | None, station: str | None, config: str,
              before: str | None, seed: int | None, as_json: bool) -> None:
    """Simulate a lot like SOURCE from --config and test it against SOURCE, quantity by quantity."""
    from ..twin.check import check
    from ..twin.simlot import twin_device

    after = twin_device(config)  # each config read once, typed (simlot.TwinDevice)
    stats, _ = _stats(source, db, since, station, after.limits)
    source = source or db
    r = check(stats, after, twin_device(before or str(default_config_path())), seed, after.limits)
    lines = [f"{source}: {stats.boards} boards; seed {r['seed']}; {r['method']}",
             _verdict_line(f"before ({r['before']['config']})", r["before"]), _verdict_line(f"after ({config})", r)]
    lines += [f"  {_effect_line(t)}" for t in r["tests"] if t["detected"]]
    _emit(as_json, r, lines)


def _verdict_line(what: str, r: Before | CheckReport) -> str:
    quiet = [q for q in r["detected"] if q not in r["gaps"]]
    return (f"{what}: {r['verdict']}" + (f"; matters in {', '.join(r['gaps'])}" if r["gaps"] else "")
            + (f"; detectable but immaterial in {', '.join(quiet)}" if quiet else ""))


def _effect_line(t: QuantityTest) -> str:
    e = t["effect"]
    largest = e.get("largest")
    size = (f"Wasserstein {e['wasserstein']:.4g}, p95 shift {e['shift_p95']:.4g}" if "wasserstein" in e
            else f"largest share change {e['share_change'][largest]:+.4f} ({largest})" if largest
            else f"energy distance {e.get('energy_distance', 0.0):.4g}")
    lim = f", yield change at {e['limit']} {e['yield_change']:+.4f}" if "limit" in e else ""
    return (f"{t['quantity']}: p {t['p_value']:.2g}; {size}{lim}; "
            f"{'matters' if t['gap'] else 'immaterial'} ({e.get('margin', '')})")


@command.command("whatif")
@_source_options
@click.option("--config", "config", required=True, type=click.Path(dir_okay=False), help="Twin config.")
@click.option("--limit", "limits", multiple=True, help="NAME=VALUE: an acceptance limit changed (repeatable).")
@click.option("--boards", type=Whole(100, 10**6), default=20_000, show_default=True,
              help="Boards to simulate.")
@click.option("--seed", type=Whole(0, None), default=None,
              help="Seed of the simulated lot (default: drawn at random; recorded in the output).")
@click.option("--json", "as_json", is_flag=True, help="Print the prediction as JSON.")
def whatif_cmd(source: str | None, db: str | None, since: str | None, station: str | None, config: str,
               limits: tuple[str, ...], boards: int, seed: int | None, as_json: bool) -> None:
    """Predicted yield of a lot like SOURCE under changed acceptance limits, with an interval that
    carries the twin's own doubt; compared with SOURCE's own yield under those limits."""
    from ..twin.simlot import twin_device
    from ..twin.whatif import parse_limits, whatif

    device = twin_device(config)  # read once, typed (simlot.TwinDevice)
    lim = parse_limits(limits, device.limits)
    stats, _ = _stats(source, db, since, station, lim)
    r = whatif(device, stats, lim, boards, seed, real_yield=stats.verdicts.get("PASS", 0) / max(stats.boards, 1))
    y, f = r["first_pass_yield"], r["failures"]
    lines = [f"first-pass yield {y['value']:.4f} (interval {y['interval'][0]:.4f}-{y['interval'][1]:.4f}, "
             f"parameter sd {y['parameter_sd']:.4f}); now {r['yield_now']:.4f}; after one retest "
             f"{r['yield_after_one_retest']['value']:.4f}; seed {r['seed']}",
             f"failures: noise-like {f['noise_like']:.4f} (a retest recovers them), systematic {f['systematic']:.4f}",
             f"the real lot under these limits: {r['real_yield']:.4f}"]
    lines += [f"  {g['reason']}: {g['before']:.4f} -> {g['after']:.4f}" for g in r["reasons_grow"]]
    for w in r["warnings"]:
        click.echo(f"warning: {w}", err=True)
    _emit(as_json, r, lines)

"""The options that choose runs in the results store, shared by `accelcal report`'s subcommands and
`report msa`: the filters, the store they read (--db, else --config's, else the default station's)."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict, TypeVar

import click

from ..config.checks import load_yaml
from ..errors import DataError
from ..store.liveness import STALE
from ..store.location import store_path, store_target
from ..store.reader import StoreReader
from ..store.schema import STATUSES, VERDICTS
from ._outputs import refuse_output
from ._text import clean

F = TypeVar("F", bound=Callable[..., Any])


def filter_options(f: F) -> F:
    """The options that choose runs (and the store they are in)."""
    opts = [
        click.option("--db", default=None, metavar="FILE|URL",
                     help="Results store: an SQLite file, sqlite:///FILE or postgresql://USER@HOST/DB; default: "
                          "the store of --config or of the default station."),
        click.option("--config", "config_path", default=None, metavar="FILE",
                     help="Station config naming the store (store.path)."),
        click.option("--device", multiple=True, metavar="SERIAL", help="Only these device serials (repeatable)."),
        click.option("--lot", default=None, metavar="LOT", help="Only this lot."),
        click.option("--station", default=None, metavar="ID", help="Only this station."),
        click.option("--operator", default=None, metavar="NAME", help="Only this operator."),
        click.option("--verdict", default=None, metavar="PASS|FAIL", help="Only this verdict."),
        click.option("--status", default=None, metavar="|".join((*STATUSES, STALE)),
                     help="Only this run status (stale: running, its station process gone)."),
        click.option("--since", default=None, metavar="TIME", help="Started at or after (ISO 8601; naive = local)."),
        click.option("--until", default=None, metavar="TIME", help="Started before (ISO 8601; naive = local)."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def store_target_of(db: str | None, config_path: str | None) -> tuple[Path | str, str | None]:
    """--db, else the store of --config, else that of the default station (as `accelcal run`);
    `accelcal report --db F SUBCOMMAND` gives the subcommand that store too.  Returns the store
    target and the config file read (None when --db named the store)."""
    ctx = click.get_current_context(silent=True)
    group = ctx.parent.params if ctx is not None and ctx.parent is not None else {}
    db = db if db is not None else group.get("db")
    config_path = config_path if config_path is not None else group.get("config_path")
    if db is not None:
        return store_target(db), None
    from ..config.sections import default_config_path

    # relative store paths are taken from the current directory, as `accelcal run` does
    cfg = str(config_path or default_config_path())
    return store_path(load_yaml(cfg), Path.cwd()), cfg


class RunFilters(TypedDict):
    """The filter options as the store's query keywords (None: not filtered)."""

    device: list[str] | None
    lot: str | None
    station: str | None
    operator: str | None
    verdict: str | None
    status: str | None
    since: str | None
    until: str | None


def run_filters(device: tuple[str, ...], lot: str | None, station: str | None, operator: str | None,
             verdict: str | None, status: str | None, since: str | None, until: str | None) -> RunFilters:
    """The filter options as keyword arguments of the store's queries; a bad verdict or status refused."""
    if verdict is not None and verdict.upper() not in VERDICTS:
        raise DataError(f"--verdict {verdict!r}; allowed: PASS, FAIL")
    if status is not None and status not in (*STATUSES, STALE):
        raise DataError(f"--status {status!r}; allowed: {', '.join((*STATUSES, STALE))}")
    return {"device": list(device) or None, "lot": lot, "station": station, "operator": operator,
            "verdict": verdict and verdict.upper(), "status": status, "since": since, "until": until}


@dataclass(frozen=True)
class RunSelection:
    """The options ``filter_options`` adds, as given: the store (``db``, else ``config_path``'s) and the
    filters that choose its runs."""

    db: str | None
    config_path: str | None
    device: tuple[str, ...]
    lot: str | None
    station: str | None
    operator: str | None
    verdict: str | None
    status: str | None
    since: str | None
    until: str | None

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> RunSelection:
        return cls(db=o["db"], config_path=o["config_path"], device=o["device"], lot=o["lot"], station=o["station"],
                   operator=o["operator"], verdict=o["verdict"], status=o["status"], since=o["since"],
                   until=o["until"])

    def filters(self, status: str | None = None) -> RunFilters:
        """The store's query keywords (``status``: the default when --status is not given)."""
        return run_filters(self.device, self.lot, self.station, self.operator, self.verdict, self.status or status,
                           self.since, self.until)


def open_reader(db: str | None, config_path: str | None, output: tuple[str, str | None, str] | None = None,
          force: bool = False) -> StoreReader:
    """The store to read, read-only (never stamped or migrated: `report migrate` does that); a store
    without its schema revision is named in one line on stderr.  ``output`` (its option, its file),
    when given, is refused first if it is the store's own file, the config's or the config's store
    (nothing written)."""
    target, cfg = store_target_of(db, config_path)
    if output is not None:  # the store read, and the --config's store even when --db names another
        ctx = click.get_current_context(silent=True)
        group = ctx.parent.params if ctx is not None and ctx.parent is not None else {}
        given = config_path if config_path is not None else group.get("config_path")
        refuse_output([output], [("--config", cfg or given)], force, config=cfg or given,
                      stores=[("the store", target)])
    reader = StoreReader(target)
    if reader.notice:
        click.echo(clean(reader.notice), err=True)
    return reader

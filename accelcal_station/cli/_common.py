"""Helpers shared by the commands (the leading underscore keeps this module from being
registered as a command)."""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import click
import numpy as np

from ..calibration import MODELS
from ..conventions import check_units
from ..errors import AccelcalError, DataError, UnitsError
from ..fileguard.numbers import ALLOWED, is_decimal

MAX_SEED = 2**128 - 1  # numpy's SeedSequence takes any; the seeds the station prints are at most 128-bit
MAX_ID = 2**63 - 1  # a run id is a 64-bit integer in every store


class Finite(click.FloatRange):
    """A float option that is finite and within [lo, hi] (click's FloatRange lets NaN through, and
    infinity when a bound is open): the one number type of every float option."""

    name = "finite number"

    def __init__(self, lo: float, hi: float) -> None:
        super().__init__(lo, hi)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and math.isfinite(_loose(value)) and not is_decimal(value):
            self.fail(f"{value!r}; allowed: {ALLOWED}", param, ctx)
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            bounded = self.min is not None and self.max is not None and math.isfinite(self.min) and \
                math.isfinite(self.max)
            allowed = f"{self.min:g} to {self.max:g}" if bounded else "a finite number"
            self.fail(f"{value!r} is not a finite number; allowed: {allowed}", param, ctx)
        return v


class Whole(click.IntRange):
    """A whole-number option within [lo, hi] (never unbounded: a count becomes an allocation), in
    ASCII digits (int() also takes '4_096' and other scripts' digits)."""

    def __init__(self, lo: int, hi: int | None) -> None:
        super().__init__(lo, hi)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not _WHOLE.fullmatch(value):
            most = f"{self.min} to {self.max}" if self.max is not None else f"{self.min} or more"
            self.fail(f"{value!r}; allowed: a whole number in ASCII digits, {most}", param, ctx)
        return super().convert(value, param, ctx)


_WHOLE = re.compile(r"\s*[+-]?\d+\s*", re.ASCII)


def _loose(value: str) -> float:
    """float(value) as Python reads it (NaN when it cannot): what a stricter check then refuses."""
    try:
        return float(value)
    except ValueError:
        return math.nan


def parse_number(value: str | None, flag: str, positive: bool = True) -> float | None:
    """Parse a numeric option ourselves so a typo is one line, not a usage screen."""
    return None if value is None else _parse(value, flag, False, positive)


def parse_int(value: str | None, flag: str, positive: bool = True) -> int | None:
    """A whole-number option, with the same one-line refusal."""
    return None if value is None else int(_parse(value, flag, True, positive))


# The largest value each option parsed here takes, and why: beyond it a value is a typo or an attack.
OPTION_MAX = {
    "--counts-per-g": 1e9,  # the most sensitive accelerometer has some 1e6 counts per g
    "--gravity": 1e3,  # m/s^2: a centrifuge at 100 g
    "--skip-rows": 1e9,  # more lines than any log the readers take
    "--samples": 1e7,  # samples per pose, as `simulate --samples`
    "--chunk-boards": 1e6,  # boards held in memory at once (a chunk of 8 poses is ~1 GB there)
    "--run": float(MAX_ID),
}


def _parse(value: str, flag: str, integer: bool, positive: bool) -> float:
    try:
        if not (_WHOLE.fullmatch(value) if integer else is_decimal(value)):
            raise ValueError(value)  # '4_096', another script's digits: refused below (fileguard.numbers)
        v = float(int(value)) if integer else float(value)
    except (ValueError, OverflowError):
        v = math.nan
    hi = OPTION_MAX.get(flag, math.inf)
    if not math.isfinite(v) or (v <= 0 if positive else v < 0) or v > hi:
        kind = "whole number" if integer else "number"
        most = f" up to {hi:g}" if math.isfinite(hi) else ""
        raise DataError(f"{flag} {value!r}; allowed: a {'positive' if positive else 'non-negative'} {kind}{most}")
    return v


FORCE_HELP = ("Replace an existing output file of another kind, or an SQLite database that is no store this "
              "command reaches (never its --db, its --config's store, the default store or an input it reads).")


def force_option(f: Any) -> Any:
    """``--force``: the kind check of fileguard.kind.refuse_kind overridden (the identity check never is)."""
    return click.option("--force", "force", is_flag=True, help=FORCE_HELP)(f)


def output_kind(path: str | Path | None, default: str = "csv") -> str:
    """The kind of file an output writes, by its extension (fileguard.kind.COMPATIBLE)."""
    suffix = Path(str(path or "")).suffix.lower()
    return {".json": "json", ".jsonl": "jsonl", ".ndjson": "jsonl", ".parquet": "parquet", ".pq": "parquet",
            ".csv": "csv", ".yaml": "yaml", ".yml": "yaml", ".html": "html", ".htm": "html",
            ".png": "png"}.get(suffix, default)


def store_file(target: str | Path | None) -> Path | None:
    """The file of an SQLite store (a path or ``sqlite:///PATH``), to compare outputs with; None for a
    server URL (postgresql://...: no local file an output could overwrite)."""
    if target is None:
        return None
    t = str(target)
    if t.startswith("sqlite:///"):
        return Path(t[len("sqlite:///"):])
    return None if "://" in t else Path(t)


def config_store_file(config_path: str | Path | None) -> Path | None:
    """The SQLite store file a station config (default: the default station's) records into, so that
    no output replaces it; None when the config cannot say (reading it reports why, later)."""
    from ..config.checks import load_yaml
    from ..config.default_config import default_config_path

    try:
        config = load_yaml(config_path or default_config_path())
        section = config.get("store")
        if isinstance(section, dict) and set(section) == {"path"} and isinstance(section["path"], str) \
                and section["path"].strip():  # a bare path (sim.yaml's): the schema would take it as it is
            path = section["path"]
            return store_file(path if "://" in path else Path.cwd() / Path(path).expanduser())
        from ..store.location import store_path  # through the schema (pydantic: ~0.3 s to import)

        return store_file(store_path(config, Path.cwd()))
    except AccelcalError:
        return None


def jsonable(o: Any) -> Any:
    """JSON-safe: numpy to Python, non-finite floats to null (never NaN in output)."""
    if isinstance(o, dict):
        return {k: jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return jsonable(o.tolist())
    if isinstance(o, (np.floating, float)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    return o


def check_model_units(model: str, units: str | None) -> None:
    """--model and --units as one line each when wrong."""
    if model not in MODELS:
        raise DataError(f"--model {model!r}; allowed: {', '.join(MODELS)}")
    if units is not None:
        try:
            check_units(units)
        except UnitsError as e:
            raise UnitsError(f"--units: {e}") from None

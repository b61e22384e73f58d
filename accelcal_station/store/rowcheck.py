"""Every stored row checked before it is used: types, ranges, JSON depth and size.

A store can be damaged (a disk error, a hand edit, another program, a fuzzer): an SQLite
column holds any type whatever its declaration, a PostgreSQL DOUBLE holds NaN and 1e300,
and a JSON text can be nested deep enough to exhaust the parser's recursion.  ``check_row``
turns one row into a ``CheckedRow`` (JSON columns parsed; a bad value replaced by None; its
values read typed, ``text``/``int``/``real``/``json``) and the list of what is wrong, as typed
``DamagedRow`` reasons (code ``damaged_row``); the listing shows them and ``accelcal report
check`` lists them, never an exception.

Limits: JSON nested at most JSON_MAX_DEPTH (64) levels, measured by a scanner that counts
brackets outside strings before the recursive parser runs (the station's deepest document,
a calibration with its temperature table, is 4 levels); a text or JSON value at most
TEXT_MAX_CHARS (16 Mi characters; a fit summary of 10,000 poses is about 2 MB); a time
between year 1 and the end of year 9999 (what ISO 8601 and ``datetime`` can say); NaN and
infinities refused in every number.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import ClassVar

import numpy as np

from ..acceptance.reasons import Reason
from ..calibration import Calibration, param_vector
from ..errors import DataError
from ..jsontypes import JsonObject, JsonValue
from .celltext import BadText
from .schema import STATUSES, VERDICTS

JSON_MAX_DEPTH = 64
TEXT_MAX_CHARS = 16 * 2**20
T_MIN_S, T_MAX_S = -62135596800.0, 253402300799.0  # 0001-01-01T00:00:00Z .. 9999-12-31T23:59:59Z
_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)


@dataclass(frozen=True)
class DamagedRow:
    """One bad value of one stored row: ``table``, the row's ``row_id`` (``run/idx`` for a
    pose), the ``column`` and what is wrong with it."""

    table: str
    row_id: str
    column: str
    problem: str
    code: ClassVar[str] = "damaged_row"

    def reason(self) -> Reason:
        return Reason.of(self.code, str(self))

    def __str__(self) -> str:
        return f"{self.table} {self.row_id} {self.column}: {self.problem}"

    def to_dict(self) -> dict[str, str]:
        """code, table, id, column, problem."""
        return {"code": self.code, "table": self.table, "id": self.row_id, "column": self.column,
                "problem": self.problem}


def json_depth(text: str) -> int:
    """The deepest nesting of ``[``/``{`` outside strings (the running sum of opens minus closes)."""
    b = np.frombuffer(_STRINGS.sub("", text).encode("utf-8", "replace"), dtype=np.uint8)
    step = (b == ord("[")).astype(np.int64) + (b == ord("{")) - (b == ord("]")) - (b == ord("}"))
    return int(np.cumsum(step).max()) if len(step) else 0


def _finite_float(s: str) -> float:
    v = float(s)
    if not math.isfinite(v):
        raise ValueError(f"number {s[:20]} out of range")
    return v


def _no_constant(s: str) -> float:
    raise ValueError(f"{s} is not a number JSON allows")


def parse_json(value: object) -> JsonValue:
    """A JSON column's value; ValueError saying what is wrong (type, size, depth, syntax)."""
    if not isinstance(value, str):
        raise ValueError(f"{type(value).__name__} where JSON text belongs")
    if len(value) > TEXT_MAX_CHARS:
        raise ValueError(f"JSON of {len(value)} characters; allowed at most {TEXT_MAX_CHARS}")
    depth = json_depth(value)
    if depth > JSON_MAX_DEPTH:
        raise ValueError(f"JSON nested {depth} levels; allowed at most {JSON_MAX_DEPTH}")
    try:
        return json.loads(value, parse_float=_finite_float, parse_constant=_no_constant)
    except RecursionError:  # cannot happen below the depth limit; kept as a damaged value if it did
        raise ValueError("JSON too deeply nested") from None
    except ValueError as e:
        raise ValueError(f"not JSON ({str(e)[:80]})") from None


Check = Callable[[object], object]  # a column's checker: the clean value, or ValueError saying what is wrong


def _type_name(v: object) -> str:
    return type(v).__name__


def _int(lo: int, hi: int) -> Check:
    def check(v: object) -> int:
        if not isinstance(v, int) or isinstance(v, bool):
            raise ValueError(f"{_type_name(v)} where an integer belongs")
        if not lo <= v <= hi:
            raise ValueError(f"{v} outside {lo}..{hi}")
        return v
    return check


def _real(lo: float = -math.inf, hi: float = math.inf) -> Check:
    def check(v: object) -> float:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise ValueError(f"{_type_name(v)} where a number belongs")
        if not (math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{v!r} outside {lo:g}..{hi:g}" if math.isfinite(v) else f"{v!r} is not finite")
        return float(v)
    return check


def _time(v: object) -> object:
    try:
        return _real(T_MIN_S, T_MAX_S)(v)
    except ValueError as e:
        raise ValueError(f"time {e}; allowed years 1..9999 as unix seconds") from None


def _text(v: object) -> str:
    if not isinstance(v, str):
        raise ValueError(f"{_type_name(v)} where text belongs")
    if len(v) > TEXT_MAX_CHARS:
        raise ValueError(f"text of {len(v)} characters; allowed at most {TEXT_MAX_CHARS}")
    return v


def _choice(allowed: tuple[str, ...]) -> Check:
    def check(v: object) -> object:
        if v not in allowed:
            raise ValueError(f"{str(v)[:40]!r}; allowed: {', '.join(allowed)}")
        return v
    return check


def _json_of(kind: type, check: Callable[[JsonValue], None] | None = None) -> Check:
    def parse(v: object) -> JsonValue:
        value = parse_json(v)
        if not isinstance(value, kind):
            raise ValueError(f"JSON {_type_name(value)} where a JSON {kind.__name__} belongs")
        if check is not None:
            check(value)
        return value
    return parse


def _reasons(value: JsonValue) -> None:
    for x in value if isinstance(value, list) else ():
        if not (isinstance(x, str) or (isinstance(x, dict) and all(isinstance(x.get(k, ""), str)
                                                                  for k in ("code", "message")))):
            raise ValueError("a reason that is neither text nor {code, message}")


def _calibration(value: JsonValue) -> None:
    if not isinstance(value, dict):
        raise ValueError("not a calibration (not an object)")
    try:
        Calibration.from_dict(value, "stored calibration")
        ok = param_vector(value).shape == (15,) and bool(np.isfinite(param_vector(value)).all())
    except (DataError, TypeError, ValueError, KeyError, IndexError) as e:
        raise ValueError(f"not a calibration ({str(e)[:80]})") from None
    if not ok:
        raise ValueError("calibration parameters are not 15 finite numbers")


def _fit_summary(value: JsonValue) -> None:
    if not isinstance(value, dict):
        return
    skipped = value.get("skipped", [])
    if not isinstance(skipped, list) or not all(isinstance(s, str) for s in skipped):
        raise ValueError("fit summary 'skipped' is not a list of pose names")
    if not isinstance(value.get("timing", {}), dict):
        raise ValueError("fit summary 'timing' is not an object")


def _limits(value: JsonValue) -> None:
    for k, v in value.items() if isinstance(value, dict) else ():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"limit {str(k)[:40]!r} is not a finite number")


def _any_json(v: object) -> JsonValue:
    return parse_json(v)


_ID = _int(-(2**63), 2**63 - 1)  # any 64-bit id: the outbox numbers runs not yet on the server below 0
_COUNT = _int(0, 2**62)
_OPT_TEXT = ("status_reason", "device_serial", "chip", "station_id", "operator", "lot", "config_hash",
             "config_text", "model", "units", "nvm_status", "host", "panel_id")
# column -> (checker, required); a value of None passes an optional column
SPECS: dict[str, dict[str, tuple[Check, bool]]] = {
    "runs": {"id": (_ID, True), "started_at": (_time, True), "finished_at": (_time, False),
             "status": (_choice(STATUSES), True), **dict.fromkeys(_OPT_TEXT, (_text, False)),
             "counts_per_g": (_real(0, 1e12), False), "gravity_mps2": (_real(0, 1e3), False),
             "verdict": (_choice(VERDICTS), False), "reasons": (_json_of(list, _reasons), False),
             "nvm_outcome": (_json_of(dict), False), "calibration": (_json_of(dict, _calibration), False),
             "fit_summary": (_json_of(dict, _fit_summary), False), "pid": (_int(0, 2**31 - 1), False),
             "limits": (_json_of(dict, _limits), False), "heartbeat_at": (_time, False),
             "heartbeat_s": (_real(0, 1e6), False), "site": (_json_of(dict), False),
             "uncertainty": (_json_of(dict), False)},
    "poses": {"run_id": (_ID, True), "idx": (_COUNT, True), "name": (_text, True),
              **{c: (_real(), True) for c in ("mean_x", "mean_y", "mean_z")},
              **{c: (_real(), False) for c in ("pitch_deg", "roll_deg", "ref_x", "ref_y", "ref_z", "std_x", "std_y",
                                               "std_z", "temp_c", "t_start", "t_end")},
              "n": (_COUNT, False), "dropped": (_COUNT, True), "retries": (_COUNT, True)},
    "events": {"id": (_ID, True), "run_id": (_ID, True), "t": (_time, True), "kind": (_text, True),
               "message": (_text, False), "data": (_any_json, False)},
}


def row_key(table: str, row: Mapping[str, object]) -> str:
    """How a row is named in messages: its id, or ``run/idx`` for a pose."""
    if table == "poses":
        return f"{str(row.get('run_id'))[:20]}/{str(row.get('idx'))[:20]}"
    return str(row.get("id"))[:20]


_NO_DAMAGE: list[DamagedRow] = []  # never appended to: CheckedRow replaces it at the first damage


class CheckedRow:
    """A stored row with every column checked (JSON parsed, a bad value None) and what was wrong
    (``damage``); its values are read typed: ``text``, ``int``, ``real``, ``json``, ...
    ``columns``: check only these (the others kept as read: an aggregate, a JSON text read later)."""

    __slots__ = ("table", "_values", "damage")

    def __init__(self, table: str, row: Mapping[str, object], columns: frozenset[str] | None = None) -> None:
        self.table = table
        self._values: Mapping[str, object] = row  # column -> checked value (None when damaged); copied on change
        self.damage: list[DamagedRow] = _NO_DAMAGE  # shared until a value is damaged (a page reads thousands)
        spec = SPECS[table]
        checked: dict[str, object] = {}
        for col in _checked_columns(table, columns):
            if col not in row:
                continue
            check, required = spec[col]
            v = row[col]
            try:
                if isinstance(v, BadText):
                    raise ValueError(v.problem)
                if v is None:
                    if required:
                        raise ValueError("empty where a value is required")
                    continue
                checked[col] = check(v)
            except (ValueError, TypeError, OverflowError) as e:
                checked[col] = None
                if self.damage is _NO_DAMAGE:
                    self.damage = []
                self.damage.append(DamagedRow(table, row_key(table, row), col, str(e)))
        if checked:
            self._values = {**row, **checked}

    def __contains__(self, col: str) -> bool:
        return col in self._values

    @property
    def values(self) -> Mapping[str, object]:
        """Column -> checked value (read only: ``set`` changes a value)."""
        return self._values

    def set(self, **values: object) -> None:
        """Replace columns' values as a reader sees them (a run whose process is gone reads ``stale``)."""
        self._values = {**self._values, **values}

    def value(self, col: str) -> object:
        """A column's checked value as it is (None when missing, empty or damaged)."""
        return self._values.get(col)

    def text(self, col: str) -> str | None:
        v = self._values.get(col)
        return v if isinstance(v, str) else None

    def int(self, col: str) -> int | None:
        v = self._values.get(col)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    def real(self, col: str) -> float | None:
        """A number column (an aggregate's integer result too) as a float."""
        v = self._values.get(col)
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None

    def json(self, col: str) -> JsonValue:
        """A JSON column's parsed value (the checker parsed it: a JSON value or None)."""
        v = self._values.get(col)
        return v if v is None or isinstance(v, (str, int, float, bool, list, dict)) else None

    def json_object(self, col: str) -> JsonObject | None:
        v = self.json(col)
        return v if isinstance(v, dict) else None

    def json_list(self, col: str) -> list[JsonValue] | None:
        v = self.json(col)
        return v if isinstance(v, list) else None

    def numbers(self, col: str) -> dict[str, float] | None:
        """A JSON object of numbers ({key: number}, as ``limits``); None when absent or damaged."""
        v = self.json_object(col)
        if v is None:
            return None
        return {k: x for k, x in v.items() if isinstance(x, (int, float)) and not isinstance(x, bool)}


@cache
def _checked_columns(table: str, only: frozenset[str] | None) -> tuple[str, ...]:
    """The columns of ``table`` a CheckedRow checks (``only`` those, when given), in the table's order."""
    return tuple(c for c in SPECS[table] if only is None or c in only)


def check_row(table: str, row: Mapping[str, object]) -> CheckedRow:
    """``row`` with every column checked (JSON parsed, a bad value None) and what was wrong."""
    return CheckedRow(table, row)

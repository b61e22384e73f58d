"""Raw sample logs: read a log's samples, its columns and its time axis.

A raw log is a CSV or whitespace-separated table of samples, with or without a
header.  ``columns`` names its columns (``t,x,y,z``; ``-`` ignores a column);
without it a header such as ``time,acc_x,acc_y,acc_z`` is recognised, and a
header-less file of 3 (``x,y,z``) or 4 (``t,x,y,z``) columns is taken as is.  The
time column is in seconds; without one, ``rate_hz`` gives the sample rate.
Finding the static poses in the samples is static_poses.py.
"""
from __future__ import annotations

import contextlib
import gc
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..fileguard.numbers import ALLOWED, all_decimal, decimal_float, is_decimal
from ..fileguard.regular import read_text
from .log_info import LogInfo
from .log_time import check_rate, time_axis
from .posetable import META_RE
from .prose import is_number as _is_number
from .prose import is_text

MIN_LOG_SAMPLES = 10

_TIME_NAMES = {"t", "ts", "time", "times", "timesec", "timestamp", "sec", "seconds"}  # normalised names
_AXIS_PREFIXES = ("", "a", "acc", "accel", "acceleration", "accelerometer")

Splitter = Callable[[str], list[str]]  # the fields of one row of text
Rows = list[tuple[int, str]]  # (file line, stripped text) of each row

_UNIT_WORDS = {  # a unit in a column name, normalised -> (kind, unit)
    "g": ("acc", "g"), "mg": ("acc", "mg"), "ms2": ("acc", "mps2"), "mps2": ("acc", "mps2"), "ms": ("time", "ms"),
    "counts": ("acc", "counts"), "count": ("acc", "counts"), "lsb": ("acc", "counts"), "raw": ("acc", "counts"),
    "s": ("time", "s"), "sec": ("time", "s"), "msec": ("time", "ms"), "us": ("time", "us"), "usec": ("time", "us"),
    "µs": ("time", "us"), "ns": ("time", "ns"), "nsec": ("time", "ns"),
}
_TIME_WORDS = {"millis": "ms", "micros": "us", "timems": "ms", "timeus": "us", "timestampms": "ms",
               "timestampus": "us", "tms": "ms", "tus": "us"}
_RATE_KEYS = re.compile(r"^(fs|sps|odr|hz|rate|freq|frequency|samplerate|samplingrate|samplingfrequency|"
                        r"samplefrequency|samplefreq|datarate|outputdatarate|loggingrate|samplerateh?z?)$")
_RATE_TEXT = re.compile(r"(?<![\w.])(\d+(?:\.\d+)?)\s*(k?hz)\b", re.I)
_NUM = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
MAX_ABS_READING = 1e9  # beyond any ADC or unit: a reading this large is not acceleration data
MAX_LOG_BYTES = 32 << 20  # about 1.3 million samples: 7 hours at 50 Hz, 20 minutes at 1 kHz
LOG_LIMIT_WHY = "a log is parsed in memory at about 30 times its size; split a longer one"
PREAMBLE_LOOKAHEAD = 5  # rows that must follow the data start with the data's field count

@dataclass
class RawLog:
    """Samples of one log: ``t`` (N,) in seconds (sample index when the rate is
    unknown), ``xyz`` (N, 3) in the log's units, ``line`` (N,) file line of each sample."""

    t: np.ndarray
    xyz: np.ndarray
    line: np.ndarray
    source: str
    columns: list[str]
    rate_hz: float | None
    has_time: bool
    info: LogInfo = field(default_factory=LogInfo)

    def __len__(self) -> int:
        return len(self.t)


# -- reading ----------------------------------------------------------------------------

def _split_fn(line: str) -> Splitter:
    """How rows split into fields; cells keep their surrounding spaces (float() and numpy ignore them)."""
    if "," in line:
        return lambda s: s.split(",")
    if ";" in line:
        return lambda s: s.split(";")
    return str.split


def _parse_columns(spec: str | list[str]) -> list[str]:
    names = [c.strip().lower() for c in (spec.split(",") if isinstance(spec, str) else spec)]
    for c in names:
        if c not in ("t", "x", "y", "z", "-"):
            raise DataError(f"--columns {spec!r}: {c!r} is not a column name; allowed: t, x, y, z, - (ignore)")
    for c in "txyz":
        if names.count(c) > 1:
            raise DataError(f"--columns {spec!r}: {c!r} appears twice")
    for c in "xyz":
        if c not in names:
            raise DataError(f"--columns {spec!r}: no {c!r} column; name x, y and z (and t if there is time)")
    return names


def _short(s: str, n: int = 40) -> str:
    return repr(s if len(s) <= n else s[:n] + "...")


def _split_name(h: str) -> tuple[str, str | None]:
    """'Acc_X [m/s^2]' -> ('accx', 'mps2'); 'time_ms' -> ('time', 'ms'); unit None when not named."""
    low = h.strip().lower().replace("m/s^2", "ms2").replace("m/s²", "ms2").replace("m/s2", "ms2")
    unit = None
    m = re.search(r"[(\[]\s*([^)\]]*)\s*[)\]]", low)
    if m:
        u = re.sub(r"[^a-zµ0-9]", "", m.group(1))
        unit = u if u in _UNIT_WORDS else None
        low = low[:m.start()] + low[m.end():]
    else:
        parts = re.split(r"[_\s.-]+", low.strip())
        if len(parts) > 1 and parts[-1] in _UNIT_WORDS and re.sub(r"[^a-z0-9]", "", "".join(parts[:-1])):
            unit, low = parts[-1], "".join(parts[:-1])
    return re.sub(r"[^a-z0-9]", "", low), unit


def _hint_columns(header: list[str]) -> str:
    """An example --columns with the file's field count: the first three columns as x, y, z, the rest ignored."""
    names = ["-"] * len(header)
    for i, a in zip(range(len(header)), "xyz", strict=False):  # fewer than 3 fields: as many as there are
        names[i] = a
    return ",".join(names)


def _columns_from_header(path: Path, line: int, header: list[str], info: LogInfo) -> list[str]:
    """Map a header like ``time_ms,acc_x [g],acc_y [g],acc_z [g],gyr_x`` to ``t,x,y,z,-``."""
    split = [_split_name(h) for h in header]
    out = ["-"] * len(header)
    units: set[str] = set()
    for a in "xyz":
        want = {p + a for p in _AXIS_PREFIXES} | {a + "acc", a + "accel", a + "axis"}
        hits = [i for i, (b, _) in enumerate(split) if b in want]
        if len(hits) != 1:
            raise DataError(f"{path}: line {line}: cannot tell which header column is {a} "
                            f"({'none' if not hits else 'several'} of {', '.join(header)} match); give --columns "
                            f"with {len(header)} names, t, x, y, z or - (ignore), e.g. {_hint_columns(header)}")
        out[hits[0]] = a
        info.axis_names[a] = header[hits[0]]
        u = split[hits[0]][1]
        if u and _UNIT_WORDS[u][0] == "acc":
            units.add(_UNIT_WORDS[u][1])
    if len(units) == 1:
        info.units_hint = units.pop()
    times = [i for i, (b, u) in enumerate(split) if out[i] == "-" and
             (b in _TIME_NAMES or b in _TIME_WORDS) and (u is None or _UNIT_WORDS[u][0] == "time")]
    if len(times) == 1:
        i = times[0]
        out[i] = "t"
        info.axis_names["t"] = header[i]
        b, u = split[i]
        if u is not None or b in _TIME_WORDS:
            info.time_unit = _UNIT_WORDS[u][1] if u is not None else _TIME_WORDS[b]
            info.time_unit_reason = f"named in the header ({header[i]!r})"
    return out


def read_text_file(path: Path, what: str, limit_bytes: int = MAX_LOG_BYTES, why: str = LOG_LIMIT_WHY) -> str:
    """The text of a regular file of at most ``limit_bytes``, or one clear DataError (fileguard.regular)."""
    return read_text(path, what, limit_bytes, why)


def _stated_rate(key: str, value: str) -> float | None:
    k = re.sub(r"[^a-z]", "", key.lower())
    text = f"{key} {value}"
    m = _RATE_TEXT.search(text)
    if m:
        return float(m.group(1)) * (1e3 if m.group(2).lower() == "khz" else 1.0)
    if _RATE_KEYS.match(k) or k.endswith("hz"):
        n = _NUM.search(value)
        return float(n.group(0)) if n else None
    return None


def _preamble(skipped: Rows, info: LogInfo) -> None:
    """Key/value lines before the data (``Fs,100``, ``# rate: 100``, ``Sample rate: 100 Hz``)."""
    for ln, s in skipped:
        m = META_RE.match(s)
        if m:  # "# units: g", "# counts_per_g: 4096": the pose table's metadata lines, read by the same rule
            info.stated[m.group(1)] = m.group(2)
            info.stated_line[m.group(1)] = ln
        body = s.lstrip("#").strip()
        parts = re.split(r"\s*[,;:=\t]\s*", body, maxsplit=1)
        key, value = (parts + [""])[:2]
        if key:
            info.preamble[key] = value
        r = _stated_rate(key, value)
        if r is not None and info.stated_rate_hz is None and math.isfinite(r) and r > 0:
            info.stated_rate_hz = r
            info.rate_source = f"stated on line {ln} ({_short(body)})"


def _data_start(rows: Rows, split: Splitter) -> tuple[int, int | None]:
    """(index of the header or first data row, index of a header that prose lines stand between
    it and the data, else None): the first row from which the data's field count holds for
    PREAMBLE_LOOKAHEAD rows; failing that, the same among the data-looking rows (``is_text``)."""
    tail = [len(split(s)) for _, s in rows[-20:]]
    k = max(set(tail), key=tail.count)
    counts: dict[int, int] = {}  # field counts, computed only as far as the search goes

    def count(i: int) -> int:
        if i not in counts:
            counts[i] = len(split(rows[i][1]))
        return counts[i]

    for j in range(len(rows)):
        ahead = range(j, min(j + PREAMBLE_LOOKAHEAD + 1, len(rows)))
        if all(count(i) == k for i in ahead) and \
                sum(_is_number(c) for c in split(rows[min(j + 1, len(rows) - 1)][1])) >= 3:
            return j, _header_before(rows, split, j, k)
    data = [i for i, (_, s) in enumerate(rows) if not is_text(split(s), k)]
    for a in range(len(data)):
        following = data[a:a + PREAMBLE_LOOKAHEAD + 1]
        if all(len(split(rows[i][1])) == k and sum(_is_number(c) for c in split(rows[i][1])) >= 3 for i in following):
            return data[a], _header_before(rows, split, data[a], k)
    return 0, None


def _header_before(rows: Rows, split: Splitter, j: int, k: int) -> int | None:
    """The header of data starting at row ``j`` when prose lines stand between them (a serial
    monitor's prompt after the header): the nearest earlier prose row of k fields whose names map
    to x, y, z; None when row j is a header itself or there is none."""
    if is_text(split(rows[j][1]), k) or not j:
        return None
    for i in range(j - 1, -1, -1):
        cells = [c.strip() for c in split(rows[i][1])]
        if len(cells) == k and is_text(cells, k):
            try:
                _columns_from_header(Path(), rows[i][0], cells, LogInfo())
                return i
            except DataError:
                continue
    return None


def _check_row(path: Path, ln: int, cells: list[str], names: list[str], use: list[tuple[int, str]],
               label: Callable[[int], str]) -> None:
    """One row's fields: as many as the first line's, each used cell a finite number in range (else one error)."""
    if len(cells) != len(names):
        raise DataError(f"{path}: line {ln}: {len(cells)} fields; expected {len(names)} like the first line")
    cells = [c.strip() for c in cells]
    for i, c in use:
        try:
            v = float(cells[i])
        except ValueError:
            raise DataError(f"{path}: line {ln}, {label(i)}: {_short(cells[i])} is not a number") from None
        if not math.isfinite(v):
            raise DataError(f"{path}: line {ln}, {label(i)}: {_short(cells[i])}; allowed: a finite number")
        if not is_decimal(cells[i]):
            raise DataError(f"{path}: line {ln}, {label(i)}: {_short(cells[i])}; allowed: {ALLOWED}")
        if c != "t" and abs(v) > MAX_ABS_READING:
            raise DataError(f"{path}: line {ln}, {label(i)}: {_short(cells[i])}; allowed: a reading within "
                            f"+-{MAX_ABS_READING:g}")


def _column(cells: list[list[str]], i: int) -> tuple[np.ndarray, np.ndarray]:
    """Column ``i`` of the rows as floats (numpy parses as float() does) and where a cell is not a number."""
    col = [r[i] for r in cells]
    if all_decimal(col):  # else a '4_096' or another script's digits: cell by cell (fileguard.numbers)
        try:
            return np.array(col, dtype=float), np.zeros(len(col), bool)
        except ValueError:
            pass
    v, bad = np.full(len(col), np.nan), np.zeros(len(col), bool)
    for k, x in enumerate(col):
        try:
            v[k] = decimal_float(x)
        except ValueError:
            bad[k] = True
    return v, bad


def _parse_rows(path: Path, rows: Rows, split: Splitter, names: list[str], use: list[tuple[int, str]],
                label: Callable[[int], str], info: LogInfo) -> tuple[np.ndarray, np.ndarray]:
    """The used columns of every data row as floats, and each row's file line; prose lines among them
    (``is_text``) are dropped into ``info.text_lines``, and the first damaged row (in file order) is
    named by _check_row.  Vectorised per column: a million rows parse in about a second."""
    lines_arr = np.fromiter((ln for ln, _ in rows), np.int64, len(rows))
    cells = [split(s) for _, s in rows]
    width = np.fromiter(map(len, cells), np.int64, len(cells))
    wide = np.flatnonzero(width == len(names))
    whole = len(wide) == len(rows)
    good_cells = cells if whole else [cells[i] for i in wide]
    bad = width != len(names)
    data = np.empty((len(rows), len(use)))
    with np.errstate(invalid="ignore"):
        for j, (i, c) in enumerate(use):
            v, b = _column(good_cells, i)
            b |= ~np.isfinite(v) | ((np.abs(v) > MAX_ABS_READING) if c != "t" else False)
            bad[wide[b]] = True
            data[wide, j] = v
    if bad.any():
        flagged = np.flatnonzero(bad)
        text = np.array([is_text(cells[i], len(names)) for i in flagged], dtype=bool)
        if not text.all():
            r = int(flagged[np.argmin(text)])
            _check_row(path, int(lines_arr[r]), cells[r], names, use, label)
        info.text_lines += [(int(lines_arr[i]), rows[i][1]) for i in flagged]
        keep = ~bad
        data, lines_arr = data[keep], lines_arr[keep]
        good_cells = [cells[i] for i in np.flatnonzero(keep)[:DECIMALS_ROWS]]
    _decimals(good_cells[:DECIMALS_ROWS], use, info)
    return data, lines_arr


DECIMALS_ROWS = 4096  # rows whose printed decimals are counted (a log prints every row alike)


def _decimals(cells: list[list[str]], use: list[tuple[int, str]], info: LogInfo) -> None:
    """The most decimals printed in each of the x, y, z columns (the rounding a value grid must allow)."""
    for i, c in use:
        if c in "xyz":
            info.decimals[c] = max((len(v.strip().split(".")[1]) if "." in v and "e" not in v.lower() else 0
                                    for v in (r[i] for r in cells)), default=0)


def _data_rows(path: Path, text: str, skip_rows: int | None, info: LogInfo) -> tuple[Rows, Splitter]:
    """The rows from the header (or first data row) on, and how to split them into fields.

    ``skip_rows`` None finds the data block (_data_start); the rows before it and the
    comments among them are read as the preamble (a stated sample rate, key/value lines)."""
    lines = text.splitlines()
    rows = [(i + 1, s.strip()) for i, s in enumerate(lines) if i >= (skip_rows or 0)]
    comments = [(n, s) for n, s in rows if s.startswith("#")]
    rows = [(n, s) for n, s in rows if s and not s.startswith("#")]
    if not rows:
        raise DataError(f"{path}: no data lines" + (f" after skipping {skip_rows} rows" if skip_rows else ""))
    split = _split_fn(next((s for _, s in reversed(rows[-50:])
                            if sum(_is_number(c) for c in _split_fn(s)(s)) >= 3), rows[-1][1]))
    if skip_rows is None:
        j, header = _data_start(rows, split)
        info.skipped_rows = j if header is None else header
        before = [r for i, r in enumerate(rows[:j]) if i != header]
        _preamble(sorted([c for c in comments if c[0] < rows[j][0]] + before), info)
        if header is not None and header < j:
            info.text_lines += [r for r in before if r[0] > rows[header][0]]
            rows = [rows[header]] + rows[j:]
        else:
            rows = rows[j:]
    else:
        info.skipped_rows = skip_rows
        _preamble([(n, s) for n, s in comments], info)
    return rows, split


def _column_names(path: Path, first_line: int, first: list[str], columns: str | list[str] | None,
                  info: LogInfo) -> tuple[list[str], bool]:
    """Each column's name (t, x, y, z or - for ignored) and whether the first row is a header:
    from ``columns``, else from a header, else 3 (x, y, z) or 4 (t, x, y, z) columns."""
    names = _parse_columns(columns) if columns else None
    if names is not None:
        if len(names) != len(first):
            raise DataError(f"{path}: line {first_line}: {len(first)} fields but --columns names {len(names)} "
                            "(use - for each column to ignore)")
        header = any(not _is_number(first[i]) for i, c in enumerate(names) if c != "-")
        info.axis_names = {c: (first[i] if header else f"column {i + 1}") for i, c in enumerate(names) if c != "-"}
        return names, header
    header = any(not _is_number(c) for c in first)
    if header:
        return _columns_from_header(path, first_line, first, info), header
    if len(first) not in (3, 4):
        raise DataError(f"{path}: line {first_line}: {len(first)} columns and no header; give --columns "
                        f"with {len(first)} names, t, x, y, z or - (ignore), e.g. {_hint_columns(first)}")
    names = ["x", "y", "z"] if len(first) == 3 else ["t", "x", "y", "z"]
    info.axis_names = {c: f"column {i + 1}" for i, c in enumerate(names)}
    if len(first) == 4:
        info.time_unit, info.time_unit_reason = "s", "a header-less first column is seconds"
    return names, header


def read_raw_log(path: str | Path, columns: str | list[str] | None = None, skip_rows: int | None = None,
                 rate_hz: float | None = None) -> RawLog:
    """Read a raw sample log (see the module doc); errors name the file, line and column.

    ``skip_rows`` None finds the data block itself: a preamble of key/value lines (``Fs,100``)
    before the header is skipped and a stated sample rate is used when there is no time column.
    """
    path = Path(path)
    if skip_rows is not None and skip_rows < 0:
        raise DataError(f"--skip-rows {skip_rows}; allowed: 0 or more")
    check_rate(rate_hz)
    text = read_text_file(path, "a CSV or whitespace-separated log", MAX_LOG_BYTES, LOG_LIMIT_WHY)
    with _no_gc():
        return _read_log(path, text, columns, skip_rows, rate_hz)


@contextlib.contextmanager
def _no_gc() -> Iterator[None]:
    """The cycle collector paused while millions of row lists are made (none holds a cycle): it
    would otherwise rescan them all again and again, six times the parse itself."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _read_log(path: Path, text: str, columns: str | list[str] | None, skip_rows: int | None,
              rate_hz: float | None) -> RawLog:
    """read_raw_log on the file's text."""
    info = LogInfo()
    rows, split = _data_rows(path, text, skip_rows, info)
    first_line, first = rows[0][0], [c.strip() for c in split(rows[0][1])]
    names, header = _column_names(path, first_line, first, columns, info)
    if header:
        rows = rows[1:]
    if "t" in names and rate_hz is not None:
        raise DataError(f"{path}: the log has a time column; --rate is only for logs without one")
    use = [(i, c) for i, c in enumerate(names) if c != "-"]

    def label(i: int) -> str:
        return f"column {i + 1} ({first[i] if header else names[i]})"

    data, lines_arr = _parse_rows(path, rows, split, names, use, label, info)
    if len(data) < MIN_LOG_SAMPLES:
        raise DataError(f"{path}: {len(data)} samples; a raw log needs at least {MIN_LOG_SAMPLES}")
    col = {c: j for j, (_, c) in enumerate(use)}
    xyz = data[:, [col["x"], col["y"], col["z"]]]
    t, rate = time_axis(path, data[:, col["t"]] if "t" in col else None, len(data), rate_hz, info, lines_arr,
                         label(names.index("t")) if "t" in col else "")
    return RawLog(t, xyz, lines_arr, str(path), names, rate, "t" in col, info)


__all__ = ["MAX_ABS_READING", "LogInfo", "RawLog", "check_rate", "is_text", "read_raw_log", "read_text_file"]

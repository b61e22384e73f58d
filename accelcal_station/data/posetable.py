"""The pose table: one CSV row per static pose, the station's interchange format.

::

    # device: mma8451
    # units: counts
    # counts_per_g: 4096
    pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,temp_c,n,std_x,std_y,std_z
    p1,39,-158,-2434.354,-977.106,-2937.402,,,,25.0,200,3.1,2.9,4.0

Required columns: ``pose, x, y, z`` (the pose mean in the table's units) and, as a
pair, ``pitch_deg, roll_deg`` (AN4399 angles, expected output by Eqn 22; may be empty
or absent).  Optional: ``ref_x, ref_y, ref_z`` (expected output in g: what the chip
reads, +1 g on the axis pointing up; they override the angles), ``temp_c``, ``n``, ``std_x, std_y, std_z`` (per-sample
std in the table's units).  ``# key: value`` lines before the header carry
metadata; ``units``, ``counts_per_g``, ``gravity`` (m/s^2) and ``device`` are
used when the matching argument is not given, other keys are kept as strings in
``Session.metadata``.  Blank lines and ``#`` lines after the header are skipped.

Row order is acquisition order: the rows are the poses in the order they were taken
(the station and ``accelcal simulate`` write them so).  ``accelcal diagnose`` reads a
change over the session (an offset relaxing after mounting) from it and says when an
effect it names could be that change instead (diagnosis/order.py).
"""
from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Generator, Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..conventions import an4399_reference, check_units
from ..errors import DataError, UnitsError
from ..fileguard.numbers import ALLOWED, decimal_float, is_decimal
from ..jsontypes import JsonScalar
from ..session import PoseColumns, PoseRecord, Session
from .prose import is_number

REQUIRED = ("pose", "x", "y", "z")
GROUPS = (("pitch_deg", "roll_deg"), ("ref_x", "ref_y", "ref_z"), ("std_x", "std_y", "std_z"))
COLUMNS = ("pose", "pitch_deg", "roll_deg", "x", "y", "z", "ref_x", "ref_y", "ref_z", "temp_c", "n",
           "std_x", "std_y", "std_z")
META_KEYS = ("units", "counts_per_g", "gravity", "gravity_mps2", "device")
MAX_POSE_ROWS = 200_000  # fit memory is linear: ~1.8 kB a pose (under 200 MB at 100,000 rows, benchmarks/)
MAX_TABLE_BYTES = 64 << 20  # MAX_POSE_ROWS rows of every column at full precision (~300 B a row) fit in 64 MiB
MAX_ABS_STD = 1e9  # as a reading (rawlog.MAX_ABS_READING): beyond any ADC or unit
MAX_SAMPLES = 1e15  # samples averaged into one pose: years at any rate
_META_RE = META_RE = re.compile(r"^#\s*([A-Za-z_][\w.-]*)\s*:\s*(.*?)\s*$")  # "# key: value"


def table_metadata(path: str | Path) -> dict[str, str]:
    """The ``# key: value`` lines before a pose table's header."""
    meta: dict[str, str] = {}
    lines = _file_lines(Path(path))  # up to the header only: never the whole table in memory
    for raw in lines:
        s = raw.strip()
        if s and not s.startswith("#") and not _banner_line(s):
            break
        m = _META_RE.match(s)
        if m:
            meta[m.group(1)] = m.group(2)
    lines.close()
    return meta


def _short(s: str, n: int = 40) -> str:
    return repr(s if len(s) <= n else s[:n] + "...")


def _meta_number(path: Path, line: int, key: str, value: str) -> float:
    try:
        v = decimal_float(value)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise UnitsError(f"{path}: line {line}: {key}: {value!r}; allowed: a positive number")
    return v


Scale = tuple[str | None, float | None, float | None]  # units, counts per g, gravity in m/s^2


def stated_scale(path: str | Path, meta: dict[str, str], meta_line: dict[str, int], units: str | None,
                 counts_per_g: float | None, gravity_mps2: float | None) -> Scale:
    """The units, counts per g and gravity (m/s^2) a file states on its ``# units:``, ``# counts_per_g:``
    and ``# gravity:`` lines (``meta`` with their 1-based ``meta_line``), each overridden by the command
    line's value when given; a stated value that is not allowed is refused with its line.  The one
    rule of every reader: pose tables, raw logs, lot files.  Units None: neither states them."""
    units = units if units is not None else meta.get("units")
    if units is not None:
        try:
            check_units(units)
        except UnitsError as e:
            where = f"line {meta_line['units']}: " if "units" in meta and units == meta["units"] else ""
            raise UnitsError(f"{path}: {where}{e}") from None
    if counts_per_g is None and meta.get("counts_per_g"):
        counts_per_g = _meta_number(Path(path), meta_line["counts_per_g"], "counts_per_g", meta["counts_per_g"])
    # the site's gravity: "# gravity_mps2:" (or the older "# gravity:"), m/s^2 (config/site.py)
    for key in ("gravity_mps2", "gravity"):
        if gravity_mps2 is None and meta.get(key):
            gravity_mps2 = _meta_number(Path(path), meta_line[key], key, meta[key])
    return units, counts_per_g, gravity_mps2


class _Row:
    """One data row with the error context every cell needs."""

    def __init__(self, path: Path, line: int, cells: dict[str, str]):
        self.path, self.line, self.cells = path, line, cells

    def where(self, col: str) -> str:
        return f"{self.path}: line {self.line}, column {col}"

    def empty(self, col: str) -> bool:
        return self.cells.get(col, "") == ""

    def number(self, col: str, lo: float = -math.inf, hi: float = math.inf) -> float:
        s = self.cells.get(col, "")
        if s == "":
            raise DataError(f"{self.where(col)}: empty; allowed: a finite number")
        try:
            v = float(s)
        except ValueError:
            raise DataError(f"{self.where(col)}: {_short(s)} is not a number") from None
        if not math.isfinite(v):
            raise DataError(f"{self.where(col)}: {_short(s)}; allowed: a finite number (no NaN or infinity)")
        if not is_decimal(s):
            raise DataError(f"{self.where(col)}: {_short(s)}; allowed: {ALLOWED}")
        if not lo <= v <= hi:
            raise DataError(f"{self.where(col)}: {_short(s)} out of range; allowed {lo:g} to {hi:g}")
        return v

    def group(self, cols: tuple[str, ...], lo: float = -math.inf, hi: float = math.inf) -> np.ndarray | None:
        """All cells of a column group, or None when all are empty (partial is an error)."""
        filled = [not self.empty(c) for c in cols]
        if not any(filled):
            return None
        if not all(filled):
            missing = cols[filled.index(False)]
            raise DataError(f"{self.where(missing)}: empty while {', '.join(cols)} are partly given; "
                            "give all of them or none")
        return np.array([self.number(c, lo, hi) for c in cols])


def read_preamble(lines: Iterable[str], path: Path, expected: str) -> tuple[dict[str, str], dict[str, int], int, str]:
    """The ``# key: value`` metadata before the header, the line number of each, and the
    header's index and text; ``lines`` may be a stream (a lot file is read on from there).
    ``expected``: the header's columns, for the error when there is none."""
    meta: dict[str, str] = {}
    meta_line: dict[str, int] = {}
    for i, raw in enumerate(lines):
        s = raw.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _META_RE.match(s)
            if m:
                meta[m.group(1)] = m.group(2)
                meta_line[m.group(1)] = i + 1
            continue
        return meta, meta_line, i, s
    raise DataError(f"{path}: empty: no header line; expected {expected}")


def _header(path: Path, line: str, hline: int) -> list[str]:
    """The header's columns, each known, none twice, the required ones and whole groups present."""
    try:
        header = [c.strip() for c in next(csv.reader([line]))]
    except csv.Error as e:
        raise DataError(f"{path}: line {hline}: not a readable CSV header ({e})") from None
    seen: set[str] = set()
    for c in header:
        if c in seen:
            raise DataError(f"{path}: line {hline}: column {c!r} appears twice in the header")
        if c not in COLUMNS:
            raise DataError(f"{path}: line {hline}: unknown column {c!r}; allowed: {', '.join(COLUMNS)}")
        seen.add(c)
    for c in REQUIRED:
        if c not in seen:
            raise DataError(f"{path}: line {hline}: missing column {c!r}; "
                            f"the header needs {','.join(COLUMNS[:6])} (pitch_deg/roll_deg may be left empty)")
    for grp in GROUPS:
        have = [c for c in grp if c in seen]
        if have and len(have) != len(grp):
            miss = next(c for c in grp if c not in seen)
            raise DataError(f"{path}: line {hline}: missing column {miss!r}: {', '.join(grp)} go together")
    return header


def _pose(row: _Row, references: bool) -> PoseRecord:
    """One table row as a PoseRecord; errors name the row's line and column."""
    name = row.cells["pose"]
    if not name:
        raise DataError(f"{row.where('pose')}: empty; every row needs a pose name")
    mean = np.array([row.number(c) for c in "xyz"])
    angles = row.group(GROUPS[0], lo=-360.0, hi=360.0)  # a pitch of -1e308 is no orientation
    ref = row.group(GROUPS[1], lo=-10.0, hi=10.0)
    if ref is not None and not np.any(ref):
        raise DataError(f"{row.where('ref_x')}: the reference is (0, 0, 0); allowed: the expected output in g")
    std = row.group(GROUPS[2], lo=0.0, hi=MAX_ABS_STD)
    temp = None if row.empty("temp_c") else row.number("temp_c", -273.15, 1000.0)
    n: int | None = None
    if not row.empty("n"):
        count = row.number("n", 1, MAX_SAMPLES)
        if count != int(count):
            raise DataError(f"{row.where('n')}: {row.cells['n']!r}; allowed: a whole number of samples >= 1")
        n = int(count)
    if ref is None and angles is not None:
        ref = an4399_reference(angles[0], angles[1])
    if references and ref is None:
        raise DataError(f"{row.where('pitch_deg')}: pose {name!r} has no reference; give pitch_deg/roll_deg "
                        "or ref_x/ref_y/ref_z (only model 9 fits without references)")
    return PoseRecord(name, mean, std, n, ref, None if angles is None else float(angles[0]),
                      None if angles is None else float(angles[1]), temp)


def _file_lines(path: Path) -> Generator[str, None, None]:
    """The lines of a regular text file of at most MAX_TABLE_BYTES (UTF-8, BOM dropped; \\n, \\r\\n or \\r
    end a line), read one at a time; an unreadable, oversized or non-text file is one DataError, as
    ``read_text_file`` gives (a FIFO or device would block: fileguard opens regular files only)."""
    from ..fileguard.regular import open_regular

    raw = open_regular(path, "a CSV pose table")
    size = os.fstat(raw.fileno()).st_size
    if size > MAX_TABLE_BYTES:
        raw.close()
        raise DataError(f"{path}: {size} bytes; allowed: at most {MAX_TABLE_BYTES} for a CSV pose table (a pose "
                        "table holds one run's static poses; a lot of boards is a lot file)")
    try:
        with io.TextIOWrapper(raw, encoding="utf-8-sig", newline="") as f:
            for line in f:
                yield line.rstrip("\r\n")
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text file (expected a CSV pose table)") from None


# a table of this many rows or more stays columns (session.PoseColumns: ~170 bytes a pose, not ~700;
# its poses are read-only records); a smaller one is a list of PoseRecords
COLUMNS_FROM_ROWS = 10_000


def is_prose_row(cells: list[str]) -> bool:
    """A banner, prompt or note line among a pose table's rows: no cell of it is a number (every pose
    row has its x, y, z readings, so a row with any number is a pose row, and a damaged one is an
    error naming its line)."""
    return any(c.strip() for c in cells) and not any(is_number(c) for c in cells)


def _banner_line(text: str) -> bool:
    """A prose line before the header: no number and no known column name among its cells."""
    try:
        cells = [c.strip() for c in next(csv.reader([text]))]
    except csv.Error:
        cells = [text]
    return not any(c in COLUMNS for c in cells) and is_prose_row(cells)


def _banner_then_header(lines: Iterator[str], path: Path, notes: list[tuple[int, str]] | None
                        ) -> tuple[dict[str, str], dict[str, int], int, str]:
    """read_preamble, with prose lines before the header (a serial monitor's banner: lines with no
    number and no known column name) skipped into ``notes``."""
    meta: dict[str, str] = {}
    meta_line: dict[str, int] = {}
    offset = 0
    while True:
        m, ml, at, text = read_preamble(lines, path, f"{','.join(COLUMNS[:6])} (and optional columns)")
        meta.update(m)
        meta_line.update({k: v + offset for k, v in ml.items()})
        if not _banner_line(text):
            return meta, meta_line, at + offset, text
        if notes is not None:
            notes.append((at + offset + 1, text))
        offset += at + 1


def _rows(path: Path, lines: Iterator[str], header_at: int, header: list[str], references: bool,
          notes: list[tuple[int, str]] | None = None) -> PoseColumns:
    """The poses of the table body after the header (blank, ``#`` and prose rows skipped, prose into
    ``notes``), parsed row by row into columns: memory is the poses, not a second copy of the table
    as lists of strings."""
    reader = csv.reader(lines)
    poses = PoseColumns()
    last = 0
    try:
        for cells in reader:
            line = header_at + 1 + reader.line_num
            if reader.line_num - last > 1:  # a quoted cell ran over a line break: "24<LF>14" would read 2414
                raise DataError(f"{path}: line {line - (reader.line_num - last) + 1}: a quoted cell spans "
                                f"{reader.line_num - last} lines (a line break inside a cell); allowed: one row "
                                "per line, numbers without line breaks")
            last = reader.line_num
            if not cells or all(not c.strip() for c in cells) or cells[0].lstrip().startswith("#"):
                continue
            if is_prose_row(cells):
                if notes is not None:
                    notes.append((line, ",".join(cells)))
                continue
            if len(cells) != len(header):
                raise DataError(f"{path}: line {line}: {len(cells)} fields; the header has {len(header)}")
            if len(poses) >= MAX_POSE_ROWS:
                raise DataError(f"{path}: line {line}: more than {MAX_POSE_ROWS} pose rows; allowed: at most "
                                f"{MAX_POSE_ROWS} (a calibration needs tens; split a lot into boards: accelcal batch)")
            row = _Row(path, line, {c: v.strip() for c, v in zip(header, cells, strict=True)})
            poses.append(_pose(row, references))
    except csv.Error as e:  # e.g. a cell longer than the csv module's field limit
        raise DataError(f"{path}: not a readable CSV table ({e}); allowed: a pose table of numbers") from None
    return poses


def read_pose_table(path: str | Path, units: str | None = None, counts_per_g: float | None = None,
                    gravity_mps2: float | None = None, *, references: bool = False,
                    notes: list[tuple[int, str]] | None = None) -> Session:
    """Read a pose table into a Session; arguments override the file's metadata.

    ``references=True`` makes every row give its expected output (pitch/roll or
    ref columns), as models 6, 12 and 15 need; errors then name the row.  Prose lines
    (``is_prose_row``: a banner before the header, prompts between the rows) are skipped,
    each (line, text) appended to ``notes`` when given.
    """
    path = Path(path)
    lines = _file_lines(path)  # read as parsed: neither the whole text nor a list of lines beside the poses
    meta, meta_line, header_at, header_text = _banner_then_header(lines, path, notes)
    hline = header_at + 1
    header = _header(path, header_text, hline)
    stated_units, counts_per_g, gravity_mps2 = stated_scale(path, meta, meta_line, units, counts_per_g,
                                                            gravity_mps2)
    units = stated_units or "counts"
    poses = _rows(path, lines, header_at, header, references, notes)
    if not poses:
        raise DataError(f"{path}: no pose rows after the header (line {hline})")
    extra = {k: v for k, v in meta.items() if k not in META_KEYS}
    if len(poses) < COLUMNS_FROM_ROWS:  # a small table: PoseRecords one can change, as every Session has
        return Session(list(poses), units, counts_per_g, gravity_mps2, meta.get("device") or None, extra)
    return Session(poses, units, counts_per_g, gravity_mps2, meta.get("device") or None, extra)


def _fmt(v: float | None) -> str:
    """Shortest text that reads back to the same float (exact round trip)."""
    if v is None:
        return ""
    f = float(v)
    return str(int(f)) if f.is_integer() and abs(f) < 1e15 else repr(f)


def write_pose_table(session: Session, path: str | Path, metadata: Mapping[str, JsonScalar] | None = None) -> None:
    """Write ``session`` so that read_pose_table gives it back exactly; atomic (tmp + rename).

    Columns appear when any pose knows them: pitch/roll, ref (whenever references are
    known, so they never depend on re-deriving them from angles), temp_c, n, std.
    """
    path = Path(path)
    meta: dict[str, JsonScalar] = {"units": session.units}  # each written as one '# key: value' line
    if session.counts_per_g is not None:
        meta["counts_per_g"] = _fmt(session.counts_per_g)
    if session.gravity_mps2 is not None:
        meta["gravity"] = _fmt(session.gravity_mps2)
    if session.device:
        meta["device"] = session.device
    meta.update(session.metadata)
    meta.update(metadata or {})
    for k, v in meta.items():
        if not re.fullmatch(r"[A-Za-z_][\w.-]*", str(k)) or "\n" in str(v) or "\r" in str(v):
            raise DataError(f"{path}: metadata {k!r}: {v!r}; allowed: a word key and a one-line value")
    P = session.poses
    cols = ["pose", "pitch_deg", "roll_deg", "x", "y", "z"]
    if any(p.reference_g is not None for p in P):
        cols += ["ref_x", "ref_y", "ref_z"]
    if any(p.temp_c is not None for p in P):
        cols.append("temp_c")
    if any(p.n is not None for p in P):
        cols.append("n")
    if any(p.std is not None for p in P):
        cols += ["std_x", "std_y", "std_z"]
    buf = io.StringIO()
    for k, v in meta.items():
        buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for p in P:
        if not p.name or p.name != p.name.strip() or p.name.startswith("#"):
            raise DataError(f"{path}: pose name {p.name!r}; allowed: non-empty, no surrounding spaces, "
                            "not starting with '#'")
        vals = {"pose": p.name, "pitch_deg": _fmt(p.pitch_deg), "roll_deg": _fmt(p.roll_deg),
                "temp_c": _fmt(p.temp_c), "n": "" if p.n is None else str(int(p.n))}
        for a, i in zip("xyz", range(3), strict=True):
            vals[a] = _fmt(p.mean[i])
            vals[f"ref_{a}"] = "" if p.reference_g is None else _fmt(p.reference_g[i])
            vals[f"std_{a}"] = "" if p.std is None else _fmt(p.std[i])
        bad = [c for c in cols if c != "pose" and vals[c] and not math.isfinite(float(vals[c]))]
        if bad:
            raise DataError(f"{path}: pose {p.name!r}: {bad[0]} is not finite; a pose table holds finite numbers")
        w.writerow([vals[c] for c in cols])
    atomic_write(path, buf.getvalue())


__all__ = ["COLUMNS", "META_RE", "is_prose_row", "read_pose_table", "stated_scale", "table_metadata",
           "write_pose_table"]

"""Property-based fuzzing of every reader (issue 25): any bytes in, either valid data out or the
project's own error (AccelcalError, one line naming the file) out, within a time and memory bound.

Fixed, small numbers of derandomized examples keep these in CI (a few seconds each); the larger
campaign through the real command line is benchmarks/robustness_counts.py.
"""
from __future__ import annotations

import gc
import json
import math
import os
import time
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accelcal_station.api import fit
from accelcal_station.calibration import Calibration
from accelcal_station.config.checks import load_yaml
from accelcal_station.data.loader import load
from accelcal_station.data.lotfile import board_arrays, open_lot
from accelcal_station.errors import AccelcalError
from accelcal_station.nvm.writer import CalibrationWriter

# issue 53: no Python warning reaches the terminal: any warning raised here fails its test (-W error)
pytestmark = pytest.mark.filterwarnings("error")

pa = pytest.importorskip("pyarrow", reason="the Parquet strategies need the optional pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

EXAMPLES = int(os.environ.get("ACCELCAL_FUZZ_EXAMPLES", "40"))  # more for a local hunt
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])
SECONDS = 2.0  # per example: far above what a clean refusal or a small fit takes, far below a hang
PEAK_BYTES = 200 << 20  # per example: a reader must not allocate what a hostile file states

NUMBER_TEXT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["", " ", "nan", "-inf", "1e308", "-1e308", "1e-320", "0x10", "1,5", "abc", "\x1b[31m",
                     "=cmd|' /C calc'!A0", "1_0", "١٢", "9" * 400, "\x00"]),
)
POSE_HEADERS = ["pose,x,y,z", "pose,pitch_deg,roll_deg,x,y,z", "pose,ref_x,ref_y,ref_z,x,y,z",
                "pose,pitch_deg,roll_deg,x,y,z,temp_c,n,std_x,std_y,std_z", "x,y,z", "pose,x,y", "t,x,y,z"]


@pytest.fixture(scope="module", autouse=True)
def _traced() -> Iterator[None]:
    """Allocation tracing on for the whole module, stopped once at its end after a collection.
    Starting and stopping it around each example crashed the interpreter now and then: on
    CPython before 3.12, stopping tracemalloc while a native thread (Arrow's) frees a traced
    numpy buffer is a race in PyTraceMalloc_Untrack (python/cpython gh-128679)."""
    tracemalloc.start()
    yield
    gc.collect()
    tracemalloc.stop()


def bounded(call: Callable[[], Any]) -> Any:
    """``call()``'s result or the AccelcalError it raised, checked against the time and memory bounds;
    any other exception fails the property (it would be exit 70)."""
    base = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    try:
        out: Any = call()
    except AccelcalError as e:
        assert "\n" not in str(e) and str(e), repr(e)
        out = e
    finally:
        took = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] - base
    assert took < SECONDS, f"{took:.2f} s"
    assert peak < PEAK_BYTES, f"{peak / 1e6:.0f} MB"
    return out


FACES = [(0, 0), (0, 180), (90, 0), (-90, 0), (0, 90), (0, -90), (45, 45), (-45, 135), (30, -60), (-60, 30),
         (10, 100), (70, -170), (-20, -20), (55, 5)]


@st.composite
def pose_tables(draw: st.DrawFn) -> bytes:
    """Pose tables: a plausible table (a gain, an offset, noise on AN4399 references) mutated a few
    times: hostile cells, rows of the wrong width, repeated or degenerate poses, broken headers and metadata."""
    from accelcal_station.conventions import an4399_reference

    n = draw(st.integers(3, len(FACES)))
    faces = np.array(FACES[:n], dtype=float)
    ref = an4399_reference(faces[:, 0], faces[:, 1]).reshape(-1, 3)
    gain = 1 + draw(st.floats(-0.05, 0.05))
    x = ref * gain + draw(st.floats(-0.05, 0.05)) + np.random.default_rng(draw(st.integers(0, 99))).normal(0, 1e-3,
                                                                                                         ref.shape)
    rows = [[f"p{i}", repr(float(faces[i, 0])), repr(float(faces[i, 1])), *map(repr, map(float, x[i]))]
            for i in range(n)]
    head = ["pose", "pitch_deg", "roll_deg", "x", "y", "z"]
    meta = ["# units: g"]
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.integers(0, 7))
        r = draw(st.integers(0, n - 1))
        if kind <= 2 and rows[r]:  # a hostile cell
            rows[r][draw(st.integers(0, len(rows[r]) - 1))] = draw(NUMBER_TEXT)
        elif kind == 3:  # a row of the wrong width
            rows[r] = rows[r][:draw(st.integers(0, 7))]
        elif kind == 4 and len(rows[r]) >= 3:  # every pose the same orientation (a degenerate design)
            rows = [[row[0], rows[r][1], rows[r][2], *row[3:]] if len(row) >= 3 else row for row in rows]
        elif kind == 5:  # a pose repeated many times
            rows += [list(rows[r]) for _ in range(draw(st.integers(1, 40)))]
        elif kind == 6:
            meta.append(draw(st.sampled_from(["# units: counts", "# units: furlongs", "# counts_per_g: 0",
                                              "# counts_per_g: 1e308", "# gravity: nan", "# device: \x1b"])))
        else:
            head = draw(st.sampled_from([head, ["pose", "x", "y", "z"], ["x", "y", "z"], head + ["bogus"]]))
    text = "\n".join(meta + [",".join(head)] + [",".join(r) for r in rows]) + "\n"
    if draw(st.integers(0, 9)) == 0:  # now and then raw bytes spliced in
        return text.encode() + draw(st.binary(max_size=64))
    return text.encode("utf-8", "surrogatepass")


@FUZZ
@given(data=pose_tables(), model=st.sampled_from(["6", "9", "12", "15"]))
def test_pose_tables_load_and_fit_or_refuse(tmp_path_factory, data, model):
    p = tmp_path_factory.mktemp("t") / "t.csv"
    p.write_bytes(data)
    out = bounded(lambda: fit(load(p, references=model != "9"), model))
    if not isinstance(out, AccelcalError):
        cal = out.calibration
        assert np.all(np.isfinite(cal.W)) and np.all(np.isfinite(cal.V))


@st.composite
def raw_logs(draw: st.DrawFn) -> bytes:
    """Raw logs: maybe a preamble and header, rows of 3-5 hostile or plausible numbers."""
    lines = draw(st.lists(st.sampled_from(["Fs,100", "# rate: 1e400 Hz", "Logging Type,0", "time,ax,ay,az",
                                           "t,x,y,z", "acc_x [g],acc_y [g],acc_z [g]"]), max_size=3))
    width = draw(st.integers(3, 5))
    base = draw(st.sampled_from([[0, 0, 1], [0, 0, 4096], [1, 1, 1e308]]))
    for k in range(draw(st.integers(0, 60))):
        if draw(st.integers(0, 7)) == 0:
            cells = [draw(NUMBER_TEXT) for _ in range(draw(st.integers(0, 6)))]
        else:
            cells = ([str(k * 0.01)] if width > 3 else []) + [repr(b + draw(st.floats(-0.01, 0.01))) for b in base]
            cells += ["0"] * (width - len(cells))
        lines.append(draw(st.sampled_from([",", ";", " "])).join(cells))
    return ("\n".join(lines) + "\n").encode("utf-8", "surrogatepass")


@FUZZ
@given(data=raw_logs(), rate=st.sampled_from([None, 100.0, 1e-9]))
def test_raw_logs_load_or_refuse(tmp_path_factory, data, rate):
    p = tmp_path_factory.mktemp("r") / "r.csv"
    p.write_bytes(data)
    out = bounded(lambda: fit(load(p, raw=True, rate_hz=rate), "9"))
    if not isinstance(out, AccelcalError):
        assert np.all(np.isfinite(out.calibration.W))


ARROW_TYPES = st.sampled_from([pa.float64(), pa.float16(), pa.int8(), pa.uint64(), pa.decimal128(38, 3), pa.null(),
                               pa.string(), pa.large_string(), pa.binary(), pa.bool_(), pa.timestamp("ns"),
                               pa.date32(), pa.list_(pa.float64()), pa.struct([("a", pa.float64())]),
                               pa.dictionary(pa.int32(), pa.string()), pa.duration("s")])


def _arrow_values(t: Any, n: int, draw: st.DrawFn) -> Any:
    """n values of Arrow type t, some null, numbers from the hostile set."""
    nums = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e308, -1e308, 0.0]))
    if pa.types.is_floating(t) and t != pa.float16():
        return pa.array(draw(st.lists(nums, min_size=n, max_size=n)), type=t)
    if pa.types.is_integer(t):
        info = np.iinfo(t.to_pandas_dtype())
        return pa.array(draw(st.lists(st.one_of(st.none(), st.integers(int(info.min), int(info.max))), min_size=n,
                                      max_size=n)), type=t)
    if pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t):
        vals = draw(st.lists(st.one_of(st.none(), NUMBER_TEXT), min_size=n, max_size=n))
        arr = pa.array(vals, type=pa.string())
        return arr.dictionary_encode() if pa.types.is_dictionary(t) else arr.cast(t)
    return pa.nulls(n, type=t) if draw(st.booleans()) else pa.array([None] * n).cast(t, safe=False) \
        if pa.types.is_null(t) else pa.nulls(n, type=t)


@st.composite
def parquet_lots(draw: st.DrawFn, base: Any) -> Any:
    """Parquet lots: a plausible lot with a few columns of another Arrow type, hostile or null values,
    serials missing now and then, an unknown column."""
    t = base
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.integers(0, 5))
        col = draw(st.sampled_from(t.column_names))
        i = t.column_names.index(col)
        if kind <= 1:  # another type
            t = t.set_column(i, col, _arrow_values(draw(ARROW_TYPES), t.num_rows, draw))
        elif kind <= 3 and t.num_rows:  # hostile values (or null) in a few rows of a text or number column
            typ = t.schema.field(i).type
            text = pa.types.is_string(typ)
            if not (text or pa.types.is_floating(typ) or pa.types.is_integer(typ)):
                continue
            vals = t.column(i).to_pylist()
            for r in draw(st.lists(st.integers(0, t.num_rows - 1), max_size=4)):
                vals[r] = draw(st.sampled_from([None, "", " ", "x"]) if text else st.one_of(
                    st.none(), st.sampled_from([math.nan, math.inf, -1e308, 1e308, 0.0, -1.0])))
            t = t.set_column(i, col, pa.array(vals, type=pa.string() if text else pa.float64()))
        elif kind == 4:
            t = t.append_column(draw(st.sampled_from(["bogus", "ref_x"])), pa.nulls(t.num_rows, pa.float64())) \
                if "ref_x" not in t.column_names else t
        else:
            t = t.slice(0, draw(st.integers(0, t.num_rows)))
    return t


BASE_LOT = None


def _base_lot() -> Any:
    global BASE_LOT
    if BASE_LOT is None:
        import tempfile

        from accelcal_station.lot.synthetic import write_lot

        with tempfile.TemporaryDirectory() as d:
            BASE_LOT = pq.read_table(write_lot(Path(d) / "lot.parquet", 5, seed=4, parquet=True))
    return BASE_LOT


@FUZZ
@given(table=st.deferred(lambda: parquet_lots(_base_lot())), model=st.sampled_from(["9", "12"]))
def test_parquet_lots_read_or_refuse(tmp_path_factory, table, model):
    p = tmp_path_factory.mktemp("l") / "lot.parquet"
    pq.write_table(table, p)

    def read() -> int:
        boards = 0
        for chunk in open_lot(p, 4)[1]:
            x, ref, noise, reasons = board_arrays(chunk, model)
            assert len(reasons) == len(chunk.serials) and "None" not in chunk.serials
            boards += len(chunk.serials)
        return boards

    bounded(read)


@FUZZ
@given(data=pose_tables(), serials=st.lists(st.sampled_from(["B1", "B2", "", " "]), min_size=1, max_size=30))
def test_csv_lots_read_or_refuse(tmp_path_factory, data, serials):
    lines = data.decode("utf-8", "replace").splitlines()
    head = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")]
    if head:
        lines = [("serial," if i == head[0] else f"{serials[i % len(serials)]},") + ln if i >= head[0] else ln
                 for i, ln in enumerate(lines)]
    p = tmp_path_factory.mktemp("c") / "lot.csv"
    p.write_text("\n".join(lines) + "\n")
    bounded(lambda: sum(len(board_arrays(c, "12")[3]) for c in open_lot(p, 3)[1]))


YAML_SCALARS = st.sampled_from(["1:0:0:0", "!!int 1:0", "2024-02-30", "9" * 350, "1e999", ".nan", "&a [*a]", "~",
                                "!!binary xx", "!!python/object:os.system x", "{a: [1, {b: 2}]}", "'\x1b'",
                                "0x" + "f" * 300, "- - - -", "\t", "? [1]\n: 2"])


@FUZZ
@given(doc=st.lists(st.tuples(st.sampled_from(["capture", "store", "device", "plan", "acceptance", "x"]),
                              YAML_SCALARS), max_size=5),
       junk=st.binary(max_size=40))
def test_yaml_configs_load_or_refuse(tmp_path_factory, doc, junk):
    p = tmp_path_factory.mktemp("y") / "c.yaml"
    p.write_bytes(("\n".join(f"{k}: {v}" for k, v in doc) + "\n").encode() + (junk if len(doc) % 2 else b""))
    out = bounded(lambda: load_yaml(p))
    assert isinstance(out, (dict, AccelcalError))


JSON_VALUES = st.recursive(st.one_of(st.none(), st.booleans(), st.floats(), st.integers(), st.text(max_size=8)),
                           lambda kids: st.one_of(st.lists(kids, max_size=4),
                                                  st.dictionaries(st.text(max_size=6), kids, max_size=4)),
                           max_leaves=20)
CAL_KEYS = ["schema", "version", "model", "W", "V", "Gamma", "input_units", "input_per_g", "temperature", "metadata"]


@FUZZ
@given(doc=st.dictionaries(st.sampled_from(CAL_KEYS), JSON_VALUES, max_size=10), deep=st.integers(0, 3))
def test_calibration_json_loads_or_refuses(tmp_path_factory, doc, deep):
    good = Calibration.identity().to_dict()
    text = json.dumps({**good, **doc}) if deep != 1 else "[" * 50_000
    p = tmp_path_factory.mktemp("j") / "cal.json"
    p.write_text(text if deep != 2 else text.replace("1.0", "1" * 5000, 1))
    out = bounded(lambda: Calibration.load(p))
    if isinstance(out, Calibration):
        assert np.all(np.isfinite(out.apply(np.eye(3), "g", temp_c=25.0 if out.temperature else None)))


@FUZZ
@given(doc=st.dictionaries(st.sampled_from(["schema", "version", "base_addr", "slot_size", "length", "crc32",
                                            "image_base64"]), JSON_VALUES, max_size=7),
       keep=st.booleans())
def test_nvm_backup_images_load_or_refuse(tmp_path_factory, doc, keep):
    from accelcal_station.drivers.eeprom import EEPROM24

    writer = CalibrationWriter(EEPROM24())
    d = tmp_path_factory.mktemp("n")
    writer.backup(d / "good.json")
    good = json.loads((d / "good.json").read_text())
    p = d / "img.json"
    p.write_text(json.dumps({**good, **doc} if keep else doc))
    out = bounded(lambda: writer.load_image(p))
    if not isinstance(out, AccelcalError):
        img, _ = out
        assert len(img) == 2 * writer.slot_size


def test_the_properties_can_fail():
    """The bound itself: a non-project exception or a slow call is caught, not passed."""
    with pytest.raises(AssertionError):
        bounded(lambda: time.sleep(SECONDS + 0.1))
    with pytest.raises(ZeroDivisionError):
        bounded(lambda: 1 / 0)
    assert math.isfinite(bounded(lambda: 1.0))

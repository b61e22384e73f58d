"""Issue 51: `accelcal batch LOT --out` on a small lot starts without what its path does not need (the
config schema, pandas), and the Arrow arrays it builds through their buffers (data/arrow_arrays.py) are
the ones pyarrow's own conversions give."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pytest

from accelcal_station.data import arrow_arrays

PROBE = """
import json, sys
from accelcal_station.cli import main
sys.argv = ["accelcal", "batch", sys.argv[1], "--model", "12", "--out", sys.argv[2]]
try:
    main()
except SystemExit as e:
    code = e.code
print(json.dumps({"code": code, "loaded": sorted(m for m in ("pandas", "pydantic", "scipy", "matplotlib",
                                                             "sqlalchemy") if m in sys.modules)}))
"""


@pytest.mark.parametrize("kind", ["csv", "parquet"])
def test_a_lot_file_batch_imports_no_schema_store_or_pandas(tmp_path, kind) -> None:
    from accelcal_station.lot.synthetic import write_lot

    lot = write_lot(tmp_path / f"lot.{kind}", 40, "an4399-8", seed=51, parquet=kind == "parquet")
    out = subprocess.run([sys.executable, "-c", PROBE, str(lot), str(tmp_path / "r.csv")], capture_output=True,
                         text=True, check=True, cwd=tmp_path).stdout.strip().splitlines()[-1]
    doc = json.loads(out)
    assert doc == {"code": 0, "loaded": []}, doc
    assert (tmp_path / "r.csv").read_text().count("\n") == 41  # a header and a row per board


def test_a_store_section_beyond_a_bare_path_still_goes_through_the_schema(tmp_path) -> None:
    from accelcal_station.cli._common import config_store_file

    (tmp_path / "a.yaml").write_text("store:\n  path: runs/a.sqlite\n")
    (tmp_path / "b.yaml").write_text("store:\n  path: b.sqlite\n  heartbeat_s: 5\n")
    (tmp_path / "c.yaml").write_text("store:\n  path: sqlite:///c.sqlite\n")
    (tmp_path / "d.yaml").write_text("store:\n  path: b.sqlite\n  colour: red\n")  # the schema refuses it
    (tmp_path / "e.yaml").write_text("store:\n  path: postgresql://u@h/db\n")
    cwd = __import__("pathlib").Path.cwd()
    assert config_store_file(tmp_path / "a.yaml") == cwd / "runs" / "a.sqlite"
    assert config_store_file(tmp_path / "b.yaml") == cwd / "b.sqlite"
    assert str(config_store_file(tmp_path / "c.yaml")) == "c.sqlite"
    assert config_store_file(tmp_path / "d.yaml") is None
    assert config_store_file(tmp_path / "e.yaml") is None


@pytest.mark.parametrize("dtype", [np.float64, np.int64, np.int8])
def test_numbers_are_what_pa_array_gives(dtype) -> None:
    rng = np.random.default_rng(51)
    a = (rng.standard_normal(1003) * 100).astype(dtype)
    mask = rng.random(1003) < 0.1
    assert arrow_arrays.numbers(a).equals(pa.array(a))
    built = arrow_arrays.numbers(a, mask=mask)
    assert built.equals(pa.array(a, mask=mask)) and built.null_count == mask.sum()
    built.validate(full=True)


def test_booleans_and_strings_are_what_pa_array_gives() -> None:
    flags = np.random.default_rng(5).random(77) < 0.5
    assert arrow_arrays.booleans(flags).equals(pa.array(flags))
    words = ["B001", "", None, "Kalibrierung ü", "é" * 40, "PASS"] * 9
    built = arrow_arrays.strings(words)
    built.validate(full=True)
    assert built.equals(pa.array(words, pa.string()))
    assert arrow_arrays.strings([]).equals(pa.array([], pa.string()))


def test_to_numpy_reads_slices_and_chunks_and_declines_nulls() -> None:
    x = np.arange(20, dtype=np.float64) * 0.5
    arr = pa.array(x)
    assert np.array_equal(arrow_arrays.to_numpy(arr.slice(3, 9)), x[3:12])
    chunked = pa.chunked_array([pa.array(x[:7]), pa.array(x[7:]).slice(2)])
    assert np.array_equal(arrow_arrays.to_numpy(chunked), np.concatenate([x[:7], x[9:]]))
    assert np.array_equal(arrow_arrays.to_numpy(pa.array(np.arange(5, dtype=np.int32))), np.arange(5))
    assert arrow_arrays.to_numpy(pa.array([1.0, None])) is None  # nulls: the caller's own conversion
    assert arrow_arrays.to_numpy(pa.array(["a"])) is None

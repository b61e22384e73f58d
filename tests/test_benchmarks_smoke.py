"""Every benchmark runs with tiny sizes and prints its table with finite ratios (benchmarks/)."""
from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
DASHES = re.compile(r"^-+(  -+)+$")


def load(name: str):
    """A benchmark script as a module (its own folder goes on sys.path for benchlib)."""
    spec = importlib.util.spec_from_file_location(f"bench_smoke_{name}", BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def run(capsys, name: str, *argv: str) -> str:
    assert load(name).main(list(argv)) == 0
    return capsys.readouterr().out


def tables(out: str) -> list[list[list[str]]]:
    """Every fixed-width table printed (rows split on runs of 2+ spaces), header excluded."""
    lines = out.splitlines()
    found = []
    for i, line in enumerate(lines):
        if DASHES.match(line):
            rows = []
            for r in lines[i + 1:]:
                cells = re.split(r"\s{2,}", r.strip())
                if len(cells) < 2:  # a note under the table
                    break
                rows.append(cells)
            found.append(rows)
    return found


def number(cell: str) -> float:
    v = float(cell.rstrip("%"))
    assert math.isfinite(v), cell
    return v


def test_accuracy_ratios_near_the_limit(capsys):
    out = run(capsys, "bench_accuracy", "--boards", "12", "--heldout", "2", "--samples", "64", "--optimal", "0")
    (rows,) = tables(out)
    mod = load("bench_accuracy")
    assert [(r[0], r[1]) for r in rows] == [(m, d) for m in ("6", "12", "15", "9") for d in mod.PLAN[m]]
    for r in rows:
        assert r[3] == "12/12"
        ratios = [number(c) for c in r[4:7] if c != "-"] + [number(r[9])]
        # pooled RMS over 12 boards x >= 3 parameters: outside 0.3..3 has probability < 1e-9
        assert all(0.3 < v < 3.0 for v in ratios), r
        # a fitted calibration is never better than the true one on the same readings, beyond chance
        assert number(r[11]) > 0.8, r


def test_peers_table_and_identical_solvers(capsys):
    out = run(capsys, "bench_peers", "--boards", "10", "--heldout", "2", "--samples", "32")
    methods, ratios = tables(out)
    names = [r[0] for r in methods]
    try:
        importlib.import_module("imucal")
        have_imucal = True
    except ImportError:
        have_imucal = False
    if have_imucal:
        assert names[0].startswith("imucal ") and ratios[0][0].startswith("imucal Ferraris")
    else:
        assert "imucal not installed: pip install -e '.[bench]'" in out
    assert names[-5:] == ["accelcal model 12", "scipy least_squares, 9-param", "accelcal model 9",
                          "accelcal model 12", "true calibration (noise only)"]
    for r in ratios:
        assert all(number(c) > 0 for c in r[1:])
    # scipy and accelcal minimise the same cost: same answer to print precision
    assert ratios[-1][1:] == ["1.00", "1.00", "1.00", "1.00"]


def test_batch_fit_rates(capsys):
    out = run(capsys, "bench_batch_fit", "--boards", "200", "--loop-boards", "8")
    rows = [ln.split() for ln in out.splitlines() if re.match(r"^\s+(6|9|12|15) ", ln)]
    assert [r[0] for r in rows] == ["6"] * 3 + ["12"] * 3 + ["15"] * 3 + ["9"] * 4
    assert all(number(r[-1]) > 0 and number(r[-3]) > 0 for r in rows)


def test_batch_end_to_end_and_memory(capsys):
    out = run(capsys, "bench_batch", "--boards", "20", "--loop-boards", "5", "--store-boards", "5",
              "--memory-boards", "200")
    e2e, mem = tables(out)
    assert [r[0] for r in e2e] == ["files", "files", "files", "store"]
    assert all(number(r[3]) > 0 for r in e2e) and number(e2e[2][-1]) > 0
    assert [r[0] for r in mem] == [f"fit_batch model {m} ({d})" for m, d in
                                  (("6", "an4399-8"), ("12", "an4399-8"), ("15", "an4399-8"), ("9", "nine-position"))
                                  ] + ["batch.recalibrate model 12 (an4399-8)"]
    # a fit keeps at least its inputs' worth of results per board
    assert all(number(r[2]) > 0 for r in mem[:4])


def test_station_time_above_floor(capsys):
    out = run(capsys, "bench_station_time", "--boards", "1", "--panel", "4")
    rows, panel, per_board = tables(out)
    by = {r[0]: r[1:] for r in rows}
    assert "verdicts: PASS" in out
    # the board's time includes its floor's sampling and its shortest path: never below the floor
    assert number(by["ratio: total / floor"][0]) >= 1.0
    # the jig's moves: 8 fit poses from home along the shortest path, then the verification poses (issue 51:
    # settle 0.2 s + angle / 100 deg/s each, a move of 0 deg taking none): well under 11 x 2 s
    assert 0 < number(by["jig moves (settle + angle / rated speed)"][0]) < 22.0
    per = {r[0]: number(r[1]) for r in per_board}
    # a panel shares every pose's moves and sampling: per board it costs far less than one board
    assert per["panel of 4, per board"] < 0.5 * per["single board (mean above)"]
    assert math.isclose(per["single board / 4"], per["single board (mean above)"] / 4, rel_tol=0.01)
    assert number({r[0]: r[1:] for r in panel}["I2C bus time (4 boards x samples, TCA9548A, 400 kHz)"][0]) > 0


def test_panel_pose_scatter(capsys):
    out = run(capsys, "bench_panel_pose", "--small")
    (rows,) = tables(out)
    by = {r[0]: [number(v) for v in r[1:]] for r in rows}
    assert list(by) == ["alone", "panel of 4", "panel of 16", "perfect jig"]
    # the panel's estimate removes the jig's scatter from the residuals (1.5 mg alone vs 0.04 mg noise)
    assert by["panel of 16"][4] < 0.2 * by["alone"][4]
    assert all(math.isfinite(v) and v > 0 for r in by.values() for v in r)


def test_bad_arguments_exit_2(capsys):
    assert load("bench_accuracy").main(["--models", "7"]) == 2
    assert "error: --models" in capsys.readouterr().err


@pytest.fixture(autouse=True)
def _keep_sys_path():
    saved = list(sys.path)
    yield
    sys.path[:] = saved


def test_bench_lot_prints_every_figure(capsys):
    out = run(capsys, "bench_lot", "--boards", "300", "--boards9", "40", "--today9", "20", "--loop-boards", "5",
              "--lot-boards", "300", "--files", "10", "--rss", "200,400")
    rates = re.findall(r"^   (6|12|15|9)\s+([\d,]+)\s+([\d,]+)\s+([\d,]+)\s+([\d.]+)\s+(\d+)"
                       r"(?:\s+([\d,]+) \((?:met|not met)\))?$", out, re.M)
    assert [r[0] for r in rates] == ["6", "12", "15", "9"]
    assert all(float(v.replace(",", "")) > 0 for r in rates for v in r[1:6])
    assert [r[6] for r in rates] == ["", "1,000,000", "", "100,000"]  # the targets, per model
    assert len(re.findall(r"boards/s", out)) >= 5 and "10,000,000 boards extrapolated" in out
    assert len(re.findall(r"peak RSS\s+\d+ MB", out)) == 2
    heap = re.findall(r"model (9|12) +([\d,]+) -> +([\d,]+) fits/s \(([\d.]+)x\); page faults per block "
                      r"([\d,]+) -> ([\d,]+)", out)
    assert [h[0] for h in heap] == ["9", "12"]
    assert all(float(v.replace(",", "")) >= 0 for h in heap for v in h[1:])


@pytest.mark.skipif(not hasattr(__import__("os"), "sched_setaffinity"),
                    reason="pinning a run to one core needs os.sched_setaffinity (Linux)")
def test_bench_lot_core_pins_one_core_and_prints_every_rate(capsys):
    pytest.importorskip("pyarrow", reason="the lot path's Parquet pairs need pyarrow")
    out = run(capsys, "bench_lot_core", "--boards", "1500", "--repeats", "2", "--formats", "csv:csv,parquet:parquet")
    assert re.search(r"1,500 boards, model 12, one core \(CPU \d+ of \d+", out), out
    rows = re.findall(r"^(csv -> csv|parquet -> parquet|numpy reference csv->csv) +(?!against)(.*)$", out, re.M)
    assert [r[0] for r in rows] == ["csv -> csv", "parquet -> parquet", "numpy reference csv->csv"], out
    for label, rest in rows:
        figures = [float(v.replace(",", "")) for v in re.findall(r"[\d,.]+", rest)]
        assert len(figures) == (4 if label.startswith("numpy") else 7) and all(v > 0 for v in figures), rest
    assert re.search(r"against the numpy reference, per CPU-second, same core: [\d.]+x", out)
    assert re.search(r"target 100,000 boards/s per core: median in process [\d,]+ \((met|NOT met)\)", out)


def test_thermal_time_split(capsys):
    out = run(capsys, "bench_thermal_time", "--boards", "1", "--panel", "2")
    (rows,) = tables(out)
    by = {r[0]: r[1:] for r in rows}
    assert "verdicts: one board PASS; panel PASS (2/2 PASS)" in out
    keys = ("soak (all set points)", "sampling floor (averaged / ODR)", "rest (moves, gating, EEPROM)",
            "total per board")
    for col in (0, 2):  # one board, then the panel's per-board figure
        soak, floor, rest, total = (number(by[k][col]) for k in keys)
        assert soak + floor + rest == pytest.approx(total, abs=2.0) and soak > floor > 0
    # two boards share one soak: per board, the panel's soak is about half one board's
    assert number(by[keys[0]][0]) / number(by[keys[0]][2]) == pytest.approx(2.0, rel=0.05)


def test_resources_prints_peaks_under_the_limit(capsys):
    from accelcal_station.data.lotarrow import arrow_available

    out = run(capsys, "bench_resources", "--small")
    (rows,) = tables(out)
    assert [r[0] for r in rows] == ["fit TABLE --model 12 (rows)", "fit TABLE, model chosen (rows)",
                                    "fit TABLE --json, model chosen (rows)"] * 2 + [
        "simulate six-face --raw (samples)"] * 2 + ["twin fit LOT (boards)", "batch LOT.csv --out R.csv (boards)"] + (
        ["batch LOT.parquet --out R.csv (boards)"] if arrow_available() else [])  # Parquet: the optional pyarrow
    # every command succeeded and its own peak (a fresh Python with numpy: tens of MB) was measured
    twin = rows.pop(8)
    assert all(r[-1] == "0" and 20 < number(r[2]) < 200 and r[3] == "under 200" for r in rows), rows
    # twin fit against its bound (issue 51: 256 MB up to 1,000,000 boards)
    assert twin[-1] == "0" and 20 < number(twin[2]) < 256 and twin[3] == "under 256", twin


def test_twin_scale_prints_time_memory_and_ratio(capsys):
    out = run(capsys, "twin_scale", "--sizes", "300,600")
    assert re.search(r"300 boards: twin fit [0-9.]+ s, peak [0-9]+ MB", out)
    m = re.search(r"peak memory ratio 600 / 300 boards: ([0-9.]+)x", out)
    assert m and 0.5 < float(m.group(1)) < 2.0


def test_twin_null_prints_the_gap_rate(capsys):
    out = run(capsys, "twin_null", "--small")
    m = re.search(r"no material gap: (\d+) of 3 \(gap rate ([0-9.]+);", out)
    assert m and int(m.group(1)) + round(3 * float(m.group(2))) == 3, out
    assert "| detectable but immaterial |" in out and re.search(r"noise scale fitted .* median 0\.9", out), out


def test_memory_prints_date_machine_and_flat_batch_peaks(capsys):
    out = run(capsys, "bench_memory", "--batch-boards", "300,600", "--twin-boards", "")
    assert re.search(r"^bench_memory: \d{4}-\d\d-\d\d \d\d:\d\d UTC; .*\d+ CPUs, \d+ GiB", out, re.M), out
    peaks = [float(m.group(1)) for m in re.finditer(r"^batch LOT\.csv --out R\.csv\s+[0-9,]+\s+([0-9]+)\s", out, re.M)]
    assert len(peaks) == 2 and all(20 < p < 200 for p in peaks), out  # a fresh Python with numpy: tens of MB
    m = re.search(r"batch LOT\.csv: largest / smallest lot ([0-9.]+)", out)
    assert m and 0.8 < float(m.group(1)) < 1.25, out

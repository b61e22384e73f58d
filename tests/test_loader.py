"""Reading logs from other rigs: preambles, column names, time units, units judged from the data,
one loader for fit, batch and diagnose; every hint followed; inputs that cannot be data refused."""
from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from test_rawlog import CPG, RATE, make_log

from accelcal_station.cli import cli


def _run(*args):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy warning would be a defect: it becomes an internal error here
        return CliRunner().invoke(cli, [str(a) for a in args])


def _one_line_error(r, *needles):
    assert r.exit_code not in (0, 70), (r.exit_code, r.output)
    assert r.stderr.startswith("error: ") and r.stderr.count("\n") == 1, r.stderr
    assert "Traceback" not in r.output and "Warning" not in r.output
    for n in needles:
        assert n in r.stderr, (n, r.stderr)


@pytest.fixture(scope="module")
def log12():
    return make_log(seed=11, n_poses=12)


def _write(path, header, rows, preamble=()):
    lines = list(preamble) + ([header] if header else []) + [",".join(r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _cells(x, fmt):
    return [[format(v, fmt) for v in row] for row in x]


def test_logger_preamble_and_stated_rate_need_no_flags(tmp_path, log12):
    counts, holds, S, b = log12
    gyro = np.zeros_like(counts)
    f = _write(tmp_path / "logger.csv", "ax,ay,az,gx,gy,gz", _cells(np.hstack([counts, gyro]), ".0f"),
               ["Fs,100", "Logging Type,0", "Initialization time,36.5"])
    r = _run("fit", "--raw", f, "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    inf = js["inferred"]
    assert inf["skipped_rows"] == 3 and inf["rate_hz"] == RATE and "line 1" in inf["rate_source"]
    assert inf["columns"] == {"x": "ax", "y": "ay", "z": "az"} and inf["units"] == "counts"
    assert inf["counts_per_g"] == CPG
    assert js["segmentation"]["count"] == len(holds)
    # the same answer as the flags a user had to guess before
    flags = _run("fit", "--raw", f, "--skip-rows", "4", "--columns", "x,y,z,-,-,-", "--rate", "100",
                 "--counts-per-g", str(CPG), "--json")
    assert flags.exit_code == 0, flags.output
    np.testing.assert_allclose(js["W"], json.loads(flags.stdout)["W"], rtol=1e-12)
    text = _run("fit", "--raw", f).stdout
    assert "skipped 3 rows before the data (Fs=100; Logging Type=0; Initialization time=36.5)" in text
    assert "rate 100 Hz from stated on line 1 ('Fs,100')" in text
    assert "columns: x = 'ax', y = 'ay', z = 'az'" in text and f"{CPG:g} counts/g, the power of two nearest" in text


@pytest.mark.parametrize("names, tcol, tscale, units_word, scale", [
    (("acc_x", "acc_y", "acc_z"), "time", 1.0, None, 1.0),
    (("accel_x", "accel_y", "accel_z"), "time_ms", 1e3, None, 1.0),
    (("x", "y", "z"), "timestamp_us", 1e6, None, 1.0),
    (("ax (g)", "ay (g)", "az (g)"), "t [s]", 1.0, "g", 1.0 / CPG),
    (("acc_x[m/s^2]", "acc_y[m/s^2]", "acc_z[m/s^2]"), "timestamp", 1e3, "mps2", 9.80665 / CPG),
    (("AccX_mg", "AccY_mg", "AccZ_mg"), "millis", 1e3, "g", 1000.0 / CPG),
])
def test_column_names_time_units_and_unit_words(tmp_path, log12, names, tcol, tscale, units_word, scale):
    counts, holds, S, b = log12
    t = np.arange(len(counts)) / RATE * tscale
    cols = [tcol, *names, "gyr_x"]
    f = _write(tmp_path / "log.csv", ",".join(cols),
               [[f"{ti:.6f}" if tscale == 1 else f"{ti:.0f}"] + [f"{v:.6f}" for v in row] + ["0"]
                for ti, row in zip(t, counts * scale, strict=True)])
    r = _run("fit", "--raw", f, "--json")
    assert r.exit_code == 0, r.output
    inf = json.loads(r.stdout)["inferred"]
    assert inf["rate_hz"] == pytest.approx(RATE) and inf["time_unit"] == {1.0: "s", 1e3: "ms", 1e6: "us"}[tscale]
    assert inf["columns"] == {"t": tcol, "x": names[0], "y": names[1], "z": names[2]}
    assert inf["units"] == (units_word or "counts")
    assert json.loads(r.stdout)["segmentation"]["count"] == len(holds)


@pytest.mark.parametrize("kind", ["g", "mps2", "counts", "unsigned"])
def test_units_are_judged_the_same_in_fit_batch_and_diagnose(tmp_path, log12, kind):
    counts, holds, S, b = log12
    x = {"g": counts / CPG, "mps2": counts / CPG * 9.80665, "counts": counts, "unsigned": counts + 32768}[kind]
    f = _write(tmp_path / "log.csv", "ax,ay,az", _cells(x, ".7g"), ["# rate: 100 Hz"])
    fit = _run("fit", "--raw", f, "--json")
    assert fit.exit_code == 0, fit.output
    fjs = json.loads(fit.stdout)
    want = {"g": "g", "mps2": "mps2", "counts": "counts", "unsigned": "counts"}[kind]
    assert fjs["inferred"]["units"] == want and fjs["inferred"]["offset_counts"] == (32768 if kind == "unsigned" else 0)
    diag = _run("diagnose", "--raw", f, "--json")
    assert diag.exit_code == 0, diag.output
    assert json.loads(diag.stdout)["data"]["counts_per_g"] == ([CPG] if want == "counts" else [None])
    # the static poses as a pose table without a units line: batch judges it the same way
    table = tmp_path / "board.csv"
    table.write_text("pose,pitch_deg,roll_deg,x,y,z\n" + "".join(
        f"{s['pose']},,,{s['mean'][0]!r},{s['mean'][1]!r},{s['mean'][2]!r}\n" for s in fjs["segmentation"]["segments"]))
    single = _run("fit", table, "--model", "9", "--json")
    assert single.exit_code == 0, single.output
    assert json.loads(single.stdout)["inferred"]["units"] == want
    batch = _run("batch", table, "--model", "9", "--json")
    assert batch.exit_code == 0, batch.output
    board = json.loads(batch.stdout)["results"][0]
    assert board["input_units"] == want
    assert board["input_per_g"] == pytest.approx(json.loads(single.stdout)["input_per_g"], rel=1e-12)
    np.testing.assert_allclose(board["W"], json.loads(single.stdout)["W"], atol=1e-9)


# -- inputs that cannot be data: one line, non-zero exit, no numpy warnings -------------------------

def test_fifo_device_and_directory_are_refused(tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)  # reading it would block forever
    for args, what in [(("fit", "--raw", fifo), "a FIFO"), (("fit", fifo), "a FIFO"),
                       (("diagnose", "--raw", fifo, "--rate", "100"), "a FIFO"),
                       (("fit", "--raw", "/dev/zero"), "a device"), (("fit", "/dev/zero"), "a device"),
                       (("fit", "--raw", tmp_path), "a directory")]:
        _one_line_error(_run(*args), what, "allowed: a regular file")


def test_huge_field_huge_reading_and_tiny_rate_are_refused(tmp_path, log12):
    counts = log12[0][:400]
    big_cell = _write(tmp_path / "cell.csv", "ax,ay,az", _cells(counts, ".0f") + [["1" * 200_000, "abc" * 70_000, "3"]])
    _one_line_error(_run("fit", "--raw", big_cell, "--rate", "100"), "allowed: a finite number")
    table = tmp_path / "table.csv"
    table.write_text("pose,pitch_deg,roll_deg,x,y,z\np1,0,0,\"" + "9" * 200_000 + "\",0,1\n")
    _one_line_error(_run("fit", table), "table.csv", "field larger than field limit")
    huge = _write(tmp_path / "huge.csv", "ax,ay,az", _cells(counts, ".0f") + [["1e308", "0", "0"]])
    _one_line_error(_run("fit", "--raw", huge, "--rate", "100"), "'1e308'; allowed: a reading within +-1e+09")
    huge_table = tmp_path / "huge_table.csv"
    huge_table.write_text("# units: g\npose,pitch_deg,roll_deg,x,y,z\n" +
                          "".join(f"p{i},,,{v},0,1\n" for i, v in enumerate([1e308, 0, 1, 0, 1, 0, 1, 0, 1, 0])))
    _one_line_error(_run("fit", huge_table, "--model", "9"), "pose 'p0', column x", "allowed: a reading within")
    ok = _write(tmp_path / "ok.csv", "ax,ay,az", _cells(counts, ".0f"))
    _one_line_error(_run("fit", "--raw", ok, "--rate", "1e-320"), "--rate 1e-320; allowed: a sample rate from")
    _one_line_error(_run("diagnose", "--raw", ok, "--rate", "1e-320"), "--rate 1e-320")
    _one_line_error(_run("diagnose", ok, "--rate", "1e-320"), "--rate 1e-320")  # a pose table's sample rate too
    _one_line_error(_run("fit", "--raw", ok, "--rate", "1e300"), "allowed: a sample rate from")


# -- every hint, followed -------------------------------------------------------------------------

def _suggested_columns(stderr: str) -> str:
    return stderr.split("e.g. ")[1].split()[0]


def test_column_hints_work_when_followed(tmp_path, log12):
    counts = log12[0]
    ambiguous = _write(tmp_path / "amb.csv", "a,b,c,gyro", _cells(np.hstack([counts, counts[:, :1] * 0]), ".0f"),
                       ["Fs,100"])
    r = _run("fit", "--raw", ambiguous)
    _one_line_error(r, "cannot tell which header column is x", "give --columns with 4 names")
    assert _run("fit", "--raw", ambiguous, "--columns", _suggested_columns(r.stderr)).exit_code == 0
    five = _write(tmp_path / "five.csv", None, _cells(np.hstack([counts, counts[:, :2] * 0]), ".0f"))
    r = _run("fit", "--raw", five, "--rate", "100")
    _one_line_error(r, "5 columns and no header; give --columns with 5 names")
    assert _run("fit", "--raw", five, "--rate", "100", "--columns", _suggested_columns(r.stderr)).exit_code == 0


def test_units_hints_work_when_followed(tmp_path, log12):
    counts = log12[0]
    odd = _write(tmp_path / "odd.csv", "ax,ay,az", _cells(counts / CPG * 2.5, ".7g"), ["# rate: 100"])
    r = _run("fit", "--raw", odd)
    _one_line_error(r, "median norm of the readings 2.5", "give --units counts|g|mps2")
    assert _run("fit", "--raw", odd, "--units", "g").exit_code == 0
    as_g = _write(tmp_path / "as_g.csv", "ax,ay,az", _cells(counts, ".0f"), ["# rate: 100"])
    r = _run("fit", "--raw", as_g, "--units", "g", "--model", "12")
    _one_line_error(r, "counts given as g? use --units counts --counts-per-g N")
    assert _run("fit", "--raw", as_g, "--units", "counts", "--counts-per-g", str(CPG)).exit_code == 0


def test_rate_and_raw_hints_work_when_followed(tmp_path, log12):
    counts = log12[0]
    norate = _write(tmp_path / "norate.csv", "ax,ay,az", _cells(counts, ".0f"))
    r = _run("diagnose", "--raw", norate)  # read as fit reads it; the time view is what --rate adds
    _one_line_error(r, "12 static poses found", "give --rate HZ for the time view")
    assert _run("diagnose", "--raw", norate, "--rate", "100").exit_code == 0
    r = _run("fit", norate, "--rate", "100")
    _one_line_error(r, "--rate is for raw sample logs; add --raw")
    assert _run("fit", norate, "--rate", "100", "--raw").exit_code == 0
    t_ns = np.arange(len(counts)) * 10_000_000  # nanoseconds: judged as us, that is 0.1 Hz... refused
    ns = _write(tmp_path / "ns.csv", "time,ax,ay,az",
                [[str(t)] + c for t, c in zip(t_ns, _cells(counts, ".0f"), strict=True)])
    r = _run("fit", "--raw", ns)
    _one_line_error(r, "gives 0.1 Hz", "name its unit in the header: time_s, time_ms, time_us or time_ns")
    renamed = tmp_path / "renamed.csv"
    renamed.write_text(ns.read_text().replace("time,", "time_ns,", 1))
    r = _run("fit", "--raw", renamed, "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["inferred"]["rate_hz"] == pytest.approx(RATE)

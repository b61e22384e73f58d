"""Logs as captured (issue 50): a serial monitor's capture (banner, sensor description, header,
``>>> Place accelerometer ...`` prompts between the data) reads as is, with a note of the lines
skipped; damaged data rows are still refused by line; repeated samples (a host polling faster than
the chip updates) are detected and each pose's noise is judged on its distinct samples; the value
grid allows the printed decimals' rounding.  The captures are written by tests/serial_capture.py
from the project's forward simulator (an MMA8451, 0.244 mg per LSB, 18 poses); the referee is the
simulator's configured truth and the LSB of its data sheet (9.80665 / 4096 m/s^2), never the
program's output.  Fixed seeds: nothing here fails by chance."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from serial_capture import MPS2_PER_LSB, write

from accelcal_station.cli import cli
from accelcal_station.data.loader import load
from accelcal_station.data.rawlog import is_text, read_raw_log
from accelcal_station.data.sample_grid import distinct_samples, repeat_fraction, value_grid


def _fit(*args):
    return CliRunner().invoke(cli, ["fit", "--raw", *[str(a) for a in args]])


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return write(tmp_path_factory.mktemp("cap") / "fxos8700.txt", seed=1)


def test_a_serial_monitor_capture_reads_as_is_with_a_note(capture):
    path, run = capture
    lines = path.read_text().splitlines()
    assert lines[12] == "time_ms,ax,ay,az" and lines[13].startswith(">>> Place accelerometer")
    r = _fit(path)
    assert r.exit_code == 0, r.output
    read = r.output.splitlines()[0]
    assert "skipped 19 text lines among the data" in read and "line 14 '>>> Place accelerometer" in read
    assert "t = 'time_ms'" in read and "rate 100 Hz" in read
    js = json.loads(_fit(path, "--json").output)
    inf = js["inferred"]
    assert inf["text_lines_skipped"] == 19 and inf["text_lines"][0] == {"line": 14, "text": lines[13]}
    prompts = [i + 1 for i, s in enumerate(lines) if s.startswith(">>>")]
    assert [t["line"] for t in inf["text_lines"]] == prompts
    assert js["segmentation"]["count"] == 18
    truth = run.truth()  # the simulator's configured gains: 1.01, 0.995, 1.02 (W inverts them)
    assert np.allclose(np.diag(js["W"]), np.diag(truth.W), atol=2e-3)


def test_skip_rows_to_the_header_reads_the_same(capture):
    path, _ = capture
    a = json.loads(_fit(path, "--json").output)
    b = json.loads(_fit(path, "--json", "--skip-rows", "12").output)
    assert b["inferred"]["text_lines_skipped"] == 19
    assert a["W"] == b["W"] and a["segmentation"]["count"] == b["segmentation"]["count"] == 18


@pytest.mark.parametrize("bad, message", [
    ("150,0.213084,abc,10.441113", "column 3 (ay): 'abc' is not a number"),
    ("150,0.213084,-0.301669", "3 fields; expected 4"),
    ("150,0.21,,10.44", "column 3 (ay): '' is not a number"),
    ("nan,0.2,0.3,10.4", "allowed: a finite number"),
])
def test_a_damaged_data_row_is_still_refused_by_line(capture, tmp_path, bad, message):
    path, _ = capture
    lines = path.read_text().splitlines()
    lines.insert(500, bad)
    p = tmp_path / "damaged.txt"
    p.write_text("\n".join(lines) + "\n")
    r = _fit(p)
    assert r.exit_code == 2
    assert "line 501" in r.output and message in r.output, r.output


def test_the_rule_that_tells_prose_from_damaged_data():
    for prose in (">>> Place accelerometer flat, z up <<<", "Max Value:    78.4532 m/s^2", "time_ms,ax,ay,az",
                  "Sample 3 of 18, hold still"):
        assert is_text(prose.split(","), 4), prose
    for data in ("0.12,abc,9.81,1", "1,2", "0.12,,9.81,3", "nan,1,2,3", "1"):
        assert not is_text(data.split(","), 4), data


def test_repeated_samples_are_detected_and_noise_judged_on_distinct_samples(tmp_path):
    path, _ = write(tmp_path / "fast.txt", seed=2, repeat=4)
    log = read_raw_log(path)
    frac = repeat_fraction(log.xyz)
    assert 0.65 < frac < 0.8  # each conversion logged 3 to 5 times: 1 - 1/4 of the pairs repeat
    loaded = load(str(path), True)
    assert any("of consecutive samples repeat" in s for s in loaded.inferred)
    keep = distinct_samples(log.xyz)
    for p, seg in zip(loaded.session.poses, loaded.detection.segments, strict=True):
        distinct = sum(int(keep[a:b].sum()) for a, b in seg.ranges)
        assert p.n == distinct < seg.n / 3  # the standard error of the mean counts conversions, not polls
    # the data sheet's noise: 99 ug/sqrt(Hz) over the simulator's 100 Hz output (bandwidth 50 Hz) is
    # 0.70 mg per conversion; std / sqrt(n) of a pose is then 0.70 mg / sqrt(conversions)
    se_g = np.array([p.std / np.sqrt(p.n) for p in loaded.session.poses]) / 9.80665
    expect = 99e-6 * np.sqrt(50.0) / np.sqrt([[p.n] * 3 for p in loaded.session.poses])
    assert 0.7 < float(np.median(se_g / expect)) < 1.4


def test_the_value_grid_allows_the_printed_rounding(capture):
    path, _ = capture
    log = read_raw_log(path)
    assert log.info.decimals == {"x": 6, "y": 6, "z": 6}
    x = log.xyz[distinct_samples(log.xyz)]
    off = np.abs(x / MPS2_PER_LSB - np.round(x / MPS2_PER_LSB))
    assert off.max() < 3e-4  # every sample on the 0.244 mg grid to 3e-4 LSB after printing
    step = value_grid(x, log.info.decimals["x"])
    assert step == pytest.approx(MPS2_PER_LSB, rel=1e-6)
    assert value_grid(x) == 0.0  # an exact test (no rounding allowed) finds no grid: why decimals are kept
    assert value_grid(np.random.default_rng(0).normal(0, 1, 500), 6) == 0.0  # no grid at all
    assert value_grid(np.array([-8, 4, 12, 20, 36], float)) == 4.0  # counts: the exact gcd


def test_a_pose_table_with_a_banner_and_prompts_reads_with_a_note(tmp_path):
    body = ["pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z",
            ">>> Place the board x up, then press a key <<<", "xu,,,1.002,0.01,-0.02,1,0,0",
            "xd,,,-0.998,0.012,-0.018,-1,0,0", ">>> Place the board y up <<<", "yu,,,0.003,1.004,-0.02,0,1,0",
            "yd,,,0.001,-0.996,-0.021,0,-1,0", "zu,,,0.002,0.011,0.985,0,0,1", "zd,,,0.001,0.01,-1.025,0,0,-1"]
    p = tmp_path / "table.csv"
    p.write_text("\n".join(["MPU-9250 six-face table, saved from the serial monitor", "# units: g", *body]) + "\n")
    r = CliRunner().invoke(cli, ["fit", str(p), "--json"])
    assert r.exit_code == 0, r.output
    js = json.loads(r.output)
    assert [t["line"] for t in js["inferred"]["text_lines"]] == [1, 4, 7]
    assert js["units"] == "g" and js["pose_count"] == 6
    assert "skipped 3 text lines" in CliRunner().invoke(cli, ["fit", str(p)]).output
    p.write_text("\n".join(["# units: g", *body[:3], "xd,,,-0.998,abc,-0.018,-1,0,0", *body[4:]]) + "\n")
    r = CliRunner().invoke(cli, ["fit", str(p)])
    assert r.exit_code == 2 and "line 5" in r.output, r.output  # a damaged pose row is still an error by line

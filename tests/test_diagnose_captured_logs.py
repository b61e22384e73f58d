"""diagnose on logs as a test engineer captures them (issue 50): a serial-monitor capture in m/s^2
printed with 6 decimals (decimal rounding off the chip's 0.244 mg grid) whose host read 3-5 times per
chip update.  The value grid is found, the noise and the floor are judged on distinct samples at the
chip's rate, so the repeats neither halve the noise floor nor make a null board 'unexplained'.
The expected grid is the chip's data sheet's (14 bits at +-2 g: 1/4096 g), written here."""
from __future__ import annotations

import json

from click.testing import CliRunner
from serial_capture import write

from accelcal_station.cli import cli

LSB_MG = 1e3 / 4096


def _diagnose(path) -> dict:
    r = CliRunner().invoke(cli, ["diagnose", "--raw", "--units", "mps2", str(path), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_repeated_samples_and_decimal_rounding_in_a_captured_log(tmp_path):
    once, _ = write(tmp_path / "once.txt", seed=1, repeat=1)
    polled, _ = write(tmp_path / "polled.txt", seed=1, repeat=4)
    a, b = _diagnose(once), _diagnose(polled)
    for d in (a, b):
        q = d["stochastic"]["quantization"]
        assert "no common value grid" not in json.dumps(d)
        assert abs(q["lsb_mg"] - LSB_MG) < 1e-3 * LSB_MG, q
        ratio = d["stochastic"]["noise"]["evidence"]["ratio"] if "evidence" in d["stochastic"]["noise"] else None
        assert "1.0" in d["stochastic"]["noise"]["reason"] or "0.9" in d["stochastic"]["noise"]["reason"], \
            (d["stochastic"]["noise"]["reason"], ratio)
        assert d["verdict"] == "nothing to explain", d["verdict_text"]
    assert abs(b["floor_mg"] / a["floor_mg"] - 1) < 0.15, (a["floor_mg"], b["floor_mg"])  # not halved
    notes = json.dumps(b)
    assert "repeat the one before" in notes and "distinct samples" in notes

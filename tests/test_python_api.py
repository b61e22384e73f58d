"""The library face: docs/python-api.md's example runs as written, and the CLI gives the same numbers."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import accelcal_station
from accelcal_station import Calibration, diagnose, fit, load, simulate

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "python-api.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)


def test_the_documented_example_runs(tmp_path):
    """The example block, run from a copy of the repository's layout (configs/, examples/), in a
    fresh interpreter, as a notebook would; its own asserts check the physics."""
    blocks = _python_blocks()
    assert len(blocks) >= 2, "docs/python-api.md has its import line and an example"
    for folder in ("configs", "examples"):
        (tmp_path / folder).symlink_to(ROOT / folder)
    script = tmp_path / "example.py"
    script.write_text(blocks[-1])
    r = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    assert "leave-one-pose-out" in r.stdout and "gap" in r.stdout


def test_the_import_line_gives_the_documented_names():
    exec(_python_blocks()[0], {})  # the first block is the import line alone
    for name in ("load", "fit", "simulate", "diagnose", "Calibration"):
        assert name in accelcal_station.__all__
    with pytest.raises(AttributeError):
        _ = accelcal_station.no_such_name


def _cli(*args: str, cwd: Path) -> dict:
    r = subprocess.run([sys.executable, "-m", "accelcal_station", *args, "--json"], cwd=cwd, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return json.loads(r.stdout)


def test_fit_from_python_is_the_fit_the_command_prints(tmp_path):
    table = ROOT / "examples" / "poses.csv"
    js = _cli("fit", str(table), "--model", "15", cwd=tmp_path)
    f = fit(load(table), model=15)
    np.testing.assert_array_equal(np.asarray(js["W"]), f.calibration.W)
    np.testing.assert_array_equal(np.asarray(js["Gamma"]), f.calibration.Gamma)
    assert js["crossval_rms_g"] == f.result.crossval_rms_g


def test_simulate_from_python_writes_what_the_command_writes(tmp_path):
    """Same design, config and seed: the command's pose table holds the session the function returns."""
    out = tmp_path / "s.csv"
    _cli("simulate", "--config", str(ROOT / "configs" / "sim.yaml"), "--poses", "six-face", "--seed", "3",
         "--samples", "50", "--out", str(out), cwd=tmp_path)
    run = simulate("six-face", config=str(ROOT / "configs" / "sim.yaml"), seed=3, samples=50)
    written = load(out).session
    assert written.names == run.session.names
    np.testing.assert_allclose(written.readings, run.session.readings, rtol=0, atol=1e-6)


def test_diagnose_from_python_is_the_commands_verdict(tmp_path):
    table = str(ROOT / "examples" / "poses.csv")
    js = _cli("diagnose", table, cwd=tmp_path)
    d = diagnose([table])
    assert (d.verdict, d.selected) == (js["verdict"], js["selected"])
    assert d.gap_after == js["gap_after"]


def test_fit_refuses_counts_without_a_scale_naming_the_data():
    from accelcal_station.errors import UnitsError
    run = simulate("optimal-12", seed=2, samples=20)
    run.session.counts_per_g = None
    with pytest.raises(UnitsError, match="the data: readings are counts with no counts_per_g; model 12"):
        fit(run.session, model=12)
    assert isinstance(fit(run.session, model=9).calibration, Calibration)  # model 9 estimates the scale


@pytest.mark.parametrize("kwargs, words", [
    ({"temps_c": [float("nan")]}, "temps_c=[nan]; allowed: temperatures in C between -60 and 150"),
    ({"temps_c": [25.0, 25.0]}, "a temperature repeats"),
    ({"samples": 1}, "samples=1; allowed: a whole number from 2"),
    ({"move_s": float("inf")}, "move_s=inf; allowed: 0 to 3600 seconds"),
])
def test_simulate_refuses_what_the_command_refuses(kwargs, words):
    """A notebook gets the command's limits as one typed error, not a NaN std or a board at nan C."""
    from accelcal_station.errors import DataError
    with pytest.raises(DataError, match=re.escape(words)):
        simulate("six-face", **kwargs)

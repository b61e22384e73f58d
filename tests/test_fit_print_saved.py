"""One calibration object from fit to file: what `accelcal fit` prints (coefficients, residuals) is
computed from exactly the calibration it writes with -o, on every model and path: pose tables
(models 6, 9, 12, 15), a raw log (model 9 with a held term), hand-placed faces chosen from a raw
log (the real imucal session, where the printed face-axes fit once differed from the saved norm
fit) and --hand-placed on a pose table.

The saved file is read back with Calibration.load and applied to the readings as a user would;
the residuals it gives are compared with the printed ones, independently of the fitter.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.api import load
from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.fixtures.simulated_run import run_design, simulated_board

DATA = Path(__file__).parent / "data"


def _table(path: Path, design: str, seed: int = 4) -> Path:
    write_pose_table(run_design(simulated_board(str(default_config_path()), seed), design, samples=200).session, path)
    return path


def _raw_ten(path: Path) -> Path:
    from test_held_terms import FACES, TILTS, write_log

    return write_log(path, FACES + TILTS, 2)


CASES = {  # name: (make the file, fit arguments, norm-based residuals)
    "table model 6": (lambda d: _table(d / "six.csv", "six-face"), ["--model", "6"], False),
    "table model 12": (lambda d: _table(d / "cube.csv", "an4399-8"), ["--model", "12"], False),
    "table model 15": (lambda d: _table(d / "cube.csv", "an4399-8"), ["--model", "15"], False),
    "table model 9 (real, chosen)": (lambda d: DATA / "calibraxis_set_1.csv", [], True),
    "raw log model 9 with M_xy held": (lambda d: _raw_ten(d / "ten.csv"), ["--raw"], True),
    "raw log hand-placed faces (real, chosen)": (lambda d: DATA / "imucal_annotated_session.csv", ["--raw"], True),
    "table --hand-placed": (lambda d: DATA / "nine_position_paper_faces.csv", ["--hand-placed"], True),
}


def _printed(text: str) -> dict[str, np.ndarray | float]:
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("W     = "))
    rows = [re.findall(r"[-+]\d+\.\d+", ln) for ln in lines[i:i + 3]]
    vec = {name: np.array(re.findall(r"[-+]\d+\.\d+", next(ln for ln in lines if ln.startswith(name))), float)
           for name in ("V     = ", "Gamma = ")}
    rms = float(re.search(r"residual RMS (\d+\.\d+) mg", text).group(1))
    return {"W": np.array(rows, float), "V": vec["V     = "], "Gamma": vec["Gamma = "], "rms_mg": rms}


@pytest.mark.parametrize("case", list(CASES))
def test_printed_numbers_are_the_saved_calibrations(case, tmp_path):
    make, args, by_norm = CASES[case]
    path = make(tmp_path)
    out, out_js = tmp_path / "cal.json", tmp_path / "cal_js.json"
    text = CliRunner().invoke(cli, ["fit", str(path), *args, "-o", str(out)])
    assert text.exit_code == 0, text.output
    js_run = CliRunner().invoke(cli, ["fit", str(path), *args, "--json", "-o", str(out_js)])
    assert js_run.exit_code == 0, js_run.output
    js = json.loads(js_run.output)
    cal = Calibration.load(out)
    assert json.loads(out.read_text())["W"] == json.loads(out_js.read_text())["W"]
    shown = _printed(text.output)
    for k in ("W", "V", "Gamma"):  # printed to 6 decimals, the JSON exactly
        np.testing.assert_allclose(shown[k], getattr(cal, k), rtol=0, atol=5.1e-7, err_msg=k)
        np.testing.assert_array_equal(np.asarray(js[k]), getattr(cal, k), err_msg=k)
    session = load(path, "--raw" in args).session  # read as fit reads it
    g = cal.apply(session.readings, session.units)
    if by_norm:  # norm-based fits: |calibrated| - the site's gravity in standard g (1 without a stated one)
        err = np.linalg.norm(g, axis=1) - session.site_gravity_g
        np.testing.assert_allclose([p["norm_error_g"] for p in js["poses"]], err, rtol=0, atol=1e-9)
        rms = float(np.sqrt(np.mean(err**2)))
    else:
        rms = float(np.sqrt(np.mean((session.references_g - g) ** 2)))
    assert shown["rms_mg"] == pytest.approx(rms * 1e3, abs=0.0006), (shown["rms_mg"], rms * 1e3)
    assert js["residual_rms_g"] == pytest.approx(rms, rel=1e-9, abs=1e-12)

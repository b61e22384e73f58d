"""The default model cannot be far wrong (issue 50): the choice judges what the design determines
from the references, never from readings an offset has moved, and a richer model whose held-out
figure is worse than the simpler one's beyond their scatter is not chosen (models/choice.py).

The tables come from the project's forward simulator (drivers.simulated.SimulatedBoard through the
simulated jig: an MPU-6050 at its data sheet's 400 ug/sqrt(Hz) noise, 1-LSB quantization), with a
0.25 g offset on z as on the public MPU-9250 six-face table whose z reads +0.77 / -1.27 g.  The
referee is the simulator's own truth (board.truth(): its configured offsets, gains and couplings),
not the fitted model.  Fixed seeds; the fits are deterministic given the table, so these tests
cannot fail by chance.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_design, run_poses
from accelcal_station.models.choice import choose_model

OFFSET_MG = [60.0, -80.0, -250.0]  # z reads +0.75 / -1.25 g on its faces


def _board(seed: int, cubic: list[float] | None = None) -> SimulatedBoard:
    effects = {"offset": {"offset_mg": OFFSET_MG}, "gain": {"gain": [1.004, 0.997, 1.012]},
               "cross_axis": {"coupling": [[0.0, 0.005, 0.002], [0.005, 0.0, -0.003], [0.002, -0.003, 0.0]]},
               "noise": {"density_ug_per_rthz": [400.0] * 3}, "quantization": {"lsb_counts": 1}}
    if cubic is not None:
        effects["cubic"] = {"cubic_per_g2": cubic}
    return SimulatedBoard.from_config({"chip": "mpu6050", "simulator": {"effects": effects}}, seed=seed)


def _table(tmp_path, design: str, seed: int, cubic: list[float] | None = None):
    run = run_design(_board(seed, cubic), design, samples=200)
    path = tmp_path / f"{design}-{seed}.csv"
    write_pose_table(run.session, path)
    return path, run


def _fit(*args):
    return CliRunner().invoke(cli, ["fit", *[str(a) for a in args]])


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_six_faces_with_a_quarter_g_offset_default_to_model_12(tmp_path, seed):
    path, run = _table(tmp_path, "six-face", seed)
    g = run.session.readings_g()
    assert g[:, 2].max() < 0.8 and g[:, 2].min() < -1.2  # the offset has moved z off +-1 g, as on the public table
    out = tmp_path / "cal.json"
    r = _fit(path, "--json", "-o", out)
    assert r.exit_code == 0, r.output
    js = json.loads(r.output)
    assert js["model"] == "12" and js["model_choice"]["judged_on"] == "references"
    assert "do not determine model 15's cubic" in js["model_choice"]["reason"]
    twelve = json.loads(_fit(path, "--json", "--model", "12").output)
    assert js["crossval_rms_g"] == twelve["crossval_rms_g"]
    saved = json.loads(out.read_text())
    truth = run.truth()
    # the written calibration against the simulator's truth: offset to 1 mg, gains and couplings to 0.2 %
    assert np.allclose(saved["V"], truth.V, atol=1e-3), (saved["V"], truth.V)
    assert np.allclose(saved["W"], truth.W, atol=2e-3)
    assert js["crossval_rms_g"] < 2e-3  # a few tenths of a mg of noise, nothing like the cubic's hundreds
    # the cubic a readings-based judgement would have fitted: not determined by the faces, so not chosen
    forced = json.loads(_fit(path, "--json", "--model", "15").output)
    assert forced["crossval_rms_g"] is None or forced["crossval_rms_g"] > 10 * js["crossval_rms_g"]


def test_text_says_model_12_and_why(tmp_path):
    path, _ = _table(tmp_path, "six-face", 3)
    r = _fit(path)
    assert r.exit_code == 0, r.output
    assert "model 12" in r.output.splitlines()[1] and "every reference is about +-1 g or 0" in r.output
    assert "barely determined" not in r.output


@pytest.mark.parametrize("design", ["an4399-8", "optimal-12"])
def test_designs_that_determine_a_real_cubic_still_get_model_15(tmp_path, design):
    cubic = [0.01, -0.02, 0.015]  # 10-20 mg at 1 g: model 12 cannot absorb it at intermediate tilts
    path, run = _table(tmp_path, design, 7, cubic)
    js = json.loads(_fit(path, "--json").output)
    assert js["model"] == "15", js["model_choice"]
    c = js["model_choice"]["compared"]
    assert c["richer"] == "15" and not c["richer_worse"] and c["richer_rms_g"] < c["simpler_rms_g"]
    assert np.allclose(js["Gamma"], run.truth().Gamma, atol=2e-3)


def _loo_rms(g, ref, cubic):
    """Leave-one-pose-out RMS of AN4399's least squares per channel, by numpy's lstsq (independent of the
    station's fitters): regressors [g, 1] (model 12) and g_c^3 (model 15)."""
    err = []
    for i in range(len(g)):
        keep = np.arange(len(g)) != i
        for c in range(3):
            X = np.column_stack([g, np.ones(len(g))] + ([g[:, c] ** 3] if cubic else []))
            beta = np.linalg.lstsq(X[keep], ref[keep, c], rcond=None)[0]
            err.append(ref[i, c] - X[i] @ beta)
    return float(np.sqrt(np.mean(np.square(err))))


def test_a_richer_model_far_worse_held_out_is_not_chosen():
    """Six faces and two 45-degree tilts (x-z, y-z): the references determine the cubic, barely (a
    fourth level per axis); on this board (seed 3, no cubic) model 15's held-out RMS is over three
    times model 12's, so the default is 12 and says why."""
    poses = [PoseSpec(*p) for p in (("x+1g", -90, 0), ("x-1g", 90, 0), ("y+1g", 0, 90), ("y-1g", 0, -90),
                                     ("z+1g", 0, 0), ("z-1g", 0, 180), ("xz+", -45, 0), ("yz+", 0, 45))]
    session = run_poses(_board(3), poses, "eight", samples=200).session
    g, ref = session.readings_g(), session.references_g
    loo12, loo15 = _loo_rms(g, ref, False), _loo_rms(g, ref, True)
    assert loo15 > 3 * loo12  # the case, computed independently
    c = choose_model(session)
    assert c.model == "12" and "worse held out" in c.reason
    assert c.compared is not None
    assert c.compared.rms_a_g == pytest.approx(loo12, rel=1e-6) and c.compared.rms_b_g == pytest.approx(loo15, rel=1e-3)

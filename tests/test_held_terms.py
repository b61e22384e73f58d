"""Fit what the poses determine, hold the rest at nominal (models/held.py), and say so.

The ten-pose log is simulated by the project's forward simulator (the default sim.yaml
board: offset, gain, full cross-axis, noise, quantisation) through the simulated jig:
six faces and four tilts, each tilt in the x-z or y-z plane, so no pose tilts x and y
together.  The unconstrained reference fit is scipy.optimize.least_squares on the
norm residual, code independent of the station's Levenberg-Marquardt.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import least_squares

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board

FACES = [("x+1g", -90.0, 0.0), ("x-1g", 90.0, 0.0), ("y+1g", 0.0, 90.0), ("y-1g", 0.0, -90.0),
         ("z+1g", 0.0, 0.0), ("z-1g", 0.0, 180.0)]
TILTS = [("xz+", -45.0, 0.0), ("xz-", 45.0, 180.0), ("yz+", 0.0, 45.0), ("yz-", 0.0, -135.0)]
XY = [("xy", -45.0, 90.0)]  # reads 1/sqrt(2) g on x and on y: between +x and +y


def write_log(path, poses, seed=3):
    run = run_poses(simulated_board(str(default_config_path()), seed), [PoseSpec(*p) for p in poses], "test",
                    samples=400, raw=True, move_s=1.0)
    (t, c), _ = run.raw_table()
    rows = "\n".join(f"{a:.5f},{int(x)},{int(y)},{int(z)}" for a, (x, y, z) in zip(t, c, strict=True))
    path.write_text("t,x,y,z\n" + rows + "\n")
    return path


def _fit_json(path, *more):
    r = CliRunner().invoke(cli, ["fit", "--raw", str(path), "--json", *more])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def _norm_residual(p, x):
    M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    return np.linalg.norm((x - p[6:]) @ M.T, axis=1) - 1.0


def _unconstrained_loo(x):
    """Leave-one-pose-out RMS norm error of the free 9-parameter norm fit (scipy, trust region)."""
    p0 = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float)
    e = [_norm_residual(least_squares(_norm_residual, p0, args=(np.delete(x, i, 0),), xtol=1e-12,
                                      ftol=1e-12, gtol=1e-12, method="lm").x, x[i:i + 1])[0] for i in range(len(x))]
    return float(np.sqrt(np.mean(np.square(e))))


SEEDS = range(1, 9)  # eight boards: one board's ten-pose LOO scatters by +-40 % between fits (noise only)


@pytest.fixture(scope="module")
def tens(tmp_path_factory):
    d = tmp_path_factory.mktemp("held")
    return [write_log(d / f"ten{s}.csv", FACES + TILTS, s) for s in SEEDS]


@pytest.fixture(scope="module")
def ten(tens):
    return tens[0]


def test_ten_pose_log_holds_xy_and_says_so(ten, tmp_path):
    js = _fit_json(ten, "-o", str(tmp_path / "cal.json"))
    assert js["model"] == "9"
    assert [h["term"] for h in js["held"]] == ["M_xy"]
    assert "x-y non-orthogonality held at 0" in js["held"][0]["reason"]
    assert "between +x and +y" in js["held"][0]["hint"]
    assert js["W"][0][1] == 0.0 and js["stderr"]["W"][0][1] == 0.0  # held: nominal value, zero variance
    stored = json.loads((tmp_path / "cal.json").read_text())
    assert stored["metadata"]["held"][0]["term"] == "M_xy"
    r = CliRunner().invoke(cli, ["fit", "--raw", str(ten)])
    assert "held: x-y non-orthogonality held at 0: no pose tilts x and y together (standard error at the data's " \
           "noise" in r.output and "not below its prior +-0.02); add a pose between +x and +y" in r.output


def test_held_loo_within_ten_percent_of_the_free_fit(tens):
    """Pooled over eight boards (RMS of the per-board leave-one-pose-out RMS), holding M_xy costs at most
    10 % against the free fit on the same poses (measured: 0.101 mg against 0.114 mg; the held fit is
    the better one, the free fit spends a parameter on noise).  Deterministic: fixed seeds."""
    held, free = [], []
    for path in tens:
        js = _fit_json(path)
        assert [h["term"] for h in js["held"]] == ["M_xy"]
        held.append(js["crossval_rms_g"])
        free.append(_unconstrained_loo(np.array([p["reading_g"] for p in js["poses"]])))
    pooled_held, pooled_free = np.sqrt(np.mean(np.square(held))), np.sqrt(np.mean(np.square(free)))
    assert pooled_held <= 1.10 * pooled_free, (pooled_held, pooled_free)


def test_a_pose_between_x_and_y_holds_nothing(tmp_path):
    js = _fit_json(write_log(tmp_path / "eleven.csv", FACES + TILTS + XY))
    assert js["model"] == "9" and js["held"] == []
    assert js["W"][0][1] != 0.0 and js["stderr"]["W"][0][1] > 0  # the hint, followed, determines it


def test_the_acceptance_verdict_carries_what_was_held(ten):
    from accelcal_station.acceptance.rules import Limits, judge
    from accelcal_station.api import fit, load

    v = judge(fit(load(ten, True)).result, Limits.from_config({"residual_rms_mg": 5.0}))
    assert len(v.held) == 1 and v.held[0].startswith("x-y non-orthogonality held at 0: no pose tilts x and y "
                                                     "together (standard error at the data's noise +-")
    assert v.held[0].endswith("not below its prior +-0.02); add a pose between +x and +y to determine it")


def test_model_15_on_faces_holds_the_cubic_and_fits_the_rest():
    """Six faces (every reading about +-1 g or 0) cannot tell a cubic from the gain: --model 15 keeps
    model 12's determined terms and holds the cubic at 0, named, instead of refusing."""
    from pathlib import Path

    table = Path(__file__).parent / "data" / "nine_position_paper_faces.csv"
    r15 = CliRunner().invoke(cli, ["fit", str(table), "--model", "15", "--json"])
    r12 = CliRunner().invoke(cli, ["fit", str(table), "--model", "12", "--json"])
    j15, j12 = json.loads(r15.stdout), json.loads(r12.stdout)
    assert j15["model"] == "15" and [h["term"] for h in j15["held"]] == ["Gamma_xx", "Gamma_yy", "Gamma_zz"]
    assert j15["Gamma"] == [0.0, 0.0, 0.0] and j15["stderr"]["Gamma"] == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(j15["W"], j12["W"], rtol=0, atol=1e-12)
    assert "intermediate tilts" in j15["held"][0]["hint"]

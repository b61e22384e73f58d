"""Hold decisions checked by held-out data (issue 50, models/held.confirm_holds): the noise rule
proposes holding a non-orthogonality; the fits with it held and free are each left out one
orientation at a time, and where holding is worse beyond the orientations' own scatter the term is
fitted freely and the summary says why (``freed``).

The pose tables come from the project's forward simulator (an MPU-6050 at its data sheet's
400 ug/sqrt(Hz), 400 samples a pose, hand-placed on six faces and four tilts a few degrees out of
the x-z and y-z planes: tests/test_held_noise.py's geometry).  Each table's std columns are 16 times
the samples' spread, as a bench vibration makes them: the samples scatter widely but the
vibration averages out of the pose means, so std / sqrt(n) overstates their noise and the noise rule
(standard error +-0.026 against the 0.02 prior) proposes holding M_xy.  With a 4 % x-y coupling
the held-out data contradict it on seeds 3 and 5 (the held fit is four times worse on the tilts),
while on seeds 1, 2, 4, 6 leaving a +-x face out leaves the free fit poorly determined, so the
held-out data do not overrule the hold; with no coupling the hold stands on every seed.  The
referee for the freed term is the simulator's truth, and for the free fit's held-out figure
scipy's least squares (test_held_noise.free_loo), independent of the station's fitters.  Fixed
seeds: nothing here fails by chance.
"""
from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
from click.testing import CliRunner
from test_held_noise import NOMINAL, OFF_DEG, free_loo

from accelcal_station.cli import cli
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses
from accelcal_station.models.held import PRIOR_SD_NONORTHO, hold_plans
from accelcal_station.session import Session

POSES = [PoseSpec(n, p + a, r + b) for (n, p, r), (a, b) in zip(NOMINAL, OFF_DEG, strict=True)]
VIBRATION = 16.0  # the stated std over the samples' own (module doc)


def _table(tmp_path, seed: int, coupling: float):
    board = SimulatedBoard.from_config({"chip": "mpu6050", "simulator": {"effects": {
        "offset": {"offset_mg": [35.0, -52.0, 78.0]}, "gain": {"gain": [1.011, 0.992, 1.018]},
        "cross_axis": {"coupling": [[0.0, coupling, 0.0], [coupling, 0.0, 0.0], [0.0, 0.0, 0.0]]},
        "noise": {"density_ug_per_rthz": [400.0] * 3}, "quantization": {"lsb_counts": 1}}}}, seed=seed)
    run = run_poses(board, POSES, "ten-pose", samples=400)
    s = run.session
    poses = [replace(p, std=p.std * VIBRATION, reference_g=None, pitch_deg=None, roll_deg=None) for p in s.poses]
    table = Session(poses, s.units, s.counts_per_g, s.gravity_mps2, s.device)
    path = tmp_path / f"ten-{seed}-{coupling}.csv"
    write_pose_table(table, path)
    return path, table, run


def _proposed_se(table: Session) -> float:
    g, nz = table.readings / table.input_per_g, table.noise() / table.input_per_g
    plan = hold_plans(g[None], "9", nz[None])
    assert [h.term for h in plan.held[0]] == ["M_xy"]
    return plan.se[0]["M_xy"]


@pytest.mark.parametrize("seed", [3, 5])
def test_a_hold_the_held_out_data_contradict_is_fitted_and_said(tmp_path, seed):
    path, table, run = _table(tmp_path, seed, 0.04)
    se = _proposed_se(table)
    assert PRIOR_SD_NONORTHO <= se < 2 * PRIOR_SD_NONORTHO  # the noise rule proposes the hold
    r = CliRunner().invoke(cli, ["fit", str(path), "--json"])
    assert r.exit_code == 0, r.output
    js = json.loads(r.output)
    assert js["model"] == "9" and js["held"] == [] and js["model_choice"]["held"] == []
    (freed,) = js["freed"]
    assert freed["term"] == "M_xy" and "fitted freely" in freed["reason"] and "worse beyond" in freed["reason"]
    # the simulator's 4 %; the tolerance 0.005 scaled with the per-sample noise, sqrt(pi / 2) larger since
    # the MPU6050's noise follows the DLPF's equivalent noise bandwidth (tests/test_mpu6050_bandwidth.py)
    assert js["params"]["M_xy"] == pytest.approx(run.truth().W[0, 1], abs=0.005 * math.sqrt(math.pi / 2))
    x = table.readings / table.input_per_g
    assert js["crossval_rms_g"] == pytest.approx(free_loo(x), rel=0.05)  # scipy's free fit, left out by pose
    text = CliRunner().invoke(cli, ["fit", str(path)]).output
    assert "freed: x-y non-orthogonality fitted freely: the noise rule would hold it" in text


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_hold_the_held_out_data_confirm_still_holds(tmp_path, seed):
    path, table, _ = _table(tmp_path, seed, 0.0)
    _proposed_se(table)
    js = json.loads(CliRunner().invoke(cli, ["fit", str(path), "--json"]).output)
    assert [h["term"] for h in js["held"]] == ["M_xy"] and js["freed"] == []
    assert js["params"]["M_xy"] == 0.0

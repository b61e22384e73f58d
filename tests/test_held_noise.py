"""Hold a term by what the data determine (models/held.py): the noise decides, not the geometry alone.

The logs come from the project's forward simulator (sim/sensor_model.py through
drivers.simulated.SimulatedBoard and the simulated jig), not from the fitted model's terms: an
MPU-6050 (data-sheet 16384 LSB/g, 400 ug/sqrt(Hz) noise, DLPF 44 Hz: ENBW pi/2 x 44 Hz) with offsets, gains and a 1 %
x-y cross-axis coupling, placed by hand on six faces and four tilts in the x-z and y-z planes, a
few degrees off each (so the tilts lean a little out of their planes, as a real one does:
the x-y direction is weak in geometry, relative singular value 0.038, below the 0.05 the geometric
rule held it at), 400 samples a pose.
At the data sheet's noise the data pin M_xy to about +-0.001, far below its prior (+-0.02), so it
is fitted freely; at 20 times the noise its standard error (about +-0.03) is above the prior, so it
is held.  The free reference fit is scipy.optimize.least_squares on the norm residual, code
independent of the station's fitters; leave-one-out with one spare orientation scatters widely
from board to board, so figures are pooled over boards (RMS of the per-board RMS), fixed seeds.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import least_squares

from accelcal_station.cli import cli
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses

NOMINAL = [("x+1g", -90, 0), ("x-1g", 90, 0), ("y+1g", 0, 90), ("y-1g", 0, -90), ("z+1g", 0, 0), ("z-1g", 0, 180),
           ("xz+", -45, 0), ("xz-", 45, 180), ("yz+", 0, 45), ("yz-", 0, -135)]
# hand placement: pitch and roll off by a degree or three (fixed, so every board has the same geometry)
OFF_DEG = [(2.25, 3.0), (-3.0, -2.25), (2.25, -2.25), (-3.0, 3.0), (1.5, -2.25), (-2.25, -2.25), (0.0, 4.5),
           (-1.5, -4.5), (3.75, 0.0), (-4.5, 1.5)]
POSES = [PoseSpec(n, p + a, r + b) for (n, p, r), (a, b) in zip(NOMINAL, OFF_DEG, strict=True)]
MPU6050_DENSITY_UG = 400.0  # MPU-6050 product specification: accelerometer noise density
SEEDS = range(1, 9)


def _board(seed: int, density: float) -> SimulatedBoard:
    return SimulatedBoard.from_config({"chip": "mpu6050", "simulator": {"effects": {
        "offset": {"offset_mg": [35.0, -52.0, 78.0]}, "gain": {"gain": [1.011, 0.992, 1.018]},
        "cross_axis": {"coupling": [[0.0, 0.01, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, 0.0]]},
        "noise": {"density_ug_per_rthz": [density] * 3}, "quantization": {"lsb_counts": 1}}}}, seed=seed)


def write_log(path, seed: int, noise_factor: float):
    # moves of 0.1 s: at 20x the noise a slower move hides inside a 0.1 s window's noise
    run = run_poses(_board(seed, MPU6050_DENSITY_UG * noise_factor), POSES, "mpu6050-ten", samples=400, raw=True,
                    move_s=1.0 if noise_factor == 1 else 0.1)
    (t, c), _ = run.raw_table()
    path.write_text("t,x,y,z\n" + "\n".join(f"{a:.5f},{int(x)},{int(y)},{int(z)}"
                                            for a, (x, y, z) in zip(t, c, strict=True)) + "\n")
    return path


def _fit(path):
    r = CliRunner().invoke(cli, ["fit", "--raw", str(path), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def _norm_residual(p, x):
    M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    return np.linalg.norm((x - p[6:]) @ M.T, axis=1) - 1.0


def free_loo(x):
    """Leave-one-pose-out RMS norm error of the free 9-parameter norm fit (scipy, Levenberg-Marquardt)."""
    p0 = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float)
    e = [_norm_residual(least_squares(_norm_residual, p0, args=(np.delete(x, i, 0),), xtol=1e-12, ftol=1e-12,
                                      gtol=1e-12, method="lm").x, x[i:i + 1])[0] for i in range(len(x))]
    return float(np.sqrt(np.mean(np.square(e))))


def _pooled(v):
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    d = tmp_path_factory.mktemp("held_noise")
    return {k: [_fit(write_log(d / f"n{k}_{s}.csv", s, k)) for s in SEEDS] for k in (1, 20)}


def test_the_geometry_is_weak_in_x_y():
    """The design is the weak one of the issue: the distinct orientations' relative singular value of
    model 9's design (unnormalised, as models/held.py judges it) is below REL_SV_MIN, so a rule by
    geometry alone holds M_xy whatever the noise."""
    from accelcal_station.identifiability import REL_SV_MIN, _design

    pitch, roll = np.radians([p.pitch_deg for p in POSES]), np.radians([p.roll_deg for p in POSES])
    r = np.stack([-np.sin(pitch), np.cos(pitch) * np.sin(roll), np.cos(pitch) * np.cos(roll)], axis=1)
    s = np.linalg.svd(_design(r[None], "9")[0, 0], compute_uv=False)
    assert 0.01 < s[-1] / s[0] < REL_SV_MIN


def test_at_the_data_sheet_noise_xy_is_fitted_freely_and_loo_matches_the_free_fit(fits):
    ours, free = [], []
    for js in fits[1]:
        assert js["model"] == "9" and js["held"] == [], js["held"]
        assert abs(js["W"][0][1]) > 0 and 0 < js["stderr"]["W"][0][1] < 0.02  # fitted, to better than its prior
        ours.append(js["crossval_rms_g"])
        free.append(free_loo(np.array([p["reading_g"] for p in js["poses"]])))
    assert abs(_pooled(ours) - _pooled(free)) <= 0.10 * _pooled(free), (_pooled(ours), _pooled(free))


def test_at_twenty_times_the_noise_xy_is_held_and_loo_is_no_worse_than_the_free_fit(fits):
    """The noise rule proposes holding M_xy on every board; the held-out data confirm the hold on all
    but at most two (seed 8 alone at the per-sample noise of density x sqrt(44 Hz), before the
    MPU6050's noise followed the DLPF's equivalent noise bandwidth: its held fit 3.7 mg left out
    against the free fit's 0.53 mg), whose hold is then fitted freely and said, its held-out figure
    scipy's free fit's (issue 50: holds checked by held-out data; before, every board held)."""
    ours, free = [], []
    assert sum(bool(js["freed"]) for js in fits[20]) <= 2
    for js in fits[20]:
        loo_free = free_loo(np.array([p["reading_g"] for p in js["poses"]]))
        if js["freed"]:
            assert js["held"] == [] and [h["term"] for h in js["freed"]] == ["M_xy"], js["freed"]
            assert "the noise rule would hold it" in js["freed"][0]["reason"]
            assert js["crossval_rms_g"] == pytest.approx(loo_free, rel=0.01)
        else:
            assert [h["term"] for h in js["held"]] == ["M_xy"], js["held"]
            reason = js["held"][0]["reason"]
            assert "standard error at the data's noise" in reason and "prior +-0.02" in reason
            assert js["W"][0][1] == 0.0 and js["stderr"]["W"][0][1] == 0.0
        ours.append(js["crossval_rms_g"])
        free.append(loo_free)
    assert _pooled(ours) <= _pooled(free), (_pooled(ours), _pooled(free))

"""Cross-validation by orientation (models/crossval.py): every pose of one distinct orientation
left out at a time, beside leave-one-pose-out, in `fit --json`, the summary line, acceptance,
`accelcal batch` and lot results.

The board is the project's forward simulator (default sim.yaml board) through the simulated jig on
AN4399's eight cube-vertex poses with the first revisited six times and the second twice (16
poses, 8 orientations), as a log with revisits does.  The reference figure is computed here by
numpy's least squares (AN4399 Eqn 46: [g 1] B = reference per channel), code independent of the
station's fitters.
"""
from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board
from accelcal_station.models.crossval import orientation_labels

CUBE = get_design("an4399-8")
REVISITS = CUBE + [CUBE[0]] * 6 + [CUBE[1]] * 2


def _table(path, poses, seed=7):
    run = run_poses(simulated_board(str(default_config_path()), seed), list(poses), "revisits", samples=100)
    write_pose_table(run.session, path)
    return path


def _fit(path, *more):
    r = CliRunner().invoke(cli, ["fit", str(path), "--model", "12", *more])
    assert r.exit_code == 0, r.output
    return r


def _by_orientation_numpy(x, ref, groups):
    """RMS over every left-out reading and axis of ref - [g 1] B, B fitted without its orientation."""
    err = []
    for g in np.unique(groups):
        out = groups == g
        X = np.c_[x[~out], np.ones((~out).sum())]
        B, *_ = np.linalg.lstsq(X, ref[~out], rcond=None)
        err.append(ref[out] - np.c_[x[out], np.ones(out.sum())] @ B)
    return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))


@pytest.fixture(scope="module")
def revisits(tmp_path_factory):
    return _table(tmp_path_factory.mktemp("cv") / "revisits.csv", REVISITS)


def test_revisits_are_grouped_and_left_out_together(revisits):
    js = json.loads(_fit(revisits, "--json").output)
    x = np.array([p["reading_g"] for p in js["poses"]])
    ref = np.array([p.reference_g for p in REVISITS])
    groups = orientation_labels(x[None])[0]
    assert groups.tolist() == [0, 1, 2, 3, 4, 5, 6, 7] + [0] * 6 + [1] * 2
    assert js["distinct_orientations"] == 8
    expect = _by_orientation_numpy(x, ref, groups)
    assert js["crossval_by_orientation_rms_g"] == pytest.approx(expect, rel=1e-9)
    # leaving one pose out keeps its twins in: optimistic against leaving the orientation out
    assert js["crossval_by_orientation_rms_g"] > js["crossval_rms_g"]


def test_without_revisits_the_two_figures_are_one(tmp_path):
    js = json.loads(_fit(_table(tmp_path / "cube.csv", CUBE), "--json").output)
    assert js["distinct_orientations"] == 8
    assert js["crossval_by_orientation_rms_g"] == js["crossval_rms_g"]


def test_the_summary_line_says_which_figure_acceptance_judges(revisits, tmp_path):
    text = _fit(revisits).output
    line = next(ln for ln in text.splitlines() if ln.startswith("residual RMS"))
    assert "leave-one-orientation-out RMS" in line and "8 distinct orientations among 16 poses" in line
    assert "acceptance judges by orientation" in line
    once = _fit(_table(tmp_path / "cube.csv", CUBE)).output
    assert "no orientation revisited: acceptance judges this" in once


def test_acceptance_judges_the_by_orientation_figure_where_orientations_repeat(revisits):
    from accelcal_station.acceptance.rules import Limits, judge, measure
    from accelcal_station.api import fit, load

    fr = fit(load(revisits), model=12).result
    assert measure(fr)["crossval_rms_mg"] == pytest.approx(fr.crossval_by_orientation_rms_g * 1e3, rel=1e-12)
    between = 1e3 * (fr.crossval_rms_g + fr.crossval_by_orientation_rms_g) / 2  # passes LOO, fails by orientation
    v = judge(fr, Limits.from_config({"crossval_rms_mg": between}))
    assert not v.passed and any(r.code == "crossval_rms_mg" for r in v.reasons)


def test_batch_and_lot_results_carry_the_by_orientation_figure(revisits, tmp_path):
    js = json.loads(_fit(revisits, "--json").output)
    out = tmp_path / "summary.csv"
    r = CliRunner().invoke(cli, ["batch", str(revisits), "--model", "12", "--csv", str(out)])
    assert r.exit_code == 0, r.output
    row = next(csv.DictReader(io.StringIO(out.read_text())))
    assert float(row["crossval_by_orientation_rms_mg"]) == pytest.approx(js["crossval_by_orientation_rms_g"] * 1e3,
                                                                         rel=1e-12)
    lines = revisits.read_text().splitlines()
    body = [ln for ln in lines if not ln.startswith("#")]
    lot = tmp_path / "lot.csv"
    lot.write_text("\n".join([ln for ln in lines if ln.startswith(("# units:", "# counts_per_g:"))]
                             + ["serial," + body[0]] + [f"SN1,{ln}" for ln in body[1:]]) + "\n")
    res = tmp_path / "results.csv"
    r = CliRunner().invoke(cli, ["batch", str(lot), "--model", "12", "--out", str(res)])
    assert r.exit_code == 0, r.output
    got = next(csv.DictReader(io.StringIO(res.read_text())))
    assert float(got["crossval_by_orientation_rms_mg"]) == pytest.approx(js["crossval_by_orientation_rms_g"] * 1e3,
                                                                         rel=1e-9)

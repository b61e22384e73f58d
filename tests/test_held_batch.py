"""Held terms through every path: the one-board fit, `accelcal batch` on pose tables, a lot file
and the results store give the same held terms and the same parameters (models/held.py).

The boards are the project's forward simulator (default sim.yaml board: offset, gain, full
cross-axis, noise, quantisation) through the simulated jig, on the ten-pose design of issue 22
(six faces and four tilts, every tilt in the x-z or y-z plane: no pose tilts x and y together),
and one board with an eleventh pose between +x and +y, which determines M_xy and holds nothing.
"""
from __future__ import annotations

import csv
import io
import json
import sqlite3

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board
from accelcal_station.models.gravity_norm import PARAM_NAMES, fit_norm_batch, nominal_scale
from accelcal_station.models.held import hold_plans
from accelcal_station.models.stacked import fit_stacked

FACES = [("x+1g", -90.0, 0.0), ("x-1g", 90.0, 0.0), ("y+1g", 0.0, 90.0), ("y-1g", 0.0, -90.0),
         ("z+1g", 0.0, 0.0), ("z-1g", 0.0, 180.0)]
TILTS = [("xz+", -45.0, 0.0), ("xz-", 45.0, 180.0), ("yz+", 0.0, 45.0), ("yz-", 0.0, -135.0)]
XY = [("xy", -45.0, 90.0)]  # 1/sqrt(2) g on x and on y: between +x and +y
TEN_SEEDS = (1, 2, 3, 4)
ELEVEN_SEED = 5
HELD_START = "x-y non-orthogonality held at 0: no pose tilts x and y together ("  # then its standard error
HELD_END = ("not below its prior +-0.02); "
             "add a pose between +x and +y to determine it")


def _run(seed, poses):
    return run_poses(simulated_board(str(default_config_path()), seed), [PoseSpec(*p) for p in poses], "test",
                     samples=200)


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    """Five pose tables (four ten-pose boards, one eleven-pose board) and the lot file of the same poses."""
    d = tmp_path_factory.mktemp("held_batch")
    tables = []
    for seed, poses in [(s, FACES + TILTS) for s in TEN_SEEDS] + [(ELEVEN_SEED, FACES + TILTS + XY)]:
        path = d / f"board{seed}.csv"
        write_pose_table(_run(seed, poses).session, path, {"serial": f"SN{seed}"})
        tables.append(path)
    meta, rows = [], []
    for k, path in enumerate(tables):
        lines = path.read_text().splitlines()
        body = [ln for ln in lines if not ln.startswith("#")]
        if k == 0:
            meta = [ln for ln in lines if ln.startswith(("# units:", "# counts_per_g:"))]
            rows.append("serial," + body[0])
        rows += [f"SN{path.stem[5:]},{ln}" for ln in body[1:]]
    lot = d / "lot.csv"
    lot.write_text("\n".join(meta + rows) + "\n")
    return tables, lot


def _fit(table):
    r = CliRunner().invoke(cli, ["fit", str(table), "--model", "9", "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def _params(W, V):
    return np.concatenate([np.ravel(W), np.ravel(V)])


def test_batch_and_lot_hold_what_fit_holds_with_the_same_parameters(boards, tmp_path):
    tables, lot = boards
    one = [_fit(t) for t in tables]
    assert [[h["term"] for h in f["held"]] for f in one] == [["M_xy"]] * 4 + [[]]
    r = CliRunner().invoke(cli, ["batch", *map(str, tables), "--model", "9", "--json"])
    assert r.exit_code == 0, r.output  # every board fitted: none refused for its weak x-y term
    batch = json.loads(r.output)["results"]
    out = tmp_path / "results.jsonl"
    r = CliRunner().invoke(cli, ["batch", str(lot), "--model", "9", "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    rows = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert [row["serial"] for row in rows] == [f"SN{s}" for s in (*TEN_SEEDS, ELEVEN_SEED)]
    for f, b, row in zip(one, batch, rows, strict=True):
        assert b["ok"] and row["ok"]
        assert b["held"] == f["held"]  # the same terms, value, reason and hint
        assert row["held"] == [h["term"] for h in f["held"]]
        p = _params(f["W"], f["V"])
        assert np.allclose(_params(b["W"], b["V"]), p, rtol=0, atol=1e-12)  # one estimator: same numbers
        lot_p = _params([[row[f"W{i}{j}"] for j in range(3)] for i in range(3)], [row[f"V{i}"] for i in range(3)])
        assert np.allclose(lot_p, p, rtol=0, atol=1e-9)  # through a CSV of 17 significant digits
        if f["crossval_rms_g"] is None:  # the eleven-pose board: leaving out its one x-y pose leaves M_xy free
            assert b["crossval_rms_g"] is None and row["crossval_rms_mg"] is None
        else:
            assert b["crossval_rms_g"] == pytest.approx(f["crossval_rms_g"], rel=1e-9)
            assert row["crossval_rms_mg"] == pytest.approx(f["crossval_rms_g"] * 1e3, rel=1e-9)
    assert all(b["W"][0][1] == 0.0 for b in batch[:4]) and batch[4]["W"][0][1] != 0.0


def test_batch_text_and_csv_name_the_held_terms(boards, tmp_path):
    tables, _ = boards
    csv_path = tmp_path / "summary.csv"
    r = CliRunner().invoke(cli, ["batch", *map(str, tables), "--model", "9", "--csv", str(csv_path)])
    assert r.exit_code == 0, r.output
    line = next(ln for ln in r.output.splitlines() if ln.startswith("held at nominal on 4 board(s): M_xy ("))
    assert HELD_START in line and line.endswith(HELD_END + ")")
    rows = list(csv.DictReader(io.StringIO(csv_path.read_text())))
    assert [row["held"] for row in rows] == ["M_xy"] * 4 + [""]


def test_verdicts_carry_the_held_terms_on_every_path(boards, tmp_path):
    from accelcal_station.acceptance.rules import Limits, judge
    from accelcal_station.api import fit, load
    from accelcal_station.lot.batch import recalibrate, sessions_from_files
    from accelcal_station.lot.streaming import recalibrate_lot

    tables, lot = boards
    limits = Limits.from_config({"residual_rms_mg": 5.0})
    one = [judge(fit(load(t), model=9).result, limits) for t in tables]
    rep = recalibrate(sessions_from_files(tables, model="9"), "9", limits=limits)
    assert [r.verdict.held for r in rep.results] == [v.held for v in one]  # the same words, numbers included
    assert [len(v.held) for v in one] == [1] * 4 + [0]
    assert all(v.held[0].startswith(HELD_START) and v.held[0].endswith(HELD_END) for v in one[:4])
    assert [r.verdict.label for r in rep.results] == [v.label for v in one]
    out = tmp_path / "judged.csv"
    recalibrate_lot(lot, out, "9", limits=limits)
    got = list(csv.DictReader(io.StringIO(out.read_text())))
    assert [g["held"] for g in got] == ["M_xy"] * 4 + [""]
    assert [g["verdict"] for g in got] == [v.label for v in one]


def test_a_held_fit_is_stored_with_its_held_terms_and_report_show_prints_them(boards, tmp_path):
    tables, _ = boards
    db = tmp_path / "store.sqlite"
    r = CliRunner().invoke(cli, ["batch", str(tables[0]), str(tables[4]), "--model", "9", "--to-store", str(db)])
    assert r.exit_code == 0, r.output
    with sqlite3.connect(db) as con:  # what is on disk, read without the station's code
        cals = [json.loads(c) for (c,) in con.execute("SELECT calibration FROM runs ORDER BY id")]
    assert [[h["term"] for h in c["metadata"].get("held", [])] for c in cals] == [["M_xy"], []]
    assert cals[0]["W"][0][1] == 0.0
    shown = CliRunner().invoke(cli, ["report", "show", "1", "--db", str(db)])
    assert shown.exit_code == 0, shown.output
    assert f"M_xy = 0.0: {HELD_START}" in shown.output and HELD_END in shown.output
    other = CliRunner().invoke(cli, ["report", "show", "2", "--db", str(db)])
    assert other.exit_code == 0 and "held" not in other.output


def test_the_stacked_held_fit_equals_the_constrained_levenberg_marquardt(boards):
    """Independent code: gravity_norm's damped fit with the same free mask reaches the same constrained
    optimum as the stacked Gauss-Newton (measured: 5e-13 in the parameters on eight boards)."""
    from accelcal_station.data.loader import load_pose_table

    tables, _ = boards
    x = np.array([load_pose_table(t, references=False).session.readings for t in tables[:4]])
    gf = x / nominal_scale(x)[:, None, None]
    plan = hold_plans(gf, "9")
    assert [[h.term for h in hs] for hs in plan.held] == [["M_xy"]] * 4
    free = plan.free(PARAM_NAMES)
    a, b = fit_norm_batch(gf, free=free[0]), fit_stacked(gf, None, "9", free=free)
    assert np.allclose(b.params, a.params, rtol=0, atol=1e-9) and np.all(b.params[:, 3] == 0.0)
    assert np.allclose(b.stderr_W, a.stderr_W, rtol=1e-6, atol=1e-12)
    assert np.allclose(b.crossval_rms_g, a.crossval_rms_g, rtol=1e-3)  # one-step LOO against exact refits


def test_a_station_run_whose_design_leaves_the_cubic_weak_stores_what_it_held(tmp_path):
    """Model 15 on the six-face design: the station fits model 12's terms, holds the cubic at 0 and the
    run's stored calibration (a real SQLite store) and `report show` say so."""
    from test_station import sim_config

    r = CliRunner().invoke(cli, ["run", "--config", sim_config(tmp_path, plan__model=15, plan__design="six-face"),
                                 "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output[r.output.index("{"):])
    assert [h["term"] for h in out["held"]] == ["Gamma_xx", "Gamma_yy", "Gamma_zz"] and out["Gamma"] == [0.0] * 3
    with sqlite3.connect(tmp_path / "runs.sqlite") as con:
        (cal,) = con.execute("SELECT calibration FROM runs").fetchone()
    assert [h["term"] for h in json.loads(cal)["metadata"]["held"]] == ["Gamma_xx", "Gamma_yy", "Gamma_zz"]
    shown = CliRunner().invoke(cli, ["report", "show", "1", "--db", str(tmp_path / "runs.sqlite")])
    assert shown.exit_code == 0, shown.output
    assert "Gamma_zz = 0.0: z cubic held at 0: a cubic cannot be told from the gain" in shown.output


def test_a_stack_mixing_held_and_free_model_15_boards_gives_each_its_own_fit():
    """One fit_batch call over a six-face board (the cubic not determined: held) and a nine-position board
    (determined: fitted) gives each exactly what fitting it alone gives."""
    from accelcal_station.fixtures.designs import get_design, references
    from accelcal_station.models.fitting import fit, fit_batch

    faces = references(get_design("six-face"))
    refs = np.stack([np.vstack([faces, faces[:3]]), references(get_design("nine-position"))])  # (2, 9, 3)
    rng = np.random.default_rng(11)  # forward physics: gain/cross-axis, offset, a cubic, 0.2 mg noise
    K = np.eye(3) + rng.normal(0, 0.01, (2, 3, 3))
    x = np.einsum("dij,dpj->dpi", K, refs) + 0.02 + 0.003 * refs**3 + rng.normal(0, 2e-4, refs.shape)
    both = fit_batch(x, refs, "15")
    assert both.ok.all() and [[h.term for h in hs] for hs in both.held] == [["Gamma_xx", "Gamma_yy", "Gamma_zz"], []]
    for d in range(2):
        alone = fit(x[d], refs[d], "15")
        assert np.allclose(both.params[d], alone.params, rtol=0, atol=1e-12)
        assert [h.term for h in alone.held] == [h.term for h in both.held[d]]
    assert np.all(both.Gamma[0] == 0.0) and np.all(both.Gamma[1] != 0.0)
    assert both.result(0).covariance.shape == both.result(1).covariance.shape == (3, 5, 5)

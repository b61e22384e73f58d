"""Batch recalibration (accelcal_station/lot/batch.py, `accelcal batch`): vectorised fits equal
one-at-a-time fits, unfittable boards are reported and skipped, results go to files and the store."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.data.posetable import read_pose_table, write_pose_table
from accelcal_station.fixtures.designs import get_design
from accelcal_station.lot.batch import recalibrate, sessions_from_files
from accelcal_station.models.fitting import fit_session, fit_temperature
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store

CPG = 4096.0
N_BOARDS = 200
DESIGN = get_design("an4399-8")


def make_board(seed: int, design=DESIGN, temps=(25.0,)) -> tuple[Session, np.ndarray, np.ndarray]:
    """Synthetic board: readings g = W^-1 (ref - V) + noise (2e-4 g), in counts; truth W, V."""
    rng = np.random.default_rng(seed)
    W = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    V = rng.normal(0, 0.02, 3)
    poses = []
    for t in temps:
        Wt = W * (1 + 1e-4 * (t - 25.0))  # gain drifts with temperature
        for p in design:
            gf = np.linalg.solve(Wt, p.reference_g - V) + rng.normal(0, 2e-4, 3)
            name = p.name if len(temps) == 1 else f"{p.name}@{t:g}"
            poses.append(PoseRecord(name, gf * CPG, np.full(3, 3.0), 400, p.reference_g, p.pitch_deg, p.roll_deg,
                                    None if len(temps) == 1 else t))
    return Session(poses, "counts", CPG, device="mma8451", metadata={"serial": f"SN{seed:04d}"}), W, V


@pytest.fixture(scope="module")
def lot(tmp_path_factory):
    """200 boards' pose tables in one folder, with their true W."""
    d = tmp_path_factory.mktemp("lot")
    truth = {}
    for i in range(N_BOARDS):
        s, W, _ = make_board(i)
        path = d / f"board{i:03d}.csv"
        write_pose_table(s, path)
        truth[str(path)] = W
    return d, truth


def batch(*args):
    return CliRunner().invoke(cli, ["batch", *map(str, args)])


def one_error_line(r) -> str:
    assert r.exit_code == 2 and r.stdout == "", r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def test_batch_of_200_equals_fitting_one_at_a_time(lot, tmp_path):
    d, truth = lot
    r = batch(d, "--json", "--out-dir", tmp_path / "cals", "--csv", tmp_path / "summary.csv")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert (rep["boards"], rep["fitted"], rep["skipped"]) == (N_BOARDS, N_BOARDS, 0)
    assert rep["fit_calls"] == 1  # all 200 boards in one stacked fit
    assert rep["outputs"]["calibrations"] == N_BOARDS
    rows = list(csv.DictReader((tmp_path / "summary.csv").open()))
    assert len(rows) == N_BOARDS
    for res, row in zip(rep["results"], rows, strict=True):
        one = fit_session(read_pose_table(res["source"], references=True), "12")
        # the one stacked estimator: a block of 200 sums in another order than a block of one, so
        # every comparison with a one-board fit in this file is to rounding (1e-12), not bitwise
        np.testing.assert_allclose(res["W"], one.W, rtol=0, atol=1e-12)
        np.testing.assert_allclose(res["V"], one.V, rtol=0, atol=1e-12)
        assert res["residual_rms_g"] == pytest.approx(one.residual_rms_g, rel=1e-9)
        assert res["crossval_rms_g"] == pytest.approx(one.crossval_rms_g, rel=1e-9)
        saved = Calibration.load(res["file"])
        np.testing.assert_allclose(saved.W, one.W, rtol=0, atol=1e-12)
        assert saved.metadata["serial"] == res["serial"] == row["serial"] and row["ok"] == "1"
        assert float(row["W01"]) == pytest.approx(one.W[0, 1], rel=0, abs=1e-12)
        # and right: 8 poses at 0.2 mg noise determine W to about 1e-4
        np.testing.assert_allclose(one.W, truth[res["source"]], atol=1e-3)


def test_model_9_batch_equals_one_at_a_time():
    design = get_design("optimal-14")
    boards = [(f"b{i}", make_board(i, design)[0]) for i in range(20)]
    short = ("short", make_board(99)[0])  # 8 poses cannot determine 9 parameters
    rep = recalibrate([*boards[:10], short, *boards[10:]], "9")
    assert len(rep.fitted) == 20 and rep.fit_calls == 2  # one stack per pose count: 14 (20 boards) and 8 (fails)
    assert "8 distinct orientations; the 9-parameter norm model needs at least 9" in rep.results[10].message
    for (_, s), r in zip(boards, rep.fitted, strict=True):
        one = fit_session(s, "9")
        np.testing.assert_allclose(r.calibration.W, one.W, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.calibration.V, one.V, rtol=0, atol=1e-12)


def write_broken(d: Path) -> dict[str, str]:
    """Boards that cannot be fitted, and a word their reason must contain."""
    s, _, _ = make_board(1000)
    write_pose_table(Session(s.poses[:3], "counts", CPG), d / "three_poses.csv")
    write_pose_table(Session(s.poses, "g", None), d / "counts_as_g.csv")  # counts declared as g
    flat = [PoseRecord(f"f{i}", s.poses[0].mean * 0 + [np.cos(a) * CPG, np.sin(a) * CPG, 0.0], None, None,
                       [np.cos(a), np.sin(a), 0.0]) for i, a in enumerate(np.linspace(0, 5, 6))]
    write_pose_table(Session(flat, "counts", CPG), d / "flat.csv")  # z never sees gravity
    (d / "garbled.csv").write_text("pose,x,y,z\np1,1,2\n")
    return {"three_poses.csv": "at least 4 poses", "counts_as_g.csv": "median norm",
            "flat.csv": "channel z has no spread", "garbled.csv": "line 2: 3 fields",
            "missing.csv": "cannot read"}


def test_broken_boards_are_reported_and_skipped(lot, tmp_path):
    d, _ = lot
    reasons = write_broken(tmp_path)
    broken = [tmp_path / n for n in reasons]
    r = batch(d, *broken, "--json", "--out-dir", tmp_path / "cals", "--csv", tmp_path / "s.csv")
    assert r.exit_code == 1, r.output  # 1: some boards skipped, the rest written
    rep = json.loads(r.stdout)
    assert (rep["boards"], rep["fitted"], rep["skipped"]) == (N_BOARDS + 5, N_BOARDS, 5)
    skipped = {Path(x["source"]).name: x for x in rep["results"] if not x["ok"]}
    assert set(skipped) == set(reasons)
    for name, word in reasons.items():
        assert word in skipped[name]["message"], skipped[name]["message"]
        assert skipped[name]["W"] is None and skipped[name]["file"] is None
    assert len(list((tmp_path / "cals").glob("*.json"))) == N_BOARDS
    rows = {Path(x["source"]).name: x for x in csv.DictReader((tmp_path / "s.csv").open())}
    assert len(rows) == N_BOARDS + 5 and rows["flat.csv"]["ok"] == "0" and "spread" in rows["flat.csv"]["message"]
    # the good boards are untouched by the bad ones (units are judged per board, not on the stack)
    clean = json.loads(batch(d, "--json").stdout)
    good = [x for x in rep["results"] if x["ok"]]
    assert [x["W"] for x in good] == [x["W"] for x in clean["results"]]

    text = batch(d, *broken)
    assert text.exit_code == 1
    assert f"{N_BOARDS} of {N_BOARDS + 5} boards recalibrated with model 12" in text.stdout
    assert sum(line.startswith("SKIP ") for line in text.stdout.splitlines()) == 5
    assert "fitting model 12" in text.stderr  # the progress bar goes to stderr


def test_nan_and_missing_references_skip_only_their_board():
    good = [(f"b{i}", make_board(i)[0]) for i in range(5)]
    nan = make_board(7)[0]
    nan.poses[2].mean[1] = np.nan
    noref = make_board(8)[0]
    noref.poses[0].reference_g = None
    rep = recalibrate(good[:2] + [("nan", nan), ("noref", noref)] + good[2:], "12")
    assert [r.ok for r in rep.results] == [True, True, False, False, True, True, True]
    assert "NaN" in rep.results[2].message and "no reference" in rep.results[3].message
    for (_src, s), r in zip(good, rep.fitted, strict=True):
        np.testing.assert_allclose(r.calibration.W, fit_session(s, "12").W, rtol=0, atol=1e-12)


def test_multi_temperature_board_gets_a_temperature_table(tmp_path):
    s, _, _ = make_board(5, temps=(0.0, 25.0, 50.0))
    write_pose_table(s, tmp_path / "hot.csv")
    rep = recalibrate(sessions_from_files([tmp_path / "hot.csv"]), "12")
    (r,) = rep.results
    assert r.ok and r.temperatures_c == [0.0, 25.0, 50.0]
    want, _ = fit_temperature(read_pose_table(tmp_path / "hot.csv"), "12")
    np.testing.assert_allclose(r.calibration.temperature.W, want.temperature.W, rtol=0, atol=1e-12)


def record_runs(db: Path, seeds, lot_name: str, poses=None) -> dict[int, Session]:
    out = {}
    with Store(db) as st:
        for seed in seeds:
            s, _, _ = make_board(seed)
            if poses is not None:
                s = s.subset(range(poses))
            s.device = f"SN{seed:04d}"
            rid = st.start_run(device_serial=s.device, chip="mma8451", station_id="st1", lot=lot_name, model="12")
            st.finish_run(rid, session=s, calibration=None, verdict="PASS")
            out[rid] = s
    return out


def test_batch_from_store_records_events_on_source_runs(tmp_path):
    db = tmp_path / "runs.sqlite"
    l1 = record_runs(db, range(6), "L1")
    bad = record_runs(db, [50], "L1", poses=3)
    l2 = record_runs(db, range(10, 13), "L2")
    r = batch("--from-store", db, "--lot", "L1", "--to-store", db, "--json")
    assert r.exit_code == 1, r.output
    rep = json.loads(r.stdout)
    assert (rep["boards"], rep["fitted"], rep["skipped"]) == (7, 6, 1)
    assert rep["outputs"]["store"] == {"path": str(db), "events": 7, "runs": 0}
    with Store(db) as st:
        assert len(st.list_runs()) == 10  # no run added: recalibrations are events on their runs
        for res in rep["results"]:
            rec = st.get_run(res["run_id"])
            assert res["serial"] == rec.device_serial and res["source"] == f"run {rec.id}"
            (ev,) = rec.events
            if res["ok"]:
                want = fit_session(l1[rec.id], "12")
                np.testing.assert_allclose(res["W"], want.W, rtol=0, atol=1e-12)
                assert ev["kind"] == "recalibration"
                np.testing.assert_allclose(ev["data"]["calibration"]["W"], want.W, rtol=0, atol=1e-12)
            else:
                assert rec.id in bad and ev["kind"] == "recalibration_skipped" and "4 poses" in ev["message"]
        assert all(not st.get_run(i).events for i in l2)


def test_batch_from_files_into_a_store_adds_runs(lot, tmp_path):
    d, _ = lot
    paths = sorted(d.glob("*.csv"))[:3]
    db = tmp_path / "new.sqlite"
    r = batch(*paths, "--to-store", db)
    assert r.exit_code == 0 and f"store {db}: 0 recalibration event(s) on source runs, 3 new run(s)" in r.stdout
    with Store(db) as st:
        runs = st.runs()
        assert [x.station_id for x in runs] == ["accelcal-batch"] * 3 and all(x.status == "complete" for x in runs)
        for rec, p in zip(runs, paths, strict=True):
            one = fit_session(read_pose_table(p, references=True), "12")
            np.testing.assert_allclose(rec.calibration_object().W, one.W, rtol=0, atol=1e-12)
            assert rec.device_serial == read_pose_table(p).metadata["serial"] and len(rec.poses) == 8


def test_bad_input_is_one_line(lot, tmp_path):
    d, _ = lot
    assert "no boards given" in one_error_line(batch())
    assert "--model '7'; allowed: 6, 9, 12, 15" in one_error_line(batch(d, "--model", "7"))
    assert "--lot filters runs of a results store" in one_error_line(batch(d, "--lot", "L1"))
    assert "no file matches" in one_error_line(batch(str(tmp_path / "*.csv")))
    assert "no results store there" in one_error_line(batch("--from-store", tmp_path / "none.sqlite"))
    assert "--counts-per-g 'x'" in one_error_line(batch(d, "--counts-per-g", "x"))
    assert "--units" in one_error_line(batch(d, "--units", "volts"))
    db = tmp_path / "runs.sqlite"
    record_runs(db, [1], "L1")
    assert "no complete runs" in one_error_line(batch("--from-store", db, "--lot", "nope"))
    assert "--run 'one'; allowed: a positive whole number" in one_error_line(batch("--from-store", db, "--run", "one"))
    assert "since 'May': not a date" in one_error_line(batch("--from-store", db, "--since", "May"))
    rep = json.loads(batch("--from-store", db, "--run", "1", "--json").stdout)
    assert [x["run_id"] for x in rep["results"]] == [1]


def test_pose_table_batch_judges_boards_against_a_station_configs_limits(tmp_path):
    """`accelcal batch TABLES --config STATION.yaml`: each board's verdict by the station's
    limits, the same as judging its own single fit (acceptance.judge), and right against the
    boards' true offsets (V ~ N(0, 20 mg) per axis; the limit 30 mg splits them)."""
    from accelcal_station.acceptance.rules import Limits, judge

    d = tmp_path / "tables"
    d.mkdir()
    truth = {}
    for i in range(40):
        s, _, V = make_board(1000 + i)
        write_pose_table(s, d / f"b{i:02d}.csv")
        truth[str(d / f"b{i:02d}.csv")] = np.abs(V).max() * 1e3  # mg
    cfg = tmp_path / "station.yaml"
    cfg.write_text("acceptance:\n  offset_max_mg: 30\n  residual_rms_mg: 5\n")
    r = batch(d, "--config", cfg, "--json")
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    limits = Limits.from_config({"offset_max_mg": 30, "residual_rms_mg": 5})
    labels = []
    for res in rep["results"]:
        one = judge(fit_session(read_pose_table(res["source"], references=True), "12"), limits)
        assert (res["verdict"], res["reasons"]) == (one.label, [x.to_dict() for x in one.reasons])
        labels.append(res["verdict"])
        # the fitted offset is within ~1 mg of the truth (0.2 mg noise, 8 poses): boards clear of
        # the limit by 2 mg are judged by their true offset (no false failure at this margin)
        off = truth[res["source"]]
        if abs(off - 30) > 2:
            assert res["verdict"] == ("FAIL" if off > 30 else "PASS"), (res, off)
            assert (res["verdict"] == "FAIL") == any(x["code"] == "offset_max_mg" for x in res["reasons"])
    assert 5 < labels.count("PASS") < 35  # a mix: both branches are tested
    text = batch(d, "--config", cfg)
    assert text.exit_code == 0 and f"verdicts: PASS {labels.count('PASS')}, FAIL {labels.count('FAIL')}" in text.stdout
    failed = [ln for ln in text.stdout.splitlines() if ln.startswith("FAIL ")]
    assert len(failed) == labels.count("FAIL") and all("offset_max_mg" in ln for ln in failed)  # with reasons
    # without --config: no verdicts; a bad limit is one line, exit 2
    assert all(x["verdict"] is None for x in json.loads(batch(d, "--json").stdout)["results"])
    cfg.write_text("acceptance:\n  offset_max_mg: -1\n")
    line = one_error_line(batch(d, "--config", cfg))
    assert "acceptance.offset_max_mg: -1 out of range; allowed: 0 to 1e+06" in line

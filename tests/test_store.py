"""SQLite results store on a real file: atomic runs, interruptions, readers, summaries, exports."""
from __future__ import annotations

import csv
import hashlib
import io
import json
import sqlite3
import subprocess
import sys
import threading

import numpy as np
import pytest

from accelcal_station.acceptance.reasons import Reason
from accelcal_station.calibration import PARAM_NAMES, Calibration
from accelcal_station.conventions import an4399_reference
from accelcal_station.drivers.eeprom import EEPROM24
from accelcal_station.errors import DataError
from accelcal_station.models.fitting import fit_batch, fit_session
from accelcal_station.nvm.writer import CalibrationWriter
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.records import StoreError
from accelcal_station.store.runs import Store
from accelcal_station.store.schema import SCHEMA_VERSION

CPG = 4096.0
POSES = [(0, 0), (0, 180), (90, 0), (-90, 0), (0, 90), (0, -90), (45, 45), (-30, 120)]


def board(seed: int, serial: str | None = None) -> tuple[Session, np.ndarray, np.ndarray]:
    """A session of one synthetic board with true W, V (readings = W^-1 (ref - V) + noise)."""
    rng = np.random.default_rng(seed)
    W = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    V = rng.normal(0, 0.02, 3)
    poses = []
    for i, (p, r) in enumerate(POSES):
        ref = an4399_reference(p, r)
        gf = np.linalg.solve(W, ref - V) + rng.normal(0, 2e-4, 3)
        poses.append(PoseRecord(f"p{i}", gf * CPG, np.full(3, 4.0) + i, 200, ref, p, r, 25.0 + 0.1 * i,
                                i % 2, 10.0 * i, 10.0 * i + 2))
    return Session(poses, "counts", CPG, device=serial or f"SN{seed:04d}"), W, V


def record(store: Store, seed: int, *, lot="L1", verdict="PASS", reasons=(), started_at=None, nvm=None):
    s, _, _ = board(seed)
    fit = fit_session(s, "12")
    rid = store.start_run(device_serial=s.device, chip="mma8451", station_id="st1", operator="op",
                          lot=lot, config_text=f"seed: {seed}\n", model="12", started_at=started_at)
    store.finish_run(rid, session=s, calibration=fit.calibration, verdict=verdict, reasons=list(reasons),
                     nvm_outcome=nvm, fit_summary=fit.to_json_dict(s.names), retries=[i % 3 for i in range(len(s))])
    return rid, s, fit


@pytest.fixture
def db(tmp_path):
    return tmp_path / "sub" / "runs.sqlite"


def test_run_round_trip_rebuilds_session(db):
    nvm = EEPROM24()
    with Store(db) as store:
        assert store.schema_version == SCHEMA_VERSION == 6
        s, _, _ = board(1)
        fit = fit_session(s, "12")
        outcome = CalibrationWriter(nvm).burn(fit.calibration, s.device, "st1")
        rid = store.start_run(device_serial=s.device, chip="mma8451", station_id="st1", operator="ana",
                              lot="L7", config_text="x: 1\n", model="12")
        assert store.get_run(rid).status == "running"
        store.finish_run(rid, session=s, calibration=fit.calibration, verdict="PASS", nvm_outcome=outcome,
                         fit_summary=fit.to_json_dict(s.names), retries=[0, 1, 0, 0, 2, 0, 0, 0])
    with Store(db) as store:  # a fresh connection reads what was committed
        rec = store.get_run(rid)
    assert (rec.status, rec.verdict, rec.lot, rec.operator, rec.nvm_status) == ("complete", "PASS", "L7", "ana",
                                                                                 "written")
    assert rec.config_hash == hashlib.sha256(b"x: 1\n").hexdigest()
    assert rec.nvm_outcome["slot"] == "A" and rec.nvm_outcome["crc32"] == outcome.crc32
    assert rec.retries == [0, 1, 0, 0, 2, 0, 0, 0]
    back = rec.session()
    assert (back.units, back.counts_per_g, back.device, len(back)) == ("counts", CPG, s.device, len(s))
    for a, b in zip(s.poses, back.poses, strict=True):
        assert a.name == b.name and np.array_equal(a.mean, b.mean) and np.array_equal(a.std, b.std)
        assert np.array_equal(a.reference_g, b.reference_g)
        assert (a.n, a.pitch_deg, a.roll_deg, a.temp_c, a.dropped, a.t_start, a.t_end) == \
               (b.n, b.pitch_deg, b.roll_deg, b.temp_c, b.dropped, b.t_start, b.t_end)
    cal = rec.calibration_object()
    assert np.array_equal(cal.W, fit.calibration.W) and np.array_equal(cal.V, fit.calibration.V)
    refit = fit_session(back, "12")  # the stored session refits to the same calibration
    assert np.allclose(refit.W, fit.W, rtol=0, atol=1e-12)
    assert rec.fit_summary["residual_rms_g"] == fit.residual_rms_g


def test_finish_is_atomic(db):
    with Store(db) as store:
        rid = store.start_run(device_serial="SN1")
        s, _, _ = board(2)
        # a failure inside SQLite after the poses are inserted (as a full disk would be)
        raw = sqlite3.connect(db)
        raw.execute("CREATE TRIGGER fail BEFORE UPDATE OF status ON runs WHEN NEW.status = 'complete'"
                    " BEGIN SELECT RAISE(ABORT, 'injected failure'); END")
        raw.commit()
        with pytest.raises(StoreError, match="cannot record run 1 .*injected failure.*rolled back"):
            store.finish_run(rid, session=s, calibration=None, verdict="FAIL")
        raw.execute("DROP TRIGGER fail")
        raw.commit()
        raw.close()
        assert store.get_run(rid).poses == [] and store.get_run(rid).status == "running"
        # a failure in Python after the poses are inserted: not JSON-serialisable fit summary
        with pytest.raises(DataError, match="not JSON-serialisable"):
            store.finish_run(rid, session=s, calibration=None, verdict="FAIL", fit_summary={"x": object()})
        rec = store.get_run(rid)
        assert rec.poses == [] and rec.status == "running" and rec.verdict is None
        store.finish_run(rid, session=s, calibration=None, verdict="FAIL", reasons=["fit_failed: singular"])
        assert len(store.get_run(rid).poses) == len(s)
        with pytest.raises(StoreError, match="run 1 is already complete"):
            store.finish_run(rid, session=s, calibration=None, verdict="PASS")
        with pytest.raises(DataError, match="verdict 'MAYBE'; allowed: PASS, FAIL"):
            store.finish_run(rid, session=s, calibration=None, verdict="MAYBE")


def test_interrupted_runs_are_recorded(db, tmp_path):
    with Store(db) as store:
        s, _, _ = board(3)
        rid = store.start_run(device_serial=s.device)
        store.log_event(rid, "retry", "pose p2 not still", {"std_counts": [30, 2, 2]})
        store.interrupt_run(rid, "operator pressed Ctrl-C at pose 4", session=s.subset([0, 1, 2]))
        rec = store.get_run(rid)
        assert (rec.status, rec.status_reason, len(rec.poses)) == (
            "interrupted", "operator pressed Ctrl-C at pose 4", 3)
        assert rec.events[0]["kind"] == "retry" and rec.events[0]["data"] == {"std_counts": [30, 2, 2]}
        err = store.start_run(device_serial="SN2")
        store.interrupt_run(err, "device stopped answering", status="error")
        assert store.get_run(err).status == "error"

    # a station process that dies mid-run leaves a 'running' row; the next start marks it
    code = (f"import os; from accelcal_station.store.runs import Store; s = Store({str(db)!r}); "
            "print(s.start_run(device_serial='SN-crash')); os._exit(9)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 9, out.stderr
    crashed = int(out.stdout)
    with Store(db) as store:
        mine = store.start_run(device_serial="SN-live")  # this process is alive: not stale
        assert store.get_run(crashed).status == "stale"  # read as stale at once (its pid is gone: liveness.py)
        assert store.mark_stale_interrupted() == [crashed]
        rec = store.get_run(crashed)
        assert rec.status == "interrupted" and "station stopped" in rec.status_reason
        assert store.get_run(mine).status == "running"
        assert store.mark_stale_interrupted(max_age_s=-1) == [mine]
        summary = store.lot_summary()
    assert summary["by_status"] == {"running": 0, "complete": 0, "interrupted": 3, "error": 1, "stale": 0}
    assert summary["interruptions"]["station stopped during the run"] == 2


def test_readers_run_alongside_a_writer(db):
    with Store(db) as store:
        record(store, 0)
    errors, seen = [], []

    def writer():
        try:
            with Store(db) as st:
                for i in range(1, 16):
                    record(st, i)
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    def reader():
        try:
            with Store(db) as st:
                for _ in range(40):
                    runs = st.list_runs()
                    # every complete run is seen whole: all its poses or none of the run
                    assert all(r["pose_count"] == len(POSES) for r in runs if r["status"] == "complete")
                    seen.append(st.lot_summary()["runs"])
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=writer)] + [threading.Thread(target=reader) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert min(seen) >= 1 and max(seen) <= 16
    # an open write transaction does not block readers and is invisible to them
    raw = sqlite3.connect(db, isolation_level=None)
    raw.execute("BEGIN IMMEDIATE")
    raw.execute("DELETE FROM poses")
    with Store(db, timeout_s=1) as st:
        assert sum(r["pose_count"] for r in st.list_runs()) == 16 * len(POSES)
    raw.execute("ROLLBACK")
    raw.close()


def test_lot_summary_matches_numpy(db):
    rng = np.random.default_rng(42)
    with Store(db) as store:
        rows = []
        for i in range(24):
            verdict = "PASS" if rng.random() < 0.7 else "FAIL"
            choices = [Reason("residual_rms_mg", "3.1 > limit 2 (RMS)", " "),
                       Reason("offset_max_mg", "90 > limit 60 (offset)", " "),
                       Reason("crossval_rms_mg", "not measurable for this fit (limit 3)")]
            reasons = [] if verdict == "PASS" else [choices[k] for k in rng.choice(
                3, size=rng.integers(1, 3), replace=False)]
            rid, s, fit = record(store, 100 + i, verdict=verdict, reasons=reasons,
                                 nvm={"ok": bool(i % 5)} if verdict == "PASS" else None)
            rows.append((verdict, reasons, fit))
        record(store, 500, lot="other", verdict="FAIL", reasons=[Reason("gain_error_max", "0.2 > limit 0.05", " ")])
        store.interrupt_run(store.start_run(device_serial="SNx", lot="L1"), "e-stop")
        summ = store.lot_summary(lot="L1")

    verdicts = [v for v, _, _ in rows]
    assert summ["runs"] == 25 and summ["by_status"]["interrupted"] == 1 and summ["interruptions"] == {"e-stop": 1}
    assert (summ["pass"], summ["fail"]) == (verdicts.count("PASS"), verdicts.count("FAIL"))
    assert summ["pass_rate"] == pytest.approx(verdicts.count("PASS") / 24, abs=0)
    expect = {}
    for _v, reasons, _ in rows:
        for code in {r.code for r in reasons}:
            expect[code] = expect.get(code, 0) + 1
    assert summ["failure_reasons"] == expect and "gain_error_max" not in summ["failure_reasons"]
    assert summ["nvm"] == {"written": sum(1 for i, (v, _, _) in enumerate(rows) if v == "PASS" and i % 5),
                           "failed": sum(1 for i, (v, _, _) in enumerate(rows) if v == "PASS" and not i % 5),
                           "none": verdicts.count("FAIL")}
    P = np.array([np.concatenate([f.W.ravel(), f.V, f.Gamma]) for _, _, f in rows])
    for j, name in enumerate(PARAM_NAMES):
        d = summ["parameters"][name]
        assert d["n"] == 24
        assert d["mean"] == pytest.approx(P[:, j].mean(), rel=1e-12, abs=1e-15)
        assert d["std"] == pytest.approx(P[:, j].std(ddof=1), rel=1e-9, abs=1e-15)
        assert (d["min"], d["max"]) == (P[:, j].min(), P[:, j].max())
    rms = np.array([f.residual_rms_g for _, _, f in rows])
    assert summ["fit"]["residual_rms_g"]["mean"] == pytest.approx(rms.mean(), rel=1e-12)


def test_filters_and_exports(db, tmp_path):
    with Store(db) as store:
        ids = [record(store, i, lot="A" if i < 3 else "B", verdict="FAIL" if i == 4 else "PASS",
                      reasons=[Reason("residual_rms_mg", "5 > limit 2 (RMS)", " ")] if i == 4 else (),
                      started_at=1_700_000_000 + 3600 * i)[0] for i in range(5)]
        store.interrupt_run(store.start_run(device_serial="SN9", lot="B", started_at=1_700_000_000 + 3600 * 9),
                            "power cut")
        assert [r["id"] for r in store.list_runs(lot="B", verdict="PASS")] == ids[3:4]
        assert [r["id"] for r in store.list_runs(device=["SN0000", "SN0002"])] == [ids[0], ids[2]]
        assert [r["id"] for r in store.list_runs(since=1_700_000_000 + 3600, until="2023-11-15T01:13:20+00:00")] \
            == ids[1:3]
        assert len(store.list_runs(status="interrupted")) == 1 and len(store.list_runs(limit=2)) == 2
        with pytest.raises(DataError, match="since 'yesterday': not a date; allowed ISO 8601"):
            store.list_runs(since="yesterday")

        n = len(POSES)
        text = store.export_csv(tmp_path / "runs.csv", lot="B")
        assert (tmp_path / "runs.csv").read_text() == text
        rows = list(csv.DictReader(io.StringIO(text)))
        assert [int(r["id"]) for r in rows] == [ids[3], ids[4], ids[4] + 1]
        full = store.get_run(ids[4])
        assert rows[1]["verdict"] == "FAIL" and rows[1]["reasons"] == "residual_rms_mg 5 > limit 2 (RMS)"
        W = np.array([[float(rows[1][f"W{i}{j}"]) for j in range(3)] for i in range(3)])
        assert np.array_equal(W, np.array(full.calibration["W"]))  # repr floats: exact
        assert rows[2]["status"] == "interrupted" and rows[2]["W00"] == "" and rows[2]["pose_count"] == "0"
        assert float(rows[0]["residual_rms_g"]) == store.get_run(ids[3]).fit_summary["residual_rms_g"]

        prows = list(csv.DictReader(io.StringIO(store.export_csv(tmp_path / "poses.csv", kind="poses"))))
        assert len(prows) == 5 * n and {int(r["run_id"]) for r in prows} == set(ids)
        p = full.poses[3]
        got = [r for r in prows if int(r["run_id"]) == ids[4] and r["name"] == p.name][0]
        assert np.array_equal([float(got[f"mean_{a}"]) for a in "xyz"], p.mean) and int(got["n"]) == p.n

        data = store.export_json(tmp_path / "runs.json")
        doc = json.loads((tmp_path / "runs.json").read_text())
        assert doc["runs"] == json.loads(json.dumps(data)) and len(doc["runs"]) == 6
        r4 = [r for r in doc["runs"] if r["id"] == ids[4]][0]
        assert r4["config_text"] == "seed: 4\n" and len(r4["poses"]) == n and r4["fit_summary"]["poses"]
        assert np.array_equal(Calibration.from_dict(r4["calibration"]).V, full.calibration_object().V)
        assert r4["poses"][3]["mean"] == p.mean.tolist() and r4["started_at_iso"].startswith("2023-11-15T")
        with pytest.raises(DataError, match="CSV kind 'pose'; allowed: runs, poses"):
            store.export_csv(kind="pose")


def test_sessions_for_batch_refit(db):
    with Store(db) as store:
        fits = [record(store, i, lot="B7")[2] for i in range(4)]
        record(store, 9, lot="other")
        store.interrupt_run(store.start_run(device_serial="SNi", lot="B7"), "stopped")
        sessions = store.sessions_for_batch(lot="B7")
    assert [s.device for s in sessions] == [f"SN{i:04d}" for i in range(4)]
    b = fit_batch(np.stack([s.readings for s in sessions]), sessions[0].references_g, "12",
                  units="counts", counts_per_g=CPG)
    for d, f in enumerate(fits):
        assert np.allclose(b.W[d], f.W, atol=1e-12) and np.allclose(b.V[d], f.V, atol=1e-12)


def test_refuses_foreign_and_newer_files(tmp_path):
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(StoreError, match="junk.sqlite: not a usable results store"):
        Store(junk)
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as c:
        c.execute("CREATE TABLE t (x)")
    with pytest.raises(StoreError, match="not an accelcal results store"):
        Store(other)
    newer = tmp_path / "newer.sqlite"
    Store(newer).close()
    with sqlite3.connect(newer) as c:
        c.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    message = f"schema version {SCHEMA_VERSION + 1} is newer than this station's {SCHEMA_VERSION}"
    with pytest.raises(StoreError, match=message):
        Store(newer)
    with pytest.raises(StoreError, match="no run 5"):
        Store(tmp_path / "fresh.sqlite").get_run(5)


def test_report_cli(db, tmp_path, monkeypatch):
    from click.testing import CliRunner

    from accelcal_station.cli import cli

    with Store(db) as store:
        for i in range(3):
            record(store, i, verdict="FAIL" if i == 1 else "PASS",
                   reasons=[Reason("offset_max_mg", "80 > limit 60 (offset)", " ")] if i == 1 else ())
        store.interrupt_run(store.start_run(device_serial="SN7", lot="L1"), "operator abort")
        expect = store.lot_summary(lot="L1")
    run = CliRunner().invoke
    r = run(cli, ["report", "list", "--db", str(db), "--json", "--verdict", "fail"])
    assert r.exit_code == 0, r.output
    assert [x["device_serial"] for x in json.loads(r.output)] == ["SN0001"]
    r = run(cli, ["report", "list", "--db", str(db)])
    assert r.exit_code == 0 and "operator abort" in r.output and r.output.strip().endswith("4 run(s)")
    (tmp_path / "station.yaml").write_text("store:\n  path: sub/runs.sqlite\n")  # relative to the cwd
    monkeypatch.chdir(tmp_path)
    r = run(cli, ["report", "summary", "--config", str(tmp_path / "station.yaml"), "--lot", "L1", "--json"])
    assert r.exit_code == 0 and json.loads(r.output) == json.loads(json.dumps(expect))
    r = run(cli, ["report", "summary", "--db", str(db)])
    assert r.exit_code == 0 and "pass rate 66.7 %" in r.output and "offset_max_mg" in r.output
    r = run(cli, ["report", "export", "--db", str(db), "-o", str(tmp_path / "out.csv"), "--json"])
    assert r.exit_code == 0 and json.loads(r.output) == {"path": str(tmp_path / "out.csv"), "format": "csv", "runs": 4}
    assert len(list(csv.DictReader((tmp_path / "out.csv").open()))) == 4
    r = run(cli, ["report", "export", "--db", str(db), "--format", "json", "--device", "SN0002"])
    assert r.exit_code == 0 and [x["device_serial"] for x in json.loads(r.output)["runs"]] == ["SN0002"]
    r = run(cli, ["report", "show", "2", "--db", str(db), "--json"])
    assert r.exit_code == 0 and json.loads(r.output)["reasons"] == ["offset_max_mg 80 > limit 60 (offset)"]
    for args, msg in [(["list", "--db", str(tmp_path / "none.sqlite")], "none.sqlite: no results store there"),
                      (["list"], "accelcal-runs.sqlite: no results store there"),  # the default station's
                      (["list", "--db", str(db), "--verdict", "ok"], "--verdict 'ok'; allowed: PASS, FAIL"),
                      (["list", "--db", str(db), "--since", "soon"], "since 'soon': not a date"),
                      (["export", "--db", str(db), "--format", "xml"], "--format 'xml'; allowed: csv, json"),
                      (["show", "99", "--db", str(db)], "no run 99")]:
        r = run(cli, ["report", *args])
        assert r.exit_code == 2 and msg in r.output and r.output.count("\n") == 1, (args, r.output)
    assert not (tmp_path / "none.sqlite").exists()

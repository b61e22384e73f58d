"""A line database: the results store as a URL, on SQLite and on a real throwaway PostgreSQL
server (tests/pgserver.py), exercised by separate `accelcal` processes at the same time."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from click.testing import CliRunner
from sqlalchemy import select

from accelcal_station.cli import cli
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.store.runs import Store
from accelcal_station.store.tables import runs

ACCELCAL = [sys.executable, "-m", "accelcal_station"]


def _report_list(url) -> list[dict]:
    r = CliRunner().invoke(cli, ["report", "list", "--db", url, "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_two_stations_record_at_once_and_report_lists_both(store_url, tmp_path):
    procs = [subprocess.Popen([*ACCELCAL, "run", "--store", store_url, "--serial", s, "--operator", "ci",
                               "--lot", "L7", "--json"], cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for s in ("SN-A", "SN-B")]
    outs = [p.communicate(timeout=120) for p in procs]
    for p, (_out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-2000:]
    ids = sorted(json.loads(out)["run_id"] for out, _ in outs)
    runs = _report_list(store_url)
    assert sorted(r["id"] for r in runs) == ids and len(set(ids)) == 2
    assert sorted(r["device_serial"] for r in runs) == ["SN-A", "SN-B"]
    assert all(r["status"] == "complete" and r["verdict"] == "PASS" and r["pose_count"] == 8 for r in runs)
    with Store(store_url, create=False) as st:
        assert st.lot_summary(lot="L7")["pass"] == 2


def test_batch_from_and_to_the_store(store_url, tmp_path):
    for s in ("SN-1", "SN-2"):
        r = CliRunner().invoke(cli, ["run", "--store", store_url, "--serial", s, "--json"])
        assert r.exit_code == 0, r.output
    # from the store back into the same store: events on the source runs
    r = CliRunner().invoke(cli, ["batch", "--from-store", store_url, "--to-store", store_url, "--model", "12",
                                 "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert doc["fitted"] == 2 and doc["outputs"]["store"]["events"] == 2 and doc["outputs"]["store"]["runs"] == 0
    with Store(store_url, create=False) as st:
        for rec in st.runs():
            assert [e["kind"] for e in rec.events].count("recalibration") == 1
        session = st.runs()[0].session()
    # pose tables into the store: new runs of station accelcal-batch
    write_pose_table(session, tmp_path / "b1.csv", {"serial": "SN-9"})
    r = CliRunner().invoke(cli, ["batch", str(tmp_path / "b1.csv"), "--to-store", store_url, "--json"])
    assert r.exit_code == 0, r.output
    runs = _report_list(store_url)
    assert len(runs) == 3 and runs[-1]["station_id"] == "accelcal-batch" and runs[-1]["device_serial"] == "SN-9"


def test_store_url_errors_are_one_line(tmp_path):
    r = CliRunner().invoke(cli, ["report", "list", "--db", "mysql://u@h/db"])
    assert r.exit_code == 2 and "unknown store URL scheme" in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(cli, ["report", "list", "--db", f"sqlite:///{tmp_path / 'none.sqlite'}"])
    assert r.exit_code == 2 and "no results store there" in r.output


def test_postgresql_unreachable_is_one_line(tmp_path):
    pytest.importorskip("psycopg", reason="psycopg is not installed")
    url = f"postgresql://nobody:secret@/x?host={tmp_path}&port=1"
    r = CliRunner().invoke(cli, ["report", "list", "--db", url])
    assert r.exit_code == 2 and "cannot open results store" in r.output
    assert "secret" not in r.output and "Traceback" not in r.output


def test_postgresql_schema_is_versioned_and_reopens(pg_server):
    url = pg_server.new_database()
    with Store(url) as st:
        v = st.schema_version
        rid = st.start_run(device_serial="X1", started_at=1.5e9 + 0.123456789)
    assert v >= 1
    with Store(url, create=False) as st:  # double precision survives (PostgreSQL REAL would not)
        assert st.schema_version == v and st.get_run(rid).started_at == 1.5e9 + 0.123456789


def test_reasons_stored_as_text_are_typed_once_by_the_migration(store_url, monkeypatch):
    """A store written at schema 2 (reasons as bare text) opened by this station: migration 3
    gives every reason a code once (the station's own reason_codes when the row kept them),
    a damaged row stays shown as damaged, and summaries then group by the stored code."""
    import accelcal_station.store.schema as store_mod
    from accelcal_station.acceptance.reasons import Reason
    from accelcal_station.models.fitting import fit_session
    from accelcal_station.session import PoseRecord, Session

    refs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0.6, 0.8, 0), (0, 0.6, 0.8)]
    s = Session([PoseRecord(f"p{i}", [4096 * a * 1.01 + 3, 4096 * b * 0.99 - 5, 4096 * c + 7], [2.0] * 3, 100,
                            [a, b, c]) for i, (a, b, c) in enumerate(refs)], "counts", 4096.0, device="SN-OLD")
    fit = fit_session(s, "12")
    legacy = [  # (reasons as an older station stored them, fit_summary reason_codes it kept)
        (["at 70 C: offset_max_mg 90 > limit 60 (offset)"], ["offset_max_mg"]),
        (["residual_rms_mg 3.1 > limit 2 (RMS)", "nvm: read-back differs"], None),
        ("[not json", None),
    ]
    monkeypatch.setattr(store_mod, "SCHEMA_VERSION", 2)
    with Store(store_url) as st:
        assert st.schema_version == 2
        for text, typed in legacy:
            rid = st.start_run(device_serial="SN-OLD", lot="OLD")
            st.finish_run(rid, session=s, calibration=fit.calibration, verdict="FAIL",
                          fit_summary={"residual_rms_g": 0.001, **({"reason_codes": typed} if typed else {})})
            with st._tx("write a schema-2 row") as db:
                db.execute(runs.update().where(runs.c.id == rid).values(
                    reasons=text if isinstance(text, str) else json.dumps(text)))
    monkeypatch.undo()
    with Store(store_url) as st:
        assert st.schema_version == store_mod.SCHEMA_VERSION == 6
        recs = st.runs(lot="OLD")
        summary = st.lot_summary(lot="OLD")
    assert [(r.code, str(r)) for r in recs[0].reasons] == [
        ("offset_max_mg", "at 70 C: offset_max_mg 90 > limit 60 (offset)")]
    assert [r.code for r in recs[1].reasons] == ["residual_rms_mg", "nvm"]
    assert all(isinstance(r, Reason) for r in recs[1].reasons)
    assert recs[2].reasons == [] and "reasons" in recs[2].damaged
    assert summary["failure_reasons"] == {"offset_max_mg": 1, "residual_rms_mg": 1, "nvm": 1}
    rows = _report_list(store_url)
    assert rows[0]["reason_codes"] == ["offset_max_mg"] and rows[2]["damaged"] == ["reasons"]
    # new rows are stored typed: the code is kept, whatever the text says
    with Store(store_url) as st:
        rid = st.start_run(device_serial="SN-NEW", lot="NEW")
        st.finish_run(rid, session=s, calibration=fit.calibration, verdict="FAIL",
                      reasons=[Reason.of("verify_error_max_mg", "verify at 70 C: 3.2 mg > limit 2")])
        with st._snapshot():
            raw = st._db.scalar(select(runs.c.reasons).where(runs.c.id == rid))
        assert st.lot_summary(lot="NEW")["failure_reasons"] == {"verify_error_max_mg": 1}
    assert json.loads(raw) == [{"code": "verify_error_max_mg", "message": "verify at 70 C: 3.2 mg > limit 2"}]

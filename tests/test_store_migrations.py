"""Alembic upgrades stores written before Alembic: SQLite files made by the pre-Alembic station
(tests/data/legacy_store_v*.sqlite) and a PostgreSQL database built with that station's DDL
(tests/data/legacy_postgresql_v2.sql) on a real server (tests/pgserver.py)."""
from __future__ import annotations

import json
import shutil
import sqlite3

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from conftest import DATA
from sqlalchemy import create_engine

from accelcal_station.store.runs import Store
from accelcal_station.store.schema import SCHEMA_VERSION
from accelcal_station.store.tables import metadata

TABLES = ("runs", "poses", "events")


def _dump(path) -> dict[str, list[tuple]]:
    with sqlite3.connect(path) as c:
        return {t: c.execute(f"SELECT * FROM {t} ORDER BY 1, 2").fetchall() for t in TABLES}


def _columns(path) -> dict[str, list[tuple]]:
    with sqlite3.connect(path) as c:  # name, declared type, not null, default, primary key
        return {t: [r[1:] for r in c.execute(f"PRAGMA table_info({t})")] for t in TABLES}


def _objects(path) -> set[tuple[str, str]]:
    with sqlite3.connect(path) as c:  # tables and indexes by name
        return set(c.execute("SELECT type, name FROM sqlite_master"))


def test_todays_sqlite_store_is_adopted_with_its_contents_unchanged(tmp_path):
    db = tmp_path / "v3.sqlite"
    shutil.copy(DATA / "legacy_store_v3.sqlite", db)
    before = _dump(db)
    with Store(db) as st:
        assert st.schema_version == SCHEMA_VERSION == 6
        rec = st.get_run(1)
        new = st.start_run(device_serial="SN-NEW")
    assert rec.started_at == 1.7e9 + 0.123456789 and len(rec.poses) == 6 and rec.retries == [0, 1, 0, 0, 2, 0]
    assert rec.nvm_outcome == {"ok": True, "slot": 1, "generation": 4, "crc32": 0x1234ABCD}
    assert [e["kind"] for e in rec.events] == ["nvm_burning", "nvm_burned"]
    after = _dump(db)
    # schema 4 adds runs.limits, schema 5 runs.heartbeat_at and heartbeat_s, schema 6 runs.site and
    # uncertainty (NULL on old runs); nothing else changes; the new run beats
    assert new == 4 and [r[:-5] for r in after["runs"][:3]] == before["runs"] and after["poses"] == before["poses"]
    assert [r[-5:] for r in after["runs"][:3]] == [(None,) * 5] * 3
    assert after["runs"][3][-5] is None and after["runs"][3][-3] == 30.0 and after["runs"][3][-4] > 1.7e9
    assert after["runs"][3][-2:] == (None, None)
    assert after["events"] == before["events"]
    with sqlite3.connect(db) as c:
        assert c.execute("SELECT version_num FROM alembic_version").fetchall() == [("0006",)]
        assert c.execute("PRAGMA user_version").fetchone() == (6,)  # a station older than schema 6 refuses it


def test_schema_2_sqlite_store_is_upgraded_by_alembic(tmp_path):
    db = tmp_path / "v2.sqlite"
    shutil.copy(DATA / "legacy_store_v2.sqlite", db)
    before = _dump(db)
    assert json.loads(before["runs"][1][17]) == ["offset_max_mg 90 > limit 60", "nvm: read-back"]
    with Store(db) as st:
        recs = st.runs(lot="LEG")
        summary = st.lot_summary(lot="LEG")
    assert [(r.code, str(r)) for r in recs[1].reasons] == [("offset_max_mg", "offset_max_mg 90 > limit 60"),
                                                           ("nvm", "nvm: read-back")]
    assert summary["failure_reasons"] == {"offset_max_mg": 1, "nvm": 1}
    after = _dump(db)
    assert after["poses"] == before["poses"] and after["events"] == before["events"]
    changed = [(b[0], i) for b, a in zip(before["runs"], after["runs"], strict=True) for i in range(len(b))
               if a[i] != b[i]]
    assert changed == [(2, 17)]  # only the reasons of the FAIL run
    fresh = tmp_path / "fresh.sqlite"
    Store(fresh).close()
    v3 = _columns(DATA / "legacy_store_v3.sqlite")  # schema 4 adds runs.limits (JSON text) and an index,
    added = [("limits", "TEXT", 0, None, 0), ("heartbeat_at", "REAL", 0, None, 0),  # schema 5 the heartbeat
             ("heartbeat_s", "REAL", 0, None, 0),
             ("site", "TEXT", 0, None, 0), ("uncertainty", "TEXT", 0, None, 0)]  # schema 6 site, uncertainty
    assert _columns(db) == _columns(fresh) == {**v3, "runs": [*v3["runs"], *added]}
    assert _objects(db) == _objects(fresh) == _objects(DATA / "legacy_store_v3.sqlite") | {
        ("table", "alembic_version"), ("index", "sqlite_autoindex_alembic_version_1"), ("index", "runs_station")}


def _no_drift(url: str) -> None:
    """The tables the revisions built are the Core tables the store queries (alembic's compare)."""
    engine = create_engine(url)
    try:
        with engine.connect() as c:
            diff = compare_metadata(MigrationContext.configure(c), metadata)
    finally:
        engine.dispose()
    assert [d for d in diff if d[0] != "remove_table"] == []  # (legacy accelcal_schema is not ours to model)


def test_fresh_sqlite_store_matches_the_core_tables(tmp_path):
    Store(tmp_path / "s.sqlite").close()
    _no_drift(f"sqlite:///{tmp_path / 's.sqlite'}")


def test_pre_alembic_postgresql_store_is_upgraded_by_alembic(pg_server):
    import psycopg

    url = pg_server.new_database()
    dbname = url.split("?")[0].rsplit("/", 1)[1]
    with psycopg.connect(host=pg_server.sock, port=5432, user="accelcal", dbname=dbname, autocommit=True) as c:
        c.execute((DATA / "legacy_postgresql_v2.sql").read_text())
        c.execute("INSERT INTO runs (started_at, status, device_serial, lot, verdict, reasons, fit_summary) "
                  "VALUES (1.7e9 + 0.123456789, 'complete', 'SN-PG', 'PG', 'FAIL', %s, %s)",
                  (json.dumps(["residual_rms_mg 3.1 > limit 2", "nvm: read-back differs"]),
                   json.dumps({"reason_codes": ["residual_rms_mg", "nvm"]})))
        c.execute("INSERT INTO poses (run_id, idx, name, mean_x, mean_y, mean_z) VALUES (1, 0, 'p0', 1, 2, 3)")
    with Store(url, create=False) as st:
        assert st.schema_version == SCHEMA_VERSION
        rec = st.get_run(1)
        new = st.start_run(device_serial="SN-NEW")
    assert rec.started_at == 1.7e9 + 0.123456789 and [p.name for p in rec.poses] == ["p0"]
    assert [(r.code, str(r)) for r in rec.reasons] == [("residual_rms_mg", "residual_rms_mg 3.1 > limit 2"),
                                                       ("nvm", "nvm: read-back differs")]
    assert new == 2
    with psycopg.connect(host=pg_server.sock, port=5432, user="accelcal", dbname=dbname) as c:
        assert c.execute("SELECT version_num FROM alembic_version").fetchall() == [("0006",)]
        assert c.execute("SELECT version FROM accelcal_schema").fetchall() == [(6,)]
    _no_drift("postgresql+psycopg://" + url.split("://", 1)[1])


def test_fresh_postgresql_store_matches_the_core_tables(pg_server):
    url = pg_server.new_database()
    Store(url).close()
    _no_drift("postgresql+psycopg://" + url.split("://", 1)[1])

"""Write the pre-Alembic results stores the upgrade tests open (tests/test_store_migrations.py).

Run with the PRE-ALEMBIC station on the path (commit ca2b967, the last whose store ran its
own migrations), never with this tree's code:

    git worktree add /tmp/pre-alembic ca2b967
    PYTHONPATH=/tmp/pre-alembic python tests/data/make_legacy_stores.py tests/data

Writes legacy_store_v2.sqlite (schema 2: reasons as bare text), legacy_store_v3.sqlite
(schema 3, today's) and legacy_postgresql_v2.sql (that code's PostgreSQL DDL of schema 2,
as its Database.ddl translated it).  Deterministic contents (fixed times, fixed numbers).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

import accelcal_station.store.schema as legacy_schema
from accelcal_station.acceptance.reasons import Reason
from accelcal_station.calibration import Calibration
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.database import Database
from accelcal_station.store.runs import Store

REFS = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]


def _session() -> Session:
    poses = [PoseRecord(f"p{i}", np.array([4096 * a * 1.01 + 3, 4096 * b * 0.99 - 5, 4096 * c + 7]),
                        np.array([2.0, 2.5, 3.0]), 100, np.array([a, b, c], float), 0.0, 0.0, 25.0 + i, i % 2,
                        10.0 * i, 10.0 * i + 2) for i, (a, b, c) in enumerate(REFS)]
    return Session(poses, "counts", 4096.0, device="SN-LEGACY")


def _fill(st: Store, bare_text_reasons: bool) -> None:
    s = _session()
    cal = Calibration(W=np.diag([0.99, 1.01, 1.0]), V=np.array([-0.001, 0.0012, -0.0017]), model="12")
    rid = st.start_run(device_serial="SN-A", chip="mma8451", station_id="st1", operator="op", lot="LEG",
                       config_text="seed: 1\n", model="12", units="counts", counts_per_g=4096.0,
                       started_at=1.7e9 + 0.123456789)
    st.record_burn(rid, "nvm_burning", {"slot": 1, "generation": 4, "crc32": 0x1234ABCD})
    st.record_burn(rid, "nvm_burned", {"slot": 1, "generation": 4, "crc32": 0x1234ABCD})
    st.finish_run(rid, session=s, calibration=cal, verdict="PASS", finished_at=1.7e9 + 60,
                  nvm_outcome={"ok": True, "slot": 1, "generation": 4, "crc32": 0x1234ABCD},
                  fit_summary={"residual_rms_g": 0.00042, "reason_codes": []}, retries=[0, 1, 0, 0, 2, 0])
    rid = st.start_run(device_serial="SN-B", chip="mma8451", station_id="st1", lot="LEG", started_at=1.7e9 + 100)
    reasons = [Reason.of("offset_max_mg", "offset_max_mg 90 > limit 60"), Reason.of("nvm", "nvm: read-back")]
    st.finish_run(rid, session=s, calibration=cal, verdict="FAIL", reasons=reasons, finished_at=1.7e9 + 160,
                  fit_summary={"residual_rms_g": 0.003, "reason_codes": ["offset_max_mg", "nvm"]})
    if bare_text_reasons:  # as a schema-2 station stored them
        with st._tx("legacy reasons") as db:
            db.execute("UPDATE runs SET reasons = ? WHERE id = ?", (json.dumps([str(r) for r in reasons]), rid))
    rid = st.start_run(device_serial="SN-C", station_id="st1", lot="LEG", started_at=1.7e9 + 200)
    st.interrupt_run(rid, "operator stopped the run", session=Session(s.poses[:2], "counts", 4096.0))


def main(out: Path) -> None:
    for version in (2, 3):
        path = out / f"legacy_store_v{version}.sqlite"
        path.unlink(missing_ok=True)
        legacy_schema.SCHEMA_VERSION = version
        with Store(path) as st:
            assert st.schema_version == version
            _fill(st, bare_text_reasons=version == 2)
    db = Database.__new__(Database)
    db.dialect = "postgresql"
    stmts = [db.ddl(x).strip() for step in legacy_schema.MIGRATIONS[:2] for x in step.split(";") if x.strip()]
    stmts.append("CREATE TABLE accelcal_schema (version INTEGER NOT NULL)")
    stmts.append("INSERT INTO accelcal_schema (version) VALUES (2)")
    (out / "legacy_postgresql_v2.sql").write_text(
        "-- PostgreSQL DDL of results-store schema 2 as the pre-Alembic station (ca2b967) ran it;\n"
        "-- written by tests/data/make_legacy_stores.py\n" + ";\n".join(stmts) + ";\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]))

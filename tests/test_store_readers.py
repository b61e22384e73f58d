"""Issue 53: reading commands never write a store.  `report list`, `show`, `export`, `summary`
and `batch --from-store` on a store whose Alembic revision is missing or empty leave it byte for
byte as it was and say in one line what it is (its schema, from its columns); on a store whose
columns are an older schema's they refuse in one line, unchanged; `report migrate` is what
records the revision, and says so."""
from __future__ import annotations

import hashlib
import shutil
import sqlite3
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_store_damage import _good_store

from accelcal_station.cli import cli
from accelcal_station.store.schema import SCHEMA_VERSION

DATA = Path(__file__).parent / "data"


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _readers(db: Path, out: Path) -> list[list[str]]:
    return [["report", "list", "--db", str(db)], ["report", "show", "1", "--db", str(db)],
            ["report", "export", "--db", str(db), "-o", str(out / "runs.json")],
            ["report", "summary", "--db", str(db)], ["batch", "--from-store", str(db), "--model", "12"]]


def _current_store(path: Path, how: str) -> None:
    _good_store(path)
    with sqlite3.connect(path) as c:
        c.execute("DELETE FROM alembic_version" if how == "empty" else "DROP TABLE alembic_version")


@pytest.mark.parametrize("how", ["empty", "missing"])
def test_readers_leave_an_unstamped_current_store_byte_identical_and_name_it(tmp_path, how):
    db = tmp_path / "store.sqlite"
    _current_store(db, how)
    before = _sha(db)
    table = "alembic_version is empty" if how == "empty" else "no alembic_version table"
    for args in _readers(db, tmp_path):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code == 0, (args, r.output, r.stderr)
        named = [line for line in r.stderr.splitlines() if "no schema revision recorded" in line]
        assert len(named) == 1 and table in named[0], (args, r.stderr)
        assert f"columns are schema {SCHEMA_VERSION}'s" in named[0], (args, r.stderr)
        assert _sha(db) == before, args  # nothing stamped, nothing else written


def test_readers_refuse_a_store_whose_columns_are_older_than_its_marker_in_one_line(tmp_path):
    db = tmp_path / "v3.sqlite"
    shutil.copy(DATA / "legacy_store_v3.sqlite", db)  # schema 3's columns, no Alembic revision
    with sqlite3.connect(db) as c:
        c.execute("PRAGMA user_version = 5")  # a marker that lies: a stamp by it would be wrong and permanent
    before = _sha(db)
    for args in _readers(db, tmp_path):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code != 0 and "Traceback" not in r.output, (args, r.output)
        err = [line for line in (r.stderr or r.output).splitlines() if line.strip()]
        assert len(err) == 1 and "columns are schema 2 or 3's" in err[0] and "report migrate" in err[0], (args, err)
        assert _sha(db) == before, args


def test_report_migrate_stamps_what_the_columns_say_and_upgrades_saying_so(tmp_path):
    db = tmp_path / "v3.sqlite"
    shutil.copy(DATA / "legacy_store_v3.sqlite", db)
    with sqlite3.connect(db) as c:
        c.execute("PRAGMA user_version = 5")
    r = CliRunner().invoke(cli, ["report", "migrate", "--db", str(db)])
    assert r.exit_code == 0 and f"upgraded to {SCHEMA_VERSION}" in r.output, (r.output, r.stderr)
    with sqlite3.connect(db) as c:
        assert c.execute("SELECT version_num FROM alembic_version").fetchall() == [(f"{SCHEMA_VERSION:04d}",)]
        cols = {row[1] for row in c.execute("PRAGMA table_info(runs)")}
    assert {"limits", "heartbeat_at", "heartbeat_s", "site", "uncertainty"} <= cols  # 0004-0006 ran
    listed = CliRunner().invoke(cli, ["report", "list", "--db", str(db)])
    assert listed.exit_code == 0 and listed.stderr == "", listed.stderr
    again = CliRunner().invoke(cli, ["report", "migrate", "--db", str(db)])
    assert again.exit_code == 0 and "nothing written" in again.output

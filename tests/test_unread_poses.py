"""Issue 53: every lot counts every run.  A complete run whose pose rows cannot be read (their
``run_id`` made 2.5, or the rows deleted) is a SKIP line with its reason in every reader of a store
(``batch --from-store``, the twin's store source, ``report export``) and is counted as skipped.

The store is real SQLite (three complete runs of six poses each); the damage is made with SQL as
an outside tool would.
"""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from click.testing import CliRunner
from test_store_outputs import _store

from accelcal_station.cli import cli
from accelcal_station.twin.store_source import store_stats


def _damaged(tmp_path: Path, sql: str) -> Path:
    db = tmp_path / "s.sqlite"
    _store(db)
    with sqlite3.connect(db) as c:
        c.execute(sql)
    return db


DAMAGE = {"run_id 2.5": "UPDATE poses SET run_id = 2.5 WHERE run_id = 2",
          "rows deleted": "DELETE FROM poses WHERE run_id = 2"}


@pytest.mark.parametrize("damage", DAMAGE)
def test_batch_from_store_names_the_run(tmp_path, damage):
    db = _damaged(tmp_path, DAMAGE[damage])
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(db)])
    assert r.exit_code == 1, r.output  # some boards skipped
    skips = [ln for ln in r.output.splitlines() if ln.startswith("SKIP")]
    assert skips == ["SKIP run 2: poses_unreadable: complete, but none of its pose rows can be read "
                     "(see report check)"], r.output
    assert "2 of 3 boards recalibrated" in r.output and "1 skipped" in r.output, r.output


def test_batch_json_counts_the_run(tmp_path):
    db = _damaged(tmp_path, DAMAGE["run_id 2.5"])
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(db), "--json"])
    doc = json.loads(r.output)
    assert (doc["boards"], doc["fitted"], doc["skipped"]) == (3, 2, 1), doc
    bad = [d for d in doc["results"] if not d["ok"]]
    assert [d["source"] for d in bad] == ["run 2"] and "poses_unreadable" in bad[0]["message"]


def test_fewer_poses_than_the_fit_used(tmp_path):
    """Some of a run's rows deleted: its fit summary's pose_count (6) says how many it had."""
    db = _damaged(tmp_path, "DELETE FROM poses WHERE run_id = 3 AND idx < 2")
    with sqlite3.connect(db) as c:
        c.execute("""UPDATE runs SET fit_summary = '{"pose_count": 6}'""")
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(db)])
    assert "SKIP run 3: poses_unreadable: only 4 of the 6 pose rows its fit used can be read" in r.output, r.output
    assert r.exit_code == 1


def test_the_twin_counts_the_run(tmp_path):
    db = _damaged(tmp_path, DAMAGE["run_id 2.5"])
    skips: list[tuple[str, str]] = []
    stats, _ = store_stats(str(db), None, skips=skips)
    assert [s[0] for s in skips] == ["run 2"] and skips[0][1].startswith("poses_unreadable")
    assert stats.skipped == 1


@pytest.mark.parametrize("poses", [[], ["--poses"]])
def test_the_export_names_the_run(tmp_path, poses):
    db = _damaged(tmp_path, DAMAGE["rows deleted"])
    r = CliRunner().invoke(cli, ["report", "export", "--db", str(db), *poses, "-o", str(tmp_path / "e.csv")])
    assert r.exit_code == 0, r.output
    assert "SKIP run 2: poses_unreadable" in r.output, r.output

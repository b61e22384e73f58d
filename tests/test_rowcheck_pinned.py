"""Issue 53: a NULL in a required store column is damage, named by `report check` on a real SQLite
file, and every column's checker pinned to values written here (the schema's required columns,
the 64-bit id range, the years ISO 8601 can say, JSON depth).

SQLite declares the required columns NOT NULL, so the damaged store is made the way another
program or a hand edit makes one: the table's declaration rewritten without NOT NULL
(``PRAGMA writable_schema``), then the values set to NULL.  The file is a real store written by
`accelcal run` on the simulated board."""
from __future__ import annotations

import hashlib
import json
import math
import sqlite3

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.store.rowcheck import JSON_MAX_DEPTH, SPECS, T_MAX_S, T_MIN_S, check_row, json_depth

# the columns the schema requires (store/tables.py: NOT NULL, or the key), written out here
REQUIRED = {
    "runs": {"id", "started_at", "status"},
    "poses": {"run_id", "idx", "name", "mean_x", "mean_y", "mean_z", "dropped", "retries"},
    "events": {"id", "run_id", "t", "kind"},
}
GOOD = {
    "runs": {"id": 1, "started_at": 1.7e9, "status": "complete", "finished_at": 1.7e9 + 5, "verdict": "PASS",
             "reasons": "[]", "limits": '{"residual_rms_mg": 1.0}', "counts_per_g": 4096.0, "pid": 12},
    "poses": {"run_id": 1, "idx": 0, "name": "p1", "mean_x": 4096.0, "mean_y": -3.5, "mean_z": 12.0,
              "dropped": 0, "retries": 0, "n": 200, "std_x": 2.9, "temp_c": 25.0},
    "events": {"id": 1, "run_id": 1, "t": 1.7e9, "kind": "nvm_burned", "data": '{"ok": true}'},
}


def test_the_required_columns_are_the_schemas():
    assert {t: {c for c, (_, req) in spec.items() if req} for t, spec in SPECS.items()} == REQUIRED


@pytest.mark.parametrize("table,col", sorted((t, c) for t, cols in SPECS.items() for c in cols))
def test_a_null_is_damage_exactly_where_a_value_is_required(table, col):
    assert check_row(table, GOOD[table]).damage == []
    row = check_row(table, {**GOOD[table], col: None})
    if col in REQUIRED[table]:
        assert [(d.table, d.column, d.problem) for d in row.damage] == [(table, col, "empty where a value is required")]
        assert row.value(col) is None and row.damage[0].reason().code == "damaged_row"
    else:
        assert row.damage == []


@pytest.mark.parametrize("col,value,ok", [
    ("id", 2**63 - 1, True), ("id", -(2**63), True), ("id", 2**63, False), ("id", True, False), ("id", 1.0, False),
    ("started_at", T_MIN_S, True), ("started_at", T_MAX_S, True), ("started_at", T_MAX_S + 1, False),
    ("started_at", T_MIN_S - 1, False), ("started_at", math.nan, False), ("started_at", "1.7e9", False),
    ("counts_per_g", 0.0, True), ("counts_per_g", 1e12, True), ("counts_per_g", -1e-9, False),
    ("counts_per_g", 1.1e12, False), ("counts_per_g", math.inf, False), ("pid", 2**31 - 1, True), ("pid", 2**31, False),
    ("pid", -1, False), ("status", "complete", True), ("status", "done", False), ("verdict", "MAYBE", False),
    ("reasons", '[{"code": "x", "message": "y"}, "text"]', True), ("reasons", '[{"code": 3}]', False),
    ("reasons", "{}", False), ("limits", '{"a": 1e400}', False), ("limits", '{"a": true}', False),
    ("limits", '{"a": NaN}', False), ("heartbeat_s", 1e6, True), ("heartbeat_s", 1e6 + 1, False),
    ("gravity_mps2", 1e3, True), ("gravity_mps2", 1001.0, False), ("operator", 5, False),
])
def test_each_runs_column_checker_at_its_bounds(col, value, ok):
    row = check_row("runs", {**GOOD["runs"], col: value})
    assert (row.damage == []) is ok, row.damage
    assert all(d.column == col for d in row.damage)


def test_json_depth_counts_brackets_outside_strings():
    assert json_depth('{"a": "[[[[", "b": [[1]]}') == 3
    assert json_depth("[]") == 1 and json_depth("") == 0 and json_depth('"{"') == 0
    deep = "[" * (JSON_MAX_DEPTH + 1) + "]" * (JSON_MAX_DEPTH + 1)
    ok = "[" * JSON_MAX_DEPTH + "]" * JSON_MAX_DEPTH
    assert check_row("events", {**GOOD["events"], "data": ok}).damage == []
    (d,) = check_row("events", {**GOOD["events"], "data": deep}).damage
    assert d.problem == f"JSON nested {JSON_MAX_DEPTH + 1} levels; allowed at most {JSON_MAX_DEPTH}"


def _drop_not_null(path) -> None:
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("PRAGMA writable_schema=ON")
    for t in ("runs", "poses", "events"):
        (sql,) = db.execute("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = ?", (t,)).fetchone()
        db.execute("UPDATE sqlite_master SET sql = ? WHERE type = 'table' AND name = ?",
                   (sql.replace(" NOT NULL", ""), t))
    db.execute("PRAGMA writable_schema=OFF")
    db.close()


def test_report_check_names_every_null_in_a_required_column_of_a_real_store(tmp_path):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["seed"] = 7
    (tmp_path / "station.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "station.yaml"), "--json"])
    assert r.exit_code == 0, r.output
    store = tmp_path / "runs.sqlite"
    clean = CliRunner().invoke(cli, ["report", "check", "--db", str(store), "--json"])
    assert clean.exit_code == 0 and json.loads(clean.stdout)["damaged"] == []
    _drop_not_null(store)
    db = sqlite3.connect(store)
    db.execute("UPDATE runs SET status = NULL")
    db.execute("UPDATE poses SET mean_y = NULL WHERE idx = 2")
    db.execute("UPDATE poses SET name = NULL WHERE idx = 5")
    (eid,) = db.execute("SELECT min(id) FROM events").fetchone()
    db.execute("UPDATE events SET kind = NULL WHERE id = ?", (eid,))
    db.commit()
    (run_id,) = db.execute("SELECT id FROM runs").fetchone()
    db.close()
    before = hashlib.sha256(store.read_bytes()).hexdigest()
    r = CliRunner().invoke(cli, ["report", "check", "--db", str(store), "--json"])
    assert r.exit_code == 1, r.output
    got = {(d["table"], d["id"], d["column"], d["problem"]) for d in json.loads(r.stdout)["damaged"]}
    empty = "empty where a value is required"
    assert got == {("runs", str(run_id), "status", empty), ("poses", f"{run_id}/2", "mean_y", empty),
                   ("poses", f"{run_id}/5", "name", empty), ("events", str(eid), "kind", empty)}
    text = CliRunner().invoke(cli, ["report", "check", "--db", str(store)])
    assert text.exit_code == 1 and "4 damaged value(s) in 4 row(s)" in text.output
    assert hashlib.sha256(store.read_bytes()).hexdigest() == before  # a reader reads


def test_sizes_and_times_at_their_documented_bounds():
    """16 Mi characters of text or JSON; times from year 1 to the end of 9999 (unix seconds, written here)."""
    big = 16 * 2**20
    assert check_row("runs", {**GOOD["runs"], "operator": "a" * big}).damage == []
    (d,) = check_row("runs", {**GOOD["runs"], "operator": "a" * (big + 1)}).damage
    assert d.problem == f"text of {big + 1} characters; allowed at most {big}"
    (d,) = check_row("events", {**GOOD["events"], "data": '"' + "a" * (big - 1) + '"'}).damage
    assert d.problem == f"JSON of {big + 1} characters; allowed at most {big}"
    year1, end9999 = -62135596800.0, 253402300799.0  # 0001-01-01T00:00:00Z, 9999-12-31T23:59:59Z
    for t, ok in ((year1, True), (end9999, True), (year1 - 1, False), (end9999 + 1, False), (0.0, True)):
        assert (check_row("events", {**GOOD["events"], "t": t}).damage == []) is ok, t
    (d,) = check_row("events", {**GOOD["events"], "t": end9999 + 1}).damage
    assert d.problem.startswith("time ") and d.problem.endswith("allowed years 1..9999 as unix seconds")


def test_json_columns_of_the_wrong_kind_and_calibrations():
    from accelcal_station.calibration import Calibration

    (d,) = check_row("events", {**GOOD["events"], "data": 5}).damage
    assert d.problem == "int where JSON text belongs"
    (d,) = check_row("runs", {**GOOD["runs"], "fit_summary": "[1, 2]"}).damage
    assert d.problem == "JSON list where a JSON dict belongs"
    (d,) = check_row("runs", {**GOOD["runs"], "fit_summary": '{"skipped": [1]}'}).damage
    assert d.problem == "fit summary 'skipped' is not a list of pose names"
    (d,) = check_row("runs", {**GOOD["runs"], "fit_summary": '{"timing": 3}'}).damage
    assert d.problem == "fit summary 'timing' is not an object"
    assert check_row("runs", {**GOOD["runs"], "fit_summary": '{"skipped": ["p2"], "timing": {}}'}).damage == []
    cal = Calibration("12", [[1.01, 0, 0], [0, 0.99, 0.002], [0, 0, 1]], [0.01, 0, -0.02], input_units="counts",
                      input_per_g=4096.0).to_dict()
    row = check_row("runs", {**GOOD["runs"], "calibration": json.dumps(cal)})
    assert row.damage == [] and row.json_object("calibration")["W"][0][0] == 1.01
    for bad in ('"x"', "[]", json.dumps({**cal, "W": [[1, 0], [0, 1]]})):
        (d,) = check_row("runs", {**GOOD["runs"], "calibration": bad}).damage
        assert d.column == "calibration" and ("calibration" in d.problem or "belongs" in d.problem), d.problem
    assert check_row("runs", {**GOOD["runs"], "heartbeat_s": 0.0}).damage == []


def test_checked_values_read_typed_and_only_the_columns_asked():
    from accelcal_station.store.rowcheck import CheckedRow

    row = check_row("runs", {**GOOD["runs"], "pid": True, "counts_per_g": 4096})
    assert [d.column for d in row.damage] == ["pid"]
    assert row.int("id") == 1 and row.int("pid") is None and row.int("status") is None
    assert row.real("counts_per_g") == 4096.0 and isinstance(row.real("counts_per_g"), float)
    assert row.real("status") is None and row.text("status") == "complete" and row.text("id") is None
    assert row.json_list("reasons") == [] and row.json_object("reasons") is None
    assert row.json_object("limits") == {"residual_rms_mg": 1.0} and row.numbers("limits") == {"residual_rms_mg": 1.0}
    assert row.numbers("reasons") is None and row.value("missing") is None and "id" in row
    assert check_row("runs", {**GOOD["runs"], "id": True}).int("id") is None
    only = CheckedRow("runs", {**GOOD["runs"], "pid": "x", "status": "nope"}, frozenset({"status"}))
    assert [d.column for d in only.damage] == ["status"] and only.value("pid") == "x"
    assert check_row("runs", GOOD["runs"]).damage == []  # damage lists are never shared between rows


def test_json_of_exactly_the_largest_size_is_read():
    big = 16 * 2**20
    assert check_row("events", {**GOOD["events"], "data": '"' + "a" * (big - 2) + '"'}).damage == []


def test_a_damaged_value_reads_as_none():
    row = check_row("runs", {**GOOD["runs"], "status": "done", "limits": "{bad"})
    assert row.value("status") is None and row.json("limits") is None and row.numbers("limits") is None
    assert [d.column for d in row.damage] == ["status", "limits"] and row.value("verdict") == "PASS"

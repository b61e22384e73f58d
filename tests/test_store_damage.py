"""A damaged results store is read, never fatal: every table's values nested 10,000 levels deep,
times beyond year 9999 and wrong-typed fields are shown as `damaged_row` reasons by `report
list/show/export/summary` (exit 0, never 70) and listed, all of them, by `report check`
(exit 1, the file unchanged).  Real SQLite files, a real PostgreSQL server, the real CLI."""
from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3

import hypothesis.strategies as st
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, reject, settings

from accelcal_station.cli import cli
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.records import StoreError
from accelcal_station.store.rowcheck import JSON_MAX_DEPTH, json_depth
from accelcal_station.store.runs import Store

DEEP = "[" * 10_000 + "]" * 10_000
REFS = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
# (table, column, value) written into run 2 (its pose 0 and first event); every one is damage
# (SQLite's column affinity turns 12.5 into the text "12.5" in a TEXT column: blobs stay what they are)
HOSTILE = [
    ("runs", "reasons", DEEP), ("runs", "nvm_outcome", "{\"a\":" * 10_000 + "1" + "}" * 10_000),
    ("runs", "calibration", DEEP), ("runs", "fit_summary", DEEP),
    ("runs", "started_at", 1e300), ("runs", "finished_at", 253402300800.0),  # 10000-01-01
    ("runs", "status", 5), ("runs", "pid", "not a pid"), ("runs", "counts_per_g", "4096 counts"),
    ("runs", "device_serial", b"SN\x002"), ("runs", "verdict", b"\x00PASS"),
    ("poses", "mean_x", "zzz"), ("poses", "n", 1.5), ("poses", "name", b"\xff\xfe"), ("poses", "t_start", 1e999),
    ("events", "data", DEEP), ("events", "t", 1e300), ("events", "kind", b"\x07"),
]


def _session() -> Session:
    return Session([PoseRecord(f"p{i}", np.array([4096.0 * a + 3, 4096.0 * b - 5, 4096.0 * c + 7]), np.full(3, 2.0),
                               100, np.array([a, b, c], float)) for i, (a, b, c) in enumerate(REFS)],
                   "counts", 4096.0, device="SN")


def _good_store(path) -> None:
    from accelcal_station.models.fitting import fit_session

    s = _session()
    fit = fit_session(s, "12")
    with Store(path) as st_:
        for i in range(3):
            rid = st_.start_run(device_serial=f"SN{i}", lot="L", started_at=1.7e9 + i)
            st_.record_burn(rid, "nvm_burning", {"slot": 0, "generation": 1, "crc32": 1})
            st_.finish_run(rid, session=s, calibration=fit.calibration, verdict="PASS",
                           nvm_outcome={"ok": True}, fit_summary={"residual_rms_g": 0.001})


def _damage(path, items) -> None:
    with sqlite3.connect(path) as c:
        c.execute("PRAGMA ignore_check_constraints = ON")
        for table, col, value in items:
            where = {"runs": "id = 2", "poses": "run_id = 2 AND idx = 0",
                     "events": "id = (SELECT min(id) FROM events WHERE run_id = 2)"}[table]
            c.execute(f"UPDATE {table} SET {col} = ? WHERE {where}", (value,))


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    path = tmp_path_factory.mktemp("store") / "good.sqlite"
    _good_store(path)
    return path


def test_every_damaged_value_is_named_and_nothing_fails(template, tmp_path):
    db = tmp_path / "damaged.sqlite"
    shutil.copy(template, db)
    _damage(db, HOSTILE)
    run = CliRunner().invoke
    for args in (["list"], ["list", "--json"], ["show", "2"], ["show", "2", "--json"], ["export"],
                 ["export", "--poses"], ["export", "--format", "json"], ["summary"], ["summary", "--json"]):
        r = run(cli, ["report", *args, "--db", str(db)])
        assert r.exit_code in (0, 1), (args, r.output)
        assert "Traceback" not in r.output and "damaged_row" in r.output, (args, r.output[-500:])
    r = run(cli, ["report", "list", "--db", str(db), "--json"])
    listed = {(d["table"], d["column"]) for x in json.loads(r.stdout) for d in x.get("damage", [])}
    assert listed == {(t, c) for t, c, _ in HOSTILE if t == "runs"}
    shown = json.loads(run(cli, ["report", "show", "2", "--db", str(db), "--json"]).stdout)
    assert {(d["table"], d["column"]) for d in shown["damage"]} == {(t, c) for t, c, _ in HOSTILE}
    assert len(shown["poses"]) == len(REFS) - 1 and shown["status"] is None and shown["started_at"] is None
    before = _sha(db)
    r = run(cli, ["report", "check", "--db", str(db), "--json"])
    assert r.exit_code == 1 and _sha(db) == before
    found = json.loads(r.stdout)["damaged"]
    assert sorted((d["table"], d["column"]) for d in found) == sorted((t, c) for t, c, _ in HOSTILE)
    assert {d["id"] for d in found} == {"2", "2/0"} | {d["id"] for d in found if d["table"] == "events"}
    text = run(cli, ["report", "check", "--db", str(db)])
    assert text.exit_code == 1 and f"{len(HOSTILE)} damaged value(s) in 3 row(s)" in text.output
    clean = run(cli, ["report", "check", "--db", str(template)])
    assert clean.exit_code == 0 and "no damaged rows" in clean.output


def test_depth_scanner_counts_brackets_outside_strings():
    assert json_depth('{"a": [1, {"b": "[[[[[[" }], "c": "\\"]]"}') == 3
    assert json_depth(DEEP) == 10_000 and json_depth("") == 0 and json_depth('"[[["') == 0


def test_damaged_postgresql_rows_are_named(pg_server):
    """PostgreSQL columns are typed, but DOUBLE holds NaN and 1e300 and TEXT holds any JSON."""
    import psycopg

    url = pg_server.new_database()
    _good_store(url)
    dbname = url.split("?")[0].rsplit("/", 1)[1]
    with psycopg.connect(host=pg_server.sock, port=5432, user="accelcal", dbname=dbname, autocommit=True) as c:
        c.execute("UPDATE runs SET calibration = %s, started_at = 1e300 WHERE id = 2", (DEEP,))
        c.execute("UPDATE poses SET mean_y = 'NaN' WHERE run_id = 2 AND idx = 1")
        c.execute("UPDATE events SET t = '-Infinity' WHERE run_id = 3")
    r = CliRunner().invoke(cli, ["report", "check", "--db", url, "--json"])
    assert r.exit_code == 1, r.output
    assert sorted((d["table"], d["id"], d["column"]) for d in json.loads(r.stdout)["damaged"]) == [
        ("events", "3", "t"), ("poses", "2/1", "mean_y"), ("runs", "2", "calibration"), ("runs", "2", "started_at")]
    for args in (["list"], ["summary"], ["export", "--format", "json"], ["show", "2"]):
        r = CliRunner().invoke(cli, ["report", *args, "--db", url])
        assert r.exit_code in (0, 1) and "damaged_row" in r.output, (args, r.output[-500:])


COLUMNS = {"runs": ["started_at", "finished_at", "status", "device_serial", "counts_per_g", "verdict", "reasons",
                    "nvm_outcome", "calibration", "fit_summary", "pid", "nvm_status"],
           "poses": ["name", "mean_x", "std_y", "ref_z", "n", "dropped", "retries", "temp_c", "t_end"],
           "events": ["t", "kind", "message", "data"]}
KIND = {**dict.fromkeys(["reasons", "nvm_outcome", "calibration", "fit_summary", "data"], "json"),
        **dict.fromkeys(["started_at", "finished_at", "t"], "time"),
        **dict.fromkeys(["counts_per_g", "mean_x", "std_y", "ref_z", "temp_c", "t_end"], "real"),
        **dict.fromkeys(["pid", "n", "dropped", "retries"], "int"),
        **dict.fromkeys(["device_serial", "nvm_status", "name", "kind", "message"], "text"),
        "status": "choice", "verdict": "choice"}
nested = st.integers(JSON_MAX_DEPTH + 1, 3000).map(lambda n: "[" * n + "]" * n)
words = st.text(alphabet="bcxyz -", min_size=1, max_size=20)  # never a number SQLite's affinity would convert
ALWAYS_BAD = {  # values wrong for every column of the kind
    "json": st.one_of(nested, st.sampled_from(["{", "[1,]", "NaN", "1e999", '{"a": Infinity}']), st.binary(min_size=1),
                      st.integers()),
    "time": st.one_of(st.floats(allow_nan=False).filter(lambda x: abs(x) > 2.6e11), words, st.binary(min_size=1)),
    "real": st.one_of(words, st.binary(min_size=1), st.sampled_from([float("inf"), -float("inf")])),
    "int": st.one_of(words, st.floats(allow_nan=False).filter(lambda x: x != int(x) if abs(x) < 1e15 else True),
                     st.binary(min_size=1)),
    "text": st.binary(min_size=1),  # a number becomes text under TEXT affinity: only a blob stays wrong
    "choice": st.one_of(words.filter(lambda w: w not in ("running", "complete", "interrupted", "error", "PASS",
                                                         "FAIL")), st.integers()),
}
anything = st.one_of(st.none(), st.integers(-2**63, 2**63 - 1), st.floats(), st.text(max_size=50), st.binary(),
                     nested, st.recursive(st.none() | st.integers() | st.text(max_size=5),
                                          lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=3), c,
                                                                                              max_size=3)).map(json.dumps))


@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(table=st.sampled_from(sorted(COLUMNS)), data=st.data(), bad=st.booleans())
def test_hostile_rows_never_raise_and_the_bad_ones_are_named(template, tmp_path, table, data, bad):
    """Property: whatever one value of one row holds, every read returns (a StoreError would
    fail the test too: the file is sound), and a value wrong for its column's kind is named
    by check().  25 examples, derandomised (the same examples every run)."""
    col = data.draw(st.sampled_from(COLUMNS[table]))
    value = data.draw(ALWAYS_BAD[KIND[col]] if bad else anything)
    db = tmp_path / f"h{abs(hash((table, col, repr(value)))) % 10**9}.sqlite"
    shutil.copy(template, db)
    try:
        _damage(db, [(table, col, value)])
    except sqlite3.IntegrityError:  # NULL in a NOT NULL column: a store cannot hold it
        reject()
    with Store(db, create=False) as s:
        s.list_runs()
        recs = s.runs()
        s.lot_summary()
        s.export_csv(kind="poses")
        s.export_json()
        found = s.check()
    assert all(r.to_dict() for r in recs)
    if bad:
        assert (table, col) in {(d.table, d.column) for d in found}, value
    db.unlink()


def test_a_store_that_is_not_readable_is_one_store_error(tmp_path):
    db = tmp_path / "x.sqlite"
    db.write_bytes(b"SQLite format 3\x00" + b"\xff" * 4000)
    with pytest.raises(StoreError):
        Store(db, create=False).check()


# -- issue 34: one bad cell never takes down the store; every damaged run is named where it is read
ISSUE34 = {
    "bad_text": ["UPDATE runs SET operator = CAST(x'6f70ff32' AS TEXT) WHERE id = 2"],
    "bad_serial_text": ["UPDATE runs SET device_serial = CAST(x'534e32c3' AS TEXT) WHERE id = 2"],
    "bad_pose_name": ["UPDATE poses SET name = CAST(x'ff' AS TEXT) WHERE run_id = 2 AND idx = 0"],
    "yesterday": ["UPDATE runs SET started_at = 'yesterday' WHERE id = 2"],
}


def _sql(path, statements) -> None:
    with sqlite3.connect(path) as c:
        for s in statements:
            c.execute(s)


def _cmds(db) -> list[list[str]]:
    return [["report", "list", "--db", db], ["report", "list", "--json", "--db", db], ["report", "check", "--db", db],
            ["report", "export", "--db", db], ["report", "export", "--poses", "--db", db],
            ["report", "summary", "--db", db], ["batch", "--from-store", db], ["twin", "fit", "--db", db, "-o",
                                                                               "twin.yaml"]]


@pytest.mark.parametrize("case", sorted(ISSUE34))
def test_one_bad_cell_is_a_damaged_row_of_its_run(template, tmp_path, monkeypatch, case):
    monkeypatch.chdir(tmp_path)
    db = tmp_path / "v.sqlite"
    shutil.copy(template, db)
    _sql(db, ISSUE34[case])
    before = _sha(db)
    for args in _cmds(str(db)):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code in (0, 1, 2) and "Traceback" not in r.output, (args, r.output[-800:])
        if case != "bad_pose_name" or args[1] not in ("list", "summary"):  # those two list runs, not poses
            assert any(w in r.output for w in ("damaged_row", "DAMAGED", "damaged value")), (args, r.output[-800:])
    assert _sha(db) == before
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(db)])
    skips = [ln for ln in r.output.splitlines() if ln.startswith("SKIP")]
    assert len(skips) == 1 and "damaged_row" in skips[0] and r.exit_code == 1, r.output
    assert "2 of 3 boards recalibrated" in r.output and "1 skipped" in r.output, r.output
    r = CliRunner().invoke(cli, ["twin", "fit", "--db", str(db), "-o", "twin.yaml"])
    assert sum(ln.startswith("SKIP") and "damaged_row" in ln for ln in r.output.splitlines()) == 1, r.output


def test_negative_and_large_ids_are_shown(template, tmp_path):
    """The outbox numbers runs not yet on the server below 0: a run id is any 64-bit integer."""
    db = tmp_path / "v.sqlite"
    shutil.copy(template, db)
    _sql(db, ["PRAGMA foreign_keys = OFF", "UPDATE runs SET id = -5 WHERE id = 3",
              "UPDATE poses SET run_id = -5 WHERE run_id = 3", "UPDATE events SET run_id = -5 WHERE run_id = 3",
              "UPDATE runs SET id = 9223372036854775807 WHERE id = 1",
              "UPDATE poses SET run_id = 9223372036854775807 WHERE run_id = 1",
              "UPDATE events SET run_id = 9223372036854775807 WHERE run_id = 1"])
    r = CliRunner().invoke(cli, ["report", "list", "--db", str(db)])
    assert r.exit_code == 0 and "damaged_row" not in r.output, r.output
    ids = [ln.split()[0] for ln in r.output.splitlines()[1:-1]]
    assert sorted(ids) == sorted(["-5", "2", "9223372036854775807"]), r.output
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(db)])
    assert r.exit_code == 0 and "3 of 3 boards" in r.output, r.output


def _flipped(template, tmp_path, seed: int):
    """A copy of the store with 8 random bits flipped past its first page (seeded: the same every run)."""
    data = bytearray(template.read_bytes())
    rng = np.random.default_rng(seed)
    for pos in rng.integers(4096, len(data), 8):
        data[pos] ^= 1 << int(rng.integers(8))
    db = tmp_path / f"flip{seed}.sqlite"
    db.write_bytes(bytes(data))
    return db


@pytest.mark.parametrize("seed", range(30))
def test_bit_flips_never_crash_a_reader(template, tmp_path, monkeypatch, seed):
    """30 seeded copies with 8 flipped bits each: every reader answers with rows, damaged_row or one
    error line (exit 0, 1 or 2), never an internal error (70) or a traceback; report check exits 1
    on every copy it can open whose flips it can see (a flip in free space changes nothing)."""
    monkeypatch.chdir(tmp_path)
    db = _flipped(template, tmp_path, seed)
    before = _sha(db)
    for args in _cmds(str(db)):
        r = CliRunner().invoke(cli, args)
        assert r.exit_code in (0, 1, 2) and "Traceback" not in r.output, (seed, args, r.output[-800:])
        if r.exit_code == 2:
            # one error line (under --json: one JSON object)
            said = [ln for ln in r.output.splitlines() if ln.startswith("error") or '"code": 2' in ln]
            assert len(said) == 1, (args, r.output)
    assert _sha(db) == before


def test_report_check_names_the_tables_whose_pages_it_cannot_read(template, tmp_path):
    """A page header overwritten (the poses table's root): check names the table, its root page and the
    rows it could not read, and the rest of the store is still listed."""
    db = tmp_path / "p.sqlite"
    shutil.copy(template, db)
    with sqlite3.connect(db) as c:
        root = c.execute("SELECT rootpage FROM sqlite_master WHERE name = 'poses'").fetchone()[0]
        page = c.execute("PRAGMA page_size").fetchone()[0]
    data = bytearray(db.read_bytes())
    for i in range(page * (root - 1), page * (root - 1) + 40):
        data[i] ^= 0x5A
    db.write_bytes(bytes(data))
    r = CliRunner().invoke(cli, ["report", "check", "--db", str(db), "--json"])
    assert r.exit_code == 1, r.output
    doc = json.loads(r.stdout)
    assert any(f"table poses (b-tree at page {root}" in p and "cannot be read" in p for p in doc["integrity"]), doc
    assert any(d["table"] == "poses" and d["column"] == "*" for d in doc["damaged"]), doc
    r = CliRunner().invoke(cli, ["report", "list", "--db", str(db)])
    assert r.exit_code in (0, 2) and "Traceback" not in r.output

"""The web pages and the MES API on a damaged store (issue 25: every read of a stored row is
checked): each hostile value of tests/test_store_damage.py in turn, every page and endpoint
answers (never a 500), and the API names the damaged value as the store's damaged_row."""
from __future__ import annotations

import pytest
from test_store_damage import HOSTILE, _damage, _good_store

pytest.importorskip("fastapi", reason="the web extra (pip install 'accelcal-station[web]')")
pytest.importorskip("httpx", reason="fastapi's test client needs httpx")
from fastapi.testclient import TestClient

from accelcal_station.web.app import create_app
from accelcal_station.web.settings import WebSettings

URLS = ("/", "/lots", "/board/SN1", "/board/SN2", "/api/v1/runs", "/api/v1/runs/1", "/api/v1/runs/2",
        "/api/v1/yield", "/openapi.json")
RUN_COLUMNS = [(t, c, v) for t, c, v in HOSTILE if t == "runs"]


@pytest.mark.parametrize("item", HOSTILE, ids=[f"{t}.{c}" for t, c, _ in HOSTILE])
def test_every_page_answers_on_a_damaged_store(tmp_path, item):
    path = tmp_path / "store.sqlite"
    _good_store(path)
    _damage(path, [item])
    client = TestClient(create_app(WebSettings(store=str(path))), raise_server_exceptions=False)
    for url in URLS:
        r = client.get(url)
        assert r.status_code < 500, (url, r.status_code, r.text[:300])


@pytest.mark.parametrize("item", [i for i in RUN_COLUMNS if i[1] in ("started_at", "status", "device_serial")],
                         ids=lambda i: i[1])
def test_the_api_names_a_damaged_run_column(tmp_path, item):
    path = tmp_path / "store.sqlite"
    _good_store(path)
    _damage(path, [item])
    runs = TestClient(create_app(WebSettings(store=str(path)))).get("/api/v1/runs").json()["runs"]
    damaged = {r["id"]: r["damage"] for r in runs if r["damage"]}
    assert list(damaged) == [2], runs  # _damage writes into run 2 only
    assert [d["column"] for d in damaged[2]] == [item[1]] and damaged[2][0]["table"] == "runs"
    assert next(r for r in runs if r["id"] == 2)[item[1]] is None


def test_serve_on_a_store_that_is_not_there_is_one_line(tmp_path):
    from click.testing import CliRunner

    from accelcal_station.cli import cli

    r = CliRunner().invoke(cli, ["serve", "--db", str(tmp_path / "none.sqlite"), "--port", "8799"])
    assert r.exit_code == 2 and r.output.strip().count("\n") == 0, r.output
    assert "none.sqlite" in r.output and "no results store" in r.output
    assert not (tmp_path / "none.sqlite").exists()


# -- issue 34: a store the server cannot read is one 503 naming the damage; never a write
PAGES = ("/", "/fragment/line", "/lot", "/lot?lot=L", "/board?serial=SN1", "/api/v1/runs", "/api/v1/runs/2",
         "/api/v1/yield", "/api/v1/events/head")
UNREADABLE = {
    "runs_dropped": (["PRAGMA foreign_keys = OFF", "DROP TABLE runs"], "no such table: runs"),
    "column_renamed": (["ALTER TABLE runs RENAME COLUMN operator TO op"], "no such column"),
    "poses_dropped": (["PRAGMA foreign_keys = OFF", "DROP TABLE poses"], "no such table: poses"),
}
# pages that read what is gone (the lot page reads its runs' figures and calibrations in SQL, not the
# operator column or the poses: it still answers those two)
NEEDS = {"runs_dropped": ("/", "/api/v1/runs", "/api/v1/yield", "/lot?lot=L"),
         "column_renamed": ("/", "/api/v1/runs", "/api/v1/yield", "/board?serial=SN1"),
         "poses_dropped": ("/api/v1/runs/2", "/board?serial=SN1")}


def _client(path):
    return TestClient(create_app(WebSettings(store=str(path))), raise_server_exceptions=False)


@pytest.mark.parametrize("case", sorted(UNREADABLE))
def test_a_store_it_cannot_read_is_503_naming_the_damage(tmp_path, case):
    import sqlite3

    path = tmp_path / "store.sqlite"
    _good_store(path)
    statements, named = UNREADABLE[case]
    with sqlite3.connect(path) as c:
        for s in statements:
            c.execute(s)
    client = _client(path)
    codes = {}
    for url in PAGES:
        r = client.get(url)
        codes[url] = r.status_code
        assert r.status_code != 500 and "Traceback" not in r.text, (url, r.text[:300])
        if r.status_code == 503:
            assert r.json()["code"] == "store_unreadable" and named in r.json()["message"], (url, r.text)
    assert all(codes[u] == 503 for u in NEEDS[case]), codes
    html_url = next(u for u in NEEDS[case] if not u.startswith("/api"))
    page = client.get(html_url, headers={"accept": "text/html"})  # a browser gets a page, not JSON
    assert page.status_code == 503 and page.headers["content-type"].startswith("text/html") and named in page.text


@pytest.mark.parametrize("statements", [
    ["UPDATE runs SET operator = CAST(x'6f70ff32' AS TEXT) WHERE id = 2"],
    ["UPDATE runs SET device_serial = CAST(x'ff' AS TEXT) WHERE id = 2"],
    ["PRAGMA foreign_keys = OFF", "UPDATE runs SET id = -5 WHERE id = 3",
     "UPDATE poses SET run_id = -5 WHERE run_id = 3", "UPDATE events SET run_id = -5 WHERE run_id = 3"],
], ids=["bad_operator_byte", "bad_serial_byte", "negative_id"])
def test_bad_text_and_negative_ids_are_served(tmp_path, statements):
    import sqlite3

    path = tmp_path / "store.sqlite"
    _good_store(path)
    with sqlite3.connect(path) as c:
        for s in statements:
            c.execute(s)
    client = _client(path)
    for url in PAGES:
        r = client.get(url)
        assert r.status_code < 500, (url, r.status_code, r.text[:300])
    runs = client.get("/api/v1/runs").json()["runs"]
    assert len(runs) == 3
    if "CAST" in statements[0]:
        bad = next(r for r in runs if r["id"] == 2)
        assert bad["damage"] and "not UTF-8" in bad["damage"][0]["problem"], bad
    else:
        assert sorted(r["id"] for r in runs) == [-5, 1, 2]


@pytest.mark.parametrize("seed", range(30))
def test_bit_flips_never_give_a_500(tmp_path, seed):
    """30 seeded copies of a store with 8 flipped bits each (as tests/test_store_damage.py flips them)."""
    import hashlib

    from test_store_damage import _flipped

    good = tmp_path / "good.sqlite"
    _good_store(good)
    path = _flipped(good, tmp_path, seed)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    client = _client(path)
    for url in PAGES:
        r = client.get(url)
        assert r.status_code != 500, (seed, url, r.text[:300])
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before


def test_serve_reads_a_schema_2_store_without_migrating_it(tmp_path):
    """tests/data/legacy_store_v2.sqlite is a schema-2 store: every page is one 503 naming the command
    that upgrades it, and the file's hash never changes (opened mode=ro, no Alembic)."""
    import hashlib
    import shutil
    from pathlib import Path

    from click.testing import CliRunner

    from accelcal_station.cli import cli

    path = tmp_path / "v2.sqlite"
    shutil.copy(Path(__file__).parent / "data" / "legacy_store_v2.sqlite", path)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    client = _client(path)
    for url in PAGES:
        r = client.get(url)
        assert r.status_code == 503 and "accelcal report migrate --db" in r.json()["message"], (url, r.text)
    r = CliRunner().invoke(cli, ["serve", "--db", str(path), "--port", "8798"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "schema version 2" in r.output, r.output
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v2.sqlite"]  # no journal left either
    hint = r.output.split("`")[1].split()  # the hint works: the command named upgrades the store
    assert CliRunner().invoke(cli, hint[1:]).exit_code == 0
    assert hashlib.sha256(path.read_bytes()).hexdigest() != before
    assert _client(path).get("/api/v1/runs").status_code == 200


def test_serve_on_postgresql_reads_in_read_only_sessions(pg_server):
    """The web server's PostgreSQL session is read-only: a write through its connection is refused by
    the server itself, and the pages answer."""
    import sqlalchemy

    from accelcal_station.web.settings import open_store

    url = pg_server.new_database()
    _good_store(url)
    settings = WebSettings(store=url)
    with open_store(settings) as st, pytest.raises(sqlalchemy.exc.DBAPIError, match="read-only"):
        st._db.conn.exec_driver_sql("UPDATE runs SET lot = 'x'")
    client = _client(url)
    assert client.get("/api/v1/runs").status_code == 200 and client.get("/").status_code == 200

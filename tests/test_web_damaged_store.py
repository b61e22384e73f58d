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

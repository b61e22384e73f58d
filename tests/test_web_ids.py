"""Issue 53: every 64-bit id a store holds is served, over real HTTP (uvicorn on 127.0.0.1).

A store whose runs have ids -5, 1 and 2^63-1 (SQLite's largest rowid; PostgreSQL's BIGINT
maximum): the events head, the feed, the stream, the run pages (both orders, by cursor) and
one run by id all answer, and each endpoint given hostile ids (the int64 bounds, one past them,
20-digit numbers, hex, exponents) answers 2xx or a JSON {code, message} 4xx, never a 5xx."""
from __future__ import annotations

import http.client
import json
import sqlite3
from urllib.parse import urlsplit

import pytest
from test_store_damage import _good_store
from webtools import live_server

pytest.importorskip("fastapi")
httpx = pytest.importorskip("httpx")

ID_MIN, ID_MAX = -(2**63), 2**63 - 1
IDS = (-5, 1, ID_MAX)  # the runs of the store below, in id order


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    path = tmp_path_factory.mktemp("ids") / "store.sqlite"
    _good_store(path)  # runs 1, 2, 3
    with sqlite3.connect(path) as c:
        c.execute("PRAGMA foreign_keys = OFF")
        for old, new in ((2, -5), (3, ID_MAX)):
            for table, col in (("runs", "id"), ("poses", "run_id"), ("events", "run_id")):
                c.execute(f"UPDATE {table} SET {col} = ? WHERE {col} = ?", (new, old))
    with live_server(str(path)) as url:
        yield url


def _get(base: str, path: str, params: dict | None = None) -> httpx.Response:
    return httpx.get(base + path, params=params, timeout=30)


def test_the_events_head_and_feed_serve_the_largest_id(base):
    r = _get(base, "/api/v1/events/head")
    assert r.status_code == 200 and r.json() == {"next": str(ID_MAX + 1)}  # past every id: nothing to come
    page = _get(base, "/api/v1/events").json()  # the feed starts at run 1
    assert [e["run"]["id"] for e in page["events"]] == [1, ID_MAX] and page["next"] == str(ID_MAX + 1)
    again = _get(base, "/api/v1/events", {"after": page["next"]})
    assert again.status_code == 200 and again.json() == {"events": [], "next": str(ID_MAX + 1)}
    low = _get(base, "/api/v1/events", {"after": str(ID_MIN)}).json()  # a hand-made negative id, reached
    assert [e["run"]["id"] for e in low["events"]] == list(IDS)


def test_the_stream_delivers_the_largest_id_and_resumes_past_it(base):
    u = urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=20)
    conn.request("GET", "/api/v1/events/stream", headers={"Last-Event-ID": str(ID_MIN)})
    resp = conn.getresponse()
    assert resp.status == 200
    got: list[tuple[str, int]] = []
    last = ""
    while len(got) < 3:
        line = resp.readline().decode().rstrip("\n")
        if line.startswith("id: "):
            last = line[4:]
        elif line.startswith("data: "):
            got.append((last, json.loads(line[6:])["id"]))
    conn.close()
    assert [rid for _, rid in got] == list(IDS) and got[-1][0] == str(ID_MAX + 1)


def test_run_pages_and_one_run_take_every_int64_id(base):
    for order, want in (("asc", list(IDS)), ("desc", list(IDS)[::-1])):
        seen, cursor = [], None
        for _ in range(5):
            params = {"order": order, "limit": 1, **({"cursor": cursor} if cursor else {})}
            body = _get(base, "/api/v1/runs", params).json()
            seen += [x["id"] for x in body["runs"]]
            cursor = body["next_cursor"]
            if cursor is None:
                break
        assert seen == want, order
    for rid in IDS:
        r = _get(base, f"/api/v1/runs/{rid}")
        assert r.status_code == 200 and r.json()["id"] == rid and len(r.json()["poses"]) == 6
    assert _get(base, f"/api/v1/runs/{ID_MIN}").status_code == 404  # in range, no such run


HOSTILE = [str(ID_MIN), str(ID_MIN - 1), "-5", "0", str(ID_MAX), str(ID_MAX + 1), "9" * 20, "-" + "9" * 30, "0x10",
           "1e3", " 7", "", "1.5"]


def _answers(r: httpx.Response, what: str) -> None:
    assert r.status_code < 500, (what, r.status_code, r.text[:200])
    if r.status_code >= 400:
        body = r.json()
        assert set(body) == {"code", "message"} and "\n" not in body["message"], (what, body)


@pytest.mark.parametrize("value", HOSTILE)
def test_no_endpoint_gives_a_5xx_for_a_hostile_id(base, value):
    _answers(_get(base, f"/api/v1/runs/{value}"), f"/runs/{value}")
    _answers(_get(base, "/api/v1/events", {"after": value}), f"events after={value}")
    _answers(_get(base, "/api/v1/events", {"after": f"{value}:{value}"}), f"events after={value}:{value}")
    for cur in (f"a{value}", f"d{value}"):  # a page cursor: its order and an id
        _answers(_get(base, "/api/v1/runs", {"cursor": cur}), f"runs cursor {cur}")
    _answers(_get(base, "/api/v1/runs", {"serial": value, "since": value}), f"runs since={value}")
    _answers(_get(base, "/api/v1/yield"), "yield")
    _answers(_get(base, "/api/v1/events/head"), "head")
    u = urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=20)
    conn.request("GET", "/api/v1/events/stream", headers={"Last-Event-ID": value or "1"})
    resp = conn.getresponse()
    assert resp.status < 500, (value, resp.status)
    if resp.status == 200:
        assert resp.readline() == b"retry: 2000\n"
    conn.close()
    for page in ("/", "/lot?lot=L", "/board?serial=SN0", f"/board?serial={value}"):
        assert _get(base, page).status_code == 200, page

"""Issue 37: the line page and the MES API at line scale.

Batch verdicts and the limits each run was judged by reach the store, `report list` and the
line page's yield; /api/v1/runs pages through 100,000 runs by cursor (newest first and
oldest first) giving each exactly once; a sweep of hostile parameters never gets a 5xx and
every error is {code, message} as the OpenAPI says; the lot and line pages over 100,000 runs
agree with counts taken by plain SQL; a lot page waiting for its turn never holds up the line
page; `accelcal serve` beyond localhost needs a read token or --public.  Figures for speed are
in benchmarks/serve_line_page.py (no wall-clock limits here)."""
from __future__ import annotations

import http.client
import json
import re
import sqlite3
import threading
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pytest
from click.testing import CliRunner
from webtools import bulk_store, live_server

pytest.importorskip("fastapi")
httpx = pytest.importorskip("httpx")
from fastapi.testclient import TestClient  # noqa: E402

from accelcal_station.cli import cli  # noqa: E402
from accelcal_station.data.posetable import write_pose_table  # noqa: E402
from accelcal_station.fixtures.designs import get_design  # noqa: E402
from accelcal_station.session import PoseRecord, Session  # noqa: E402
from accelcal_station.web.app import create_app  # noqa: E402
from accelcal_station.web.settings import WebSettings  # noqa: E402

N_BIG = 100_000
INT64 = 2**63 - 1


@pytest.fixture(scope="module")
def big(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("big") / "line.sqlite"
    bulk_store(path, N_BIG)
    return path


def _sql(path: Path, q: str, *args) -> list[tuple]:
    with sqlite3.connect(path) as c:
        return c.execute(q, args).fetchall()


# -- 1. batch verdicts and limits in the store ------------------------------------------------
DESIGN = get_design("an4399-8")


def _board(seed: int, design=DESIGN) -> tuple[Session, float]:
    """A synthetic board in counts (readings g = W^-1 (ref - V) + noise) and its true largest |V| in mg."""
    rng = np.random.default_rng(seed)
    W = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    V = rng.normal(0, 0.02, 3)
    poses = [PoseRecord(p.name, (np.linalg.solve(W, p.reference_g - V) + rng.normal(0, 2e-4, 3)) * 4096.0,
                        np.full(3, 3.0), 400, p.reference_g, p.pitch_deg, p.roll_deg) for p in design]
    return Session(poses, "counts", 4096.0, device="mma8451", metadata={"serial": f"SN{seed:04d}"}), \
        float(np.abs(V).max() * 1e3)


def test_batch_to_store_records_each_verdict_with_its_limits_and_the_line_page_counts_them(tmp_path):
    truth = {}
    for seed in range(12):
        s, v_mg = _board(seed)
        if abs(v_mg - 25.0) > 1.0:  # clear of the limit by far more than the fit's error (~0.01 mg)
            write_pose_table(s, tmp_path / f"b{seed}.csv")
            truth[f"SN{seed:04d}"] = "FAIL" if v_mg > 25.0 else "PASS"
    assert set(truth.values()) == {"PASS", "FAIL"}
    cfg = tmp_path / "st1.yaml"
    cfg.write_text("acceptance:\n  offset_max_mg: 25\n  residual_rms_mg: 2\n")
    db = tmp_path / "runs.sqlite"
    r = CliRunner().invoke(cli, ["batch", *sorted(map(str, tmp_path.glob("b*.csv"))), "--config", str(cfg),
                                 "--to-store", str(db)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["report", "list", "--db", str(db), "--json"])
    runs = json.loads(r.stdout)
    assert {x["device_serial"]: x["verdict"] for x in runs} == truth
    for x in runs:  # the limits it was judged by: the config's, and the default every run gets
        assert x["limits"] == {"offset_max_mg": 25.0, "residual_rms_mg": 2.0, "crossval_rms_mg": 10.0}
        assert (x["reason_codes"] == ["offset_max_mg"]) == (x["verdict"] == "FAIL")
    n_pass = sum(v == "PASS" for v in truth.values())
    page = TestClient(create_app(WebSettings(str(db)))).get("/")
    card = re.search(r'data-station="accelcal-batch">(.*?)</article>', page.text, re.S).group(1)
    assert f"{100 * n_pass / len(truth):.1f} %" in card and f"<dd>{len(truth)}</dd>" in card


# -- 2. the MES API -----------------------------------------------------------------------------
def _all_pages(client: TestClient, order: str, limit: int, **filters) -> tuple[list[int], int]:
    ids: list[int] = []
    cursor, pages = None, 0
    while True:
        params = {"order": order, "limit": limit, **filters, **({"cursor": cursor} if cursor else {})}
        r = client.get("/api/v1/runs", params=params)
        assert r.status_code == 200, r.text
        body = r.json()
        ids += [x["id"] for x in body["runs"]]
        pages += 1
        cursor = body["next_cursor"]
        if cursor is None:
            return ids, pages


def test_runs_page_through_100000_runs_newest_and_oldest_first_each_exactly_once(big):
    client = TestClient(create_app(WebSettings(str(big))))
    every = [i for (i,) in _sql(big, "SELECT id FROM runs ORDER BY id")]
    assert len(every) == N_BIG
    newest, pages = _all_pages(client, "desc", 1000)
    assert newest == every[::-1] and pages == 100
    oldest, _ = _all_pages(client, "asc", 1000)
    assert oldest == every
    first = client.get("/api/v1/runs", params={"limit": 3, "total": "true"}).json()
    assert [x["id"] for x in first["runs"]] == every[-3:][::-1] and first["total"] == N_BIG
    assert client.get("/api/v1/runs", params={"limit": 3}).json()["total"] is None  # only on request
    # filters, with an odd page size, against plain SQL
    want = [i for (i,) in _sql(big, "SELECT id FROM runs WHERE station_id = 'st3' AND verdict = 'FAIL'"
                                    " AND lot = 'L7' AND started_at >= ? ORDER BY id", 1.7e9 - 20 * 86400)]
    got, _ = _all_pages(client, "asc", 7, station="st3", verdict="FAIL", lot="L7", since=str(1.7e9 - 20 * 86400))
    assert got == want and len(want) > 7
    r = client.get("/api/v1/runs", params={"serial": "SN0004242", "total": "true"}).json()
    assert [x["device_serial"] for x in r["runs"]] == ["SN0004242"] and r["total"] == 1
    assert r["runs"][0]["limits"] == {"offset_max_mg": 60.0} and r["runs"][0]["limits_source"] == "stored"


def test_a_cursor_carries_its_order_and_only_cursors_match_its_pattern(big):
    """Issue 53: a page cursor is its order and the last id delivered; it continues that order (the
    order parameter cannot turn it round), and what does not match its declared pattern is 422."""
    client = TestClient(create_app(WebSettings(str(big))))
    first = client.get("/api/v1/runs", params={"limit": 2}).json()
    ids = [r["id"] for r in first["runs"]]
    assert ids == [N_BIG, N_BIG - 1] and first["next_cursor"] == f"d{N_BIG - 1}"
    r = client.get("/api/v1/runs", params={"cursor": first["next_cursor"], "order": "asc", "limit": 2}).json()
    assert r["order"] == "desc" and [x["id"] for x in r["runs"]] == [N_BIG - 2, N_BIG - 3]
    past = "a" + "9" * 19  # after every int64 id: an empty last page
    assert client.get("/api/v1/runs", params={"cursor": past}).json() == {"runs": [], "order": "asc",
                                                                          "next_cursor": None, "total": None}
    for bad in ("not-a-cursor", "", "=" * 10, "é", "d01", "x5", "a" + "9" * 20):
        r = client.get("/api/v1/runs", params={"cursor": bad})
        assert r.status_code == 422 and r.json()["code"] == "invalid_request", bad


EXTREMES = ["0", "-1", str(INT64), str(INT64 + 1), str(-INT64 - 2), str(2**64), "1e308", "1e309", "-1e309",
            "nan", "inf", "-inf", "1.5", "", " ", "x", "9" * 5000, "\x00", "%00", "１２", "true", "null",
            "2026-02-30", "0001-01-01T00:00:00-23:59", "9999-12-31T23:59:59", "x" * 200_001]
ENDPOINTS = {"/api/v1/runs": ["since", "until", "station", "serial", "verdict", "lot", "status", "order", "cursor",
                              "limit", "total"],
             "/api/v1/events": ["after", "wait_s", "limit"], "/api/v1/events/head": [], "/api/v1/yield": [],
             "/api/v1/events/stream": ["after"], "/": ["day", "shift"], "/fragment/line": ["day", "shift"],
             "/board": ["serial"], "/lot": ["lot", "cursor", "per"],
             "/reason": ["code", "day", "shift", "station", "cursor", "per"], "/station": ["station", "day", "shift"]}


def _status(base: str, path: str, params: dict | None = None, headers: dict | None = None) -> tuple[int, str, bytes]:
    """GET through http.client (no client-side limit on a URL's length): status, content type, body
    (not read for an event stream, which does not end)."""
    from urllib.parse import urlencode, urlsplit

    u = urlsplit(base)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
    try:
        conn.request("GET", path + ("?" + urlencode(params) if params else ""), headers=headers or {})
        r = conn.getresponse()
        kind = r.getheader("content-type", "")
        return r.status, kind, b"" if kind.startswith("text/event-stream") else r.read()
    finally:
        conn.close()


def _check(status: int, kind: str, body: bytes, what: str, api: bool) -> None:
    assert status < 500, what
    if status >= 400 and api:
        err = json.loads(body)
        assert set(err) == {"code", "message"} and err["message"], what


def test_no_hostile_parameter_gets_a_5xx_and_every_api_error_is_code_and_message(tmp_path):
    db = tmp_path / "small.sqlite"
    bulk_store(db, 300, lot_size=100, t_end=1.7e9)
    with live_server(str(db)) as base:
        checked = 0
        for path, names in ENDPOINTS.items():
            for name in names:
                for v in EXTREMES:
                    _check(*_status(base, path, {name: v} if path != "/reason" or name == "code"
                                    else {"code": "x", name: v}), f"{path}?{name}={v[:30]!r}", "/api/" in path)
                    checked += 1
        for v in EXTREMES:  # the path parameter and the stream's resume header
            _check(*_status(base, f"/api/v1/runs/{quote(v, safe='')}"), f"runs/{v[:30]!r}", True)
            if v.isascii() and v.isprintable():
                _check(*_status(base, "/api/v1/events/stream", headers={"Last-Event-ID": v}), f"Last-Event-ID {v[:30]}",
                       True)
            checked += 2
        assert checked == len(EXTREMES) * (sum(map(len, ENDPOINTS.values())) + 2)
        # the cases, each a 4xx JSON answer
        for path, status in ((f"/api/v1/runs/{INT64 + 1}", 422), (f"/api/v1/runs/{INT64}", 404),
                             ("/api/v1/events?after=x", 422), ("/api/v1/events?after=" + "1" * 200_001, 422),
                             ("/api/v1/runs?limit=1001", 422), ("/api/v1/runs?limit=0", 422)):
            code, _, body = _status(base, path)
            assert code == status and set(json.loads(body)) == {"code", "message"}, path


def test_openapi_documents_one_error_shape_and_a_model_for_every_body(tmp_path):
    from openapi_spec_validator import validate

    db = tmp_path / "s.sqlite"
    bulk_store(db, 5, lot_size=5)
    spec = TestClient(create_app(WebSettings(str(db)))).get("/openapi.json").json()
    validate(spec)
    schemas = spec["components"]["schemas"]
    assert "HTTPValidationError" not in schemas and set(schemas["ErrorBody"]["properties"]) == {"code", "message"}
    for path, ops in spec["paths"].items():
        op = ops["get"]
        for status in ("400", "401", "404", "422", "503"):
            ref = op["responses"][status]["content"]["application/json"]["schema"]["$ref"]
            assert ref.endswith("/ErrorBody"), (path, status)
        ok = op["responses"]["200"]["content"]
        if "application/json" in ok:
            assert "$ref" in ok["application/json"]["schema"], path  # a declared model, not a free object
    detail = schemas["RunDetail"]["properties"]
    assert {"poses", "events", "calibration", "limits", "reasons"} <= set(detail)
    assert spec["paths"]["/api/v1/runs"]["get"]["responses"]["200"]["content"]["application/json"]["schema"][
        "$ref"].endswith("/RunPage")
    ids = [p for p in spec["paths"]["/api/v1/runs/{run_id}"]["get"]["parameters"] if p["name"] == "run_id"]
    assert ids[0]["schema"]["maximum"] == INT64


# -- 3. bounded work ----------------------------------------------------------------------------
def test_the_lot_and_line_pages_of_100000_runs_agree_with_plain_sql(big):
    client = TestClient(create_app(WebSettings(str(big))))
    lot = client.get("/lot", params={"lot": "L3"}).text
    (n, n_pass, n_fail), = _sql(big, "SELECT count(*), sum(verdict = 'PASS'), sum(verdict = 'FAIL') FROM runs"
                                     " WHERE lot = 'L3'")
    assert n == 5000
    assert f'<div class="big">{n}</div>' in lot and f"PASS {n_pass} · FAIL {n_fail}" in lot
    assert "newest 200 of 5000 runs drawn" in lot  # the charts draw a bounded number of runs
    # V in mg in the table, as on the charts: the V0 row's mean against the calibrations' own mean
    v0 = [json.loads(c)["V"][0] * 1e3 for (c,) in _sql(big, "SELECT calibration FROM runs WHERE lot = 'L3'")]
    row = re.search(r"<tr><td>V0</td><td>mg</td><td class=\"n\">([-0-9.e]+)</td>", lot)
    assert row and float(row.group(1)) == pytest.approx(np.mean(v0), rel=1e-4, abs=1e-3)
    # the line page: each station's yield over the day before the newest run, by SQL
    line = client.get("/").text
    (t_new,), = _sql(big, "SELECT max(started_at) FROM runs")
    for st, k, p in _sql(big, "SELECT station_id, count(*), sum(verdict = 'PASS') FROM runs WHERE started_at >= ?"
                              " GROUP BY station_id", t_new - 86400):
        card = re.search(rf'data-station="{st}">(.*?)</article>', line, re.S).group(1)
        assert f"<dd>{k}</dd>" in card and f"{100 * p / k:.1f} %" in card


def test_lot_pages_waiting_for_their_turn_do_not_hold_up_the_line_page(big):
    """Three lot pages at once on a server with one lane for heavy pages: while they are served
    one at a time, the line page and the API are answered; the lot pages all complete."""
    with live_server(str(big)) as base:
        done: list[str] = []
        def lot_page(lot: str) -> None:
            done.append(f"{lot} {httpx.get(base + '/lot', params={'lot': lot}, timeout=120).status_code}")

        lots = [threading.Thread(target=lot_page, args=(lot,)) for lot in ("L1", "L2", "L3")]
        for t in lots:
            t.start()
        line = httpx.get(base + "/", timeout=120)
        api = httpx.get(base + "/api/v1/runs", params={"limit": 5}, timeout=120)
        during = len(done)
        for t in lots:
            t.join()
    assert line.status_code == 200 and api.status_code == 200 and "Yield" in line.text
    assert during < 3  # answered while lot pages were still waiting or in work
    assert sorted(done) == ["L1 200", "L2 200", "L3 200"]


# -- 5. network exposure ------------------------------------------------------------------------
def test_serve_beyond_localhost_refuses_without_a_read_token_or_public(tmp_path):
    from accelcal_station.cli.serve import exposure

    db = tmp_path / "s.sqlite"
    bulk_store(db, 3, lot_size=3)
    for host in ("0.0.0.0", "::", "192.168.1.20", "line-server"):
        r = CliRunner().invoke(cli, ["serve", "--db", str(db), "--host", host])
        assert r.exit_code == 2 and r.stderr.count("\n") == 1 and "web.read_token" in r.stderr \
            and "--public" in r.stderr, r.output
    # what each allowed start says (the function the command runs before it listens)
    assert exposure("127.0.0.1", None, False) == "this machine only" == exposure("localhost", None, False)
    assert exposure("::1", None, False) == "this machine only"
    assert "PUBLIC" in exposure("0.0.0.0", None, True)
    assert "read_token" in exposure("0.0.0.0", "t" * 20, False)
    cfg = tmp_path / "c.yaml"
    cfg.write_text((Path(__file__).resolve().parents[1] / "configs" / "sim.yaml").read_text()
                   + "\nweb:\n  read_token: short\n")
    r = CliRunner().invoke(cli, ["serve", "--config", str(cfg), "--db", str(db)])
    assert r.exit_code == 2 and "web.read_token: allowed: a string of 16-200" in r.stderr


def test_a_read_token_is_needed_for_every_request(tmp_path):
    db = tmp_path / "s.sqlite"
    bulk_store(db, 3, lot_size=3)
    token = "line-7-read-0123456789"
    with live_server(str(db), read_token=token) as base:
        for path in ("/", "/api/v1/runs", "/api/v1/runs/1", "/openapi.json", "/static/app.css", "/lot?lot=L0"):
            r = httpx.get(base + path)
            assert r.status_code == 401 and r.json()["code"] == "unauthorized" and "Basic" in r.headers[
                "www-authenticate"], path
            assert httpx.get(base + path, headers={"Authorization": "Bearer wrong-token-0123456"}).status_code == 401
            assert httpx.get(base + path, headers={"Authorization": f"Bearer {token}"}).status_code == 200, path
            assert httpx.get(base + path, auth=("engineer", token)).status_code == 200, path  # a browser's Basic

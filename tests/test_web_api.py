"""Issue 23, the MES JSON API of `accelcal serve` against a live server: the events feed's
exactly-once delivery (a 200-run burst from 4 concurrent writers, with a resume halfway),
`/api/v1/runs?since=`, the OpenAPI schema, JSON errors, and the operator API's token."""
from __future__ import annotations

import http.client
import json
import threading
import time
from urllib.parse import urlsplit

import numpy as np
import pytest
from webtools import live_server

httpx = pytest.importorskip("httpx")

from accelcal_station.fixtures.operator_ui import PosePrompt  # noqa: E402
from accelcal_station.session import PoseRecord, Session  # noqa: E402
from accelcal_station.store.runs import Store  # noqa: E402
from accelcal_station.web.feed import Cursor, advance  # noqa: E402


def _session(serial: str) -> Session:
    poses = [PoseRecord(f"p{i}", np.array([0.0, 0.0, 1.0]) + 1e-3 * i, None, 10, np.array([0.0, 0.0, 1.0]))
             for i in range(3)]
    return Session(poses, units="g", device=serial)


def _writer(url: str, station: str, n: int, lot: str) -> None:
    """One station: n runs started, then finished after a random short while (out of id order)."""
    rng = np.random.default_rng(abs(hash(station)) % 2**32)
    with Store(url) as st:
        for i in range(n):
            rid = st.start_run(device_serial=f"{station}-{i}", station_id=station, lot=lot)
            time.sleep(float(rng.uniform(0, 0.004)))
            verdict = "PASS" if rng.uniform() < 0.9 else "FAIL"
            st.finish_run(rid, session=_session(f"{station}-{i}"), calibration=None, verdict=verdict,
                          fit_summary={"measured": {"residual_rms_mg": float(rng.uniform(0.01, 0.1))}})


def _drain_sse(base: str, want: int, got: list[tuple[str, int]], after: str = "", stop_at: int | None = None,
               timeout_s: float = 60.0) -> None:
    """Read run events from the stream into ``got`` as (event id, run id) until ``want`` (or ``stop_at``)."""
    t0 = time.monotonic()
    headers = {"Last-Event-ID": after} if after else {}
    with httpx.stream("GET", f"{base}/api/v1/events/stream", headers=headers, timeout=30) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        ev_id, data = None, None
        for line in r.iter_lines():
            if line.startswith("id: "):
                ev_id = line[4:]
            elif line.startswith("data: "):
                data = json.loads(line[6:])
            elif line == "" and data is not None:
                got.append((ev_id, data["id"]))
                ev_id, data = None, None
                if len(got) >= (stop_at or want):
                    return
            assert time.monotonic() - t0 < timeout_s, f"only {len(got)} events of {want}"


def test_events_and_runs_since_deliver_a_200_run_burst_from_4_writers_exactly_once(store_url):
    with Store(store_url) as st:  # the schema, before the server reads it
        st.start_run(device_serial="before", station_id="s0")  # one run left running the whole time
    before = time.time()
    with live_server(store_url, poll_s=0.05) as base:
        stream: list[tuple[str, int]] = []
        first: list[tuple[str, int]] = []
        reader = threading.Thread(target=_drain_sse, args=(base, 200, first), kwargs={"stop_at": 80})
        reader.start()
        writers = [threading.Thread(target=_writer, args=(store_url, f"st{k}", 50, "burst")) for k in range(4)]
        for w in writers:
            w.start()
        # a long-polling client at the same time, following `next`
        polled: list[int] = []
        cursor = ""
        t0 = time.monotonic()
        while len(polled) < 200 and time.monotonic() - t0 < 60:
            page = httpx.get(f"{base}/api/v1/events", params={"after": cursor, "wait_s": 1, "limit": 37}).json()
            polled += [e["run"]["id"] for e in page["events"]]
            cursor = page["next"]
        for w in writers:
            w.join()
        reader.join()
        # the stream client stopped after 80 runs and comes back with its last event id
        _drain_sse(base, 200 - len(first), stream, after=first[-1][0])
        runs = httpx.get(f"{base}/api/v1/runs", params={"since": before, "lot": "burst", "limit": 1000}).json()["runs"]
    with Store(store_url) as st:
        finished = {r["id"] for r in st.list_runs(lot="burst")}
    assert len(finished) == 200
    resumed = [rid for _, rid in first] + [rid for _, rid in stream]
    for seen in (polled, resumed, [r["id"] for r in runs]):
        assert len(seen) == 200 and set(seen) == finished  # every run, none twice
    assert all(r["status"] == "complete" for r in runs)


def test_the_feed_cursor_waits_for_a_running_run_and_a_young_gap():
    """Unit of the cursor rule: runs 1-5, run 2 still running, id 4 missing (not yet visible)."""
    now = 1000.0
    rows = [{"id": 1, "status": "complete", "started_at": now - 5}, {"id": 2, "status": "running", "started_at": now},
            {"id": 3, "status": "complete", "started_at": now}, {"id": 5, "status": "complete", "started_at": now}]
    steps = advance(Cursor(), rows, now)
    assert [s.run_id for s in steps] == [1, 3, 5]
    last = steps[-1].cursor
    assert last.low == 2 and last.done == {3, 5}
    # run 2 finishes and run 4 becomes visible: both delivered, once, and the cursor moves past all
    rows = [{"id": 2, "status": "complete", "started_at": now}, {"id": 3, "status": "complete", "started_at": now},
            {"id": 4, "status": "complete", "started_at": now}, {"id": 5, "status": "complete", "started_at": now}]
    again = advance(Cursor.parse(last.text()), rows, now)
    assert [s.run_id for s in again] == [2, 4] and again[-1].cursor == Cursor(6)
    # a gap older than a minute is a rolled-back insert: the cursor passes it
    old = [{"id": 1, "status": "complete", "started_at": now - 600}, {"id": 3, "status": "complete",
                                                                       "started_at": now - 600}]
    assert advance(Cursor(), old, now)[-1].cursor == Cursor(4)


def test_openapi_schema_is_served_and_valid_and_errors_are_json(tmp_path):
    from openapi_spec_validator import validate

    db = tmp_path / "runs.sqlite"
    Store(db).close()
    with live_server(str(db)) as base:
        spec = httpx.get(f"{base}/openapi.json").json()
        validate(spec)
        assert {"/api/v1/runs", "/api/v1/runs/{run_id}", "/api/v1/yield", "/api/v1/events",
                "/api/v1/events/stream"} <= set(spec["paths"])
        for path, status, code in (("/api/v1/runs/999", 404, "not_found"),
                                   ("/api/v1/events?after=nonsense", 422, "invalid_request"),
                                   ("/api/v1/runs?since=yesterday", 422, "invalid_request"),
                                   ("/api/v1/runs?since=2026-02-30", 422, "invalid_request"),
                                   ("/api/v1/runs?verdict=MAYBE", 422, "invalid_request"),
                                   ("/static/..%2f..%2fpyproject.toml", 404, "not_found"),
                                   ("/static/app.py", 404, "not_found")):
            r = httpx.get(base + path)
            assert r.status_code == status and r.json()["code"] == code and r.json()["message"], (path, r.text)
        # read-only: no method writes
        assert httpx.post(f"{base}/api/v1/runs").status_code == 405
        trace = httpx.request("TRACE", f"{base}/api/v1/runs")  # RFC 9110: a 405 names the methods allowed
        assert trace.status_code == 405 and trace.headers["allow"] == "GET" and trace.json()["code"] == "http_error"
        for size, status in ((1_200_000, (400, 422)), (3_000_000, (400,))):  # 3 MB: past the 1 MiB request head
            u = urlsplit(base)
            conn = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
            conn.request("GET", "/api/v1/runs?lot=" + "x" * size)  # http.client: no client-side URL limit
            huge = conn.getresponse()
            body = huge.read()
            conn.close()
            assert huge.status in status and huge.getheader("content-type") == "application/json", body[:200]
            assert json.loads(body)["code"] == "invalid_request"


def test_operator_api_abort_needs_the_configured_token():
    from webtools import free_port

    from accelcal_station.fixtures.base import PoseSpec
    from accelcal_station.web.operator import WebOperator
    from accelcal_station.web.operator_app import create_operator_app
    from accelcal_station.web.server import BackgroundServer

    answers: list[str] = []
    for token in (None, "s3cret-token-0123456789"):
        ui = WebOperator(lambda t: None, "st", 6)
        port = free_port()
        server = BackgroundServer(create_operator_app(ui, token), "127.0.0.1", port)
        server.start()
        base = f"http://127.0.0.1:{port}"
        try:
            pose = PoseSpec("x+1g", -90.0, 0.0)
            asker = threading.Thread(target=lambda ui=ui, p=pose: answers.append(
                _ask_or_abort(ui, PosePrompt(1, p, "x+ down"))))
            asker.start()
            while ui.state["phase"] != "ask":
                time.sleep(0.01)
            r = httpx.post(f"{base}/api/v1/station/abort")
            if token is None:
                assert r.status_code == 403 and r.json()["code"] == "read_only"
                ui.answer("accept")
            else:
                assert httpx.post(f"{base}/api/v1/station/abort").status_code == 401
                bad = httpx.post(f"{base}/api/v1/station/abort", headers={"Authorization": "Bearer wrong"})
                assert bad.status_code == 401
                # a form post from another site cannot answer (not JSON)
                assert httpx.post(f"{base}/operator/answer", data={"answer": "accept"}).status_code in (415, 422)
                ok = httpx.post(f"{base}/api/v1/station/abort", headers={"Authorization": f"Bearer {token}"})
                assert ok.status_code == 200
            asker.join(5)
        finally:
            server.stop()
    assert answers == ["", "a"]


def _ask_or_abort(ui, prompt) -> str:
    return ui.ask(prompt, None)


def test_serve_and_web_token_refusals_are_one_line(tmp_path):
    import yaml
    from click.testing import CliRunner

    from accelcal_station.cli import cli
    from accelcal_station.config.sections import default_config_path

    r = CliRunner().invoke(cli, ["serve"])
    assert r.exit_code == 2 and r.stderr.strip() == "error: --db or --config: name the results store to serve"
    cfg = yaml.safe_load(default_config_path().read_text())
    for token, message in (("short", "web.token: allowed: a string of 16-200"), (None, "web.tokn: unknown key")):
        cfg["web"] = {"token": token} if token else {"tokn": "x" * 20}
        p = tmp_path / "station.yaml"
        p.write_text(yaml.safe_dump(cfg))
        r = CliRunner().invoke(cli, ["serve", "--config", str(p)])
        assert r.exit_code == 2 and message in r.stderr and r.stderr.count("\n") == 1, r.output

"""The heavy pages' worker processes (web/lanes.py; issue 37: a slow page must not slow the line page).

The lot, board and reason pages are computed in a worker process once the application has
started (its lifespan), and give the same bytes as in a thread; the work runs in another
process, which opens SQLite and PostgreSQL read-only; a worker that dies is replaced and its
request answered 503, never hanging; an error from the worker is answered as in a thread;
`accelcal serve` stopped by SIGTERM or SIGINT leaves no process behind.
"""
from __future__ import annotations

import asyncio
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from webtools import bulk_store, free_port

pytest.importorskip("fastapi")
httpx = pytest.importorskip("httpx")
from fastapi.testclient import TestClient  # noqa: E402

from accelcal_station.web import pages  # noqa: E402
from accelcal_station.web.app import create_app  # noqa: E402
from accelcal_station.web.errors import WorkerLost  # noqa: E402
from accelcal_station.web.lanes import HeavyLanes  # noqa: E402
from accelcal_station.web.settings import WebSettings, open_store  # noqa: E402

HEAVY = ("/lot?lot=L1", "/lot", "/board?serial=SN0000007", "/board?serial=NOPE", "/reason?code=offset_max_mg",
         "/reason?code=offset_max_mg&shift=B&day=2023-11-13")
needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process tree from /proc")


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lanes") / "line.sqlite"
    bulk_store(path, 3000, lot_size=1000)
    return path


def children(pid: int) -> dict[int, str]:
    """Every live descendant of ``pid`` with its command line (from /proc)."""
    parent: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except (OSError, ValueError):
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if fields[0] != "Z":  # a zombie has exited already
            parent[int(d.name)] = int(fields[1])
    out, todo = {}, [pid]
    while todo:
        p = todo.pop()
        for c, pp in parent.items():
            if pp == p and c not in out:
                try:
                    out[c] = (Path(f"/proc/{c}/cmdline").read_bytes().replace(b"\0", b" ").decode())
                except OSError:
                    continue
                todo.append(c)
    return out


def workers(pid: int) -> set[int]:
    return {c for c, cmd in children(pid).items() if "spawn_main" in cmd}


def die(*_args: object) -> None:
    """A page whose work kills its worker process (as the out-of-memory killer would)."""
    os._exit(9)


class TwoArgs(Exception):
    def __init__(self, a: int, b: int) -> None:
        super().__init__(f"{a} and {b}")


def refuse() -> None:
    """Raises an exception that pickles but cannot be unpickled by its args."""
    raise TwoArgs(1, 2)


def test_heavy_pages_are_the_same_bytes_from_a_worker_process_as_from_a_thread(store):
    in_thread = TestClient(create_app(WebSettings(str(store))))  # no lifespan: threads, as before
    want = {u: in_thread.get(u) for u in HEAVY}
    assert all(r.status_code == 200 for r in want.values()), {u: r.status_code for u, r in want.items()}
    assert "SN0000007" in want["/board?serial=SN0000007"].text and "L1" in want["/lot?lot=L1"].text
    before = workers(os.getpid())
    with TestClient(create_app(WebSettings(str(store)))) as client:
        got = {u: client.get(u) for u in HEAVY}
        started = workers(os.getpid()) - before
        assert client.get("/").status_code == 200
    assert {u: r.content for u, r in got.items()} == {u: r.content for u, r in want.items()}
    if Path("/proc/self/stat").exists():
        assert len(started) == 1  # heavy_lanes = 1: one worker process
        deadline = time.monotonic() + 10
        while started & workers(os.getpid()) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not started & workers(os.getpid()), "the worker outlived the application's shutdown"


def write_through(settings: WebSettings) -> None:
    """A write through the store a worker opens (refused: the worker's store is read-only)."""
    with open_store(settings) as st:
        st._db.conn.exec_driver_sql("UPDATE runs SET lot = 'x'")


def test_the_worker_reads_sqlite_and_postgresql_read_only_and_the_pages_match(store_url):
    from test_store_damage import _good_store

    _good_store(store_url)
    settings = WebSettings(store_url)
    urls = ("/lot?lot=L", "/lot", "/board?serial=SN1", "/reason?code=x")
    want = {u: TestClient(create_app(settings)).get(u) for u in urls}
    with TestClient(create_app(settings)) as client:
        got = {u: client.get(u) for u in urls}

    async def write() -> None:
        lanes = HeavyLanes(1)
        lanes.start()
        try:
            assert lanes.in_processes
            await lanes.run(write_through, settings)
        finally:
            lanes.close()
    with pytest.raises(Exception, match="(?i)read-?only"):
        asyncio.run(write())
    assert all(r.status_code == 200 for r in got.values()) and "SN1" in got["/board?serial=SN1"].text
    assert {u: r.content for u, r in got.items()} == {u: r.content for u, r in want.items()}
    with open_store(settings) as st:
        assert {r.lot for r in st.runs()} == {"L"}


def test_the_work_runs_in_another_process_and_a_dead_worker_is_replaced():
    async def go() -> None:
        lanes = HeavyLanes(1)
        lanes.start()
        try:
            assert lanes.in_processes
            first = await lanes.run(os.getpid)
            assert first != os.getpid()
            with pytest.raises(WorkerLost, match="load the page again"):  # the worker dies in this request
                await lanes.run(die)
            second = await lanes.run(os.getpid)
            assert second not in (first, os.getpid())
            os.kill(second, signal.SIGKILL)  # dies between requests (killed from outside)
            got: list[int | str] = []
            for _ in range(2):  # the next request may learn of it (503) or find the new worker
                try:
                    got.append(await asyncio.wait_for(lanes.run(os.getpid), 60))
                except WorkerLost:
                    got.append("lost")
            assert isinstance(got[-1], int) and got[-1] not in (first, second, os.getpid()), got
            with pytest.raises(RuntimeError, match="TwoArgs: 1 and 2"):  # answered, the pool unbroken
                await lanes.run(refuse)
            assert await lanes.run(os.getpid) == got[-1]
        finally:
            lanes.close()
        assert not lanes.in_processes and await lanes.run(os.getpid) == os.getpid()  # closed: a thread
    asyncio.run(go())


def test_without_spawn_the_pages_run_in_a_thread(monkeypatch):
    import accelcal_station.web.lanes as lanes_mod

    monkeypatch.setattr(lanes_mod, "_spawn_context", lambda: None)

    async def go() -> int:
        lanes = HeavyLanes(2)
        lanes.start()
        assert not lanes.in_processes
        return await lanes.run(os.getpid)
    assert asyncio.run(go()) == os.getpid()


def test_closing_ends_a_worker_stuck_in_a_page():
    async def go() -> tuple[int, float]:
        lanes = HeavyLanes(1)
        lanes.start()
        pid = await lanes.run(os.getpid)
        stuck = asyncio.ensure_future(lanes.run(time.sleep, 120))
        await asyncio.sleep(0.5)
        t0 = time.monotonic()
        lanes.close(wait_s=0.5)
        stuck.cancel()
        return pid, time.monotonic() - t0
    pid, took = asyncio.run(go())
    assert took < 10 and not _wait_gone({pid}, 5)


def test_a_worker_dying_mid_page_is_a_503_and_the_next_page_is_served(store, monkeypatch):
    with TestClient(create_app(WebSettings(str(store))), raise_server_exceptions=False) as client:
        ok = client.get("/lot?lot=L1")
        monkeypatch.setattr(pages, "lot_page", die)
        html = client.get("/lot?lot=L1", headers={"accept": "text/html"})
        js = client.get("/lot?lot=L1", headers={"accept": "application/json"})
        monkeypatch.undo()
        again = client.get("/lot?lot=L1")
    assert html.status_code == 503 and "worker process stopped" in html.text and "<h1>" in html.text
    assert js.status_code == 503 and js.json()["code"] == "worker_lost"
    assert again.status_code == 200 and again.content == ok.content


def test_an_unreadable_store_is_answered_the_same_from_the_worker(tmp_path):
    path = tmp_path / "s.sqlite"
    bulk_store(path, 30, lot_size=10)
    with sqlite3.connect(path) as c:
        c.execute("ALTER TABLE runs RENAME TO runs_gone")
    in_thread = TestClient(create_app(WebSettings(str(path))), raise_server_exceptions=False)
    with TestClient(create_app(WebSettings(str(path))), raise_server_exceptions=False) as client:
        for url in ("/lot?lot=L1", "/board?serial=SN0000001", "/reason?code=x"):
            want, got = in_thread.get(url), client.get(url)
            assert got.status_code == want.status_code == 503, (url, got.text[:300])
            assert got.content == want.content


def _serve(store: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "serve", "--db", str(store),
                             "--port", str(port)], stderr=subprocess.PIPE, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        try:
            httpx.get(base + "/api/v1/events/head", timeout=2)
            return proc, base
        except httpx.HTTPError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                pytest.fail(f"accelcal serve did not start: {proc.communicate()[1].decode()[-2000:]}")
            time.sleep(0.2)


def _wait_gone(pids: set[int], timeout_s: float = 15) -> set[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        alive = {p for p in pids if Path(f"/proc/{p}").exists() and "Z" not in
                 Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[:1]}
        if not alive:
            return set()
        time.sleep(0.1)
    return alive


@needs_proc
@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_accelcal_serve_computes_lot_pages_in_a_worker_and_leaves_no_process_when_stopped(store, stop):
    proc, base = _serve(store)
    try:
        first = httpx.get(base + "/lot", params={"lot": "L1"}, timeout=60)
        assert first.status_code == 200
        worker = workers(proc.pid)
        assert len(worker) == 1 and proc.pid not in worker
        if stop == signal.SIGTERM:  # kill the worker: the server replaces it and never hangs
            os.kill(worker.pop(), signal.SIGKILL)
            codes = [httpx.get(base + "/lot", params={"lot": "L1"}, timeout=60) for _ in range(2)]
            assert codes[-1].status_code == 200 and codes[-1].content == first.content
            assert all(r.status_code in (200, 503) for r in codes)
            assert all(r.json()["code"] == "worker_lost" for r in codes if r.status_code == 503)
            assert len(workers(proc.pid)) == 1
        tree = set(children(proc.pid))
        assert tree
        if stop == signal.SIGINT:  # Ctrl-C in a terminal: to the whole process group, workers too
            os.killpg(proc.pid, stop)
        else:
            proc.send_signal(stop)
        # uvicorn shuts down in order (the lifespan stops the workers), then raises SIGTERM again;
        # the CLI answers an interrupt with "error: interrupted" and 130
        assert proc.wait(20) in (0, -signal.SIGTERM, 130), proc.communicate()[1].decode()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert not _wait_gone(tree), f"left behind: {tree}"
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err

"""`accelcal serve` at scale: the line and lot pages over a store of 100,000 runs, the line page
while three lot pages load, and the server's memory while the events stream delivers a line's runs.

1. Builds an SQLite store of N runs (default 100,000; 8 stations, 30 days, 7 % FAIL with typed
   reasons, 4 % retests) by bulk insert (the store's schema, created by Store; rows inserted in
   one transaction: the benchmark's set-up, not the station's path), then times the line page's
   server work (the aggregate queries and the Jinja2 render, in process, best and median of 7)
   (the HTTP round trip adds the uvicorn write of about 60 kB).
2. Starts `accelcal serve` in its own process and times over HTTP: the line page alone, a lot
   page of 5,000 runs alone, then the line page while three lot pages load at once (issue 37:
   a slow request must not slow the line page); prints the figures and their ratios.
3. Follows two SSE clients on /api/v1/events/stream,
   and writes a line's runs through the store API (Store.start_run / finish_run): 8 stations,
   one run each per --run-every-s simulated seconds, for --sim-minutes simulated minutes,
   compressed into --wall-s seconds of wall time.  Prints the server's RSS at the start and the
   end of the stream and how many runs each client received.

    python benchmarks/serve_line_page.py [--runs 100000] [--sim-minutes 10] [--wall-s 60]
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from accelcal_station.acceptance.reasons import Reason
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store
from accelcal_station.web import linepage
from accelcal_station.web.assets import render

STATIONS = [f"line1-st{k}" for k in range(8)]


def build(path: Path, n: int, seed: int = 1) -> None:
    Store(path).close()  # the schema
    rng = np.random.default_rng(seed)
    t_end = time.time()
    t = np.sort(rng.uniform(t_end - 30 * 86400, t_end, n))
    rows = []
    for i in range(n):
        fail = rng.uniform() < 0.07
        measured = {"gain_error_max": float(abs(rng.normal(0.01, 0.004))),
                    "offset_max_mg": float(abs(rng.normal(40, 8))),
                    "cross_axis_max": float(abs(rng.normal(0.01, 0.003))),
                    "residual_rms_mg": float(abs(rng.normal(0.03, 0.01)))}
        reasons = [Reason("offset_max_mg", f"{measured['offset_max_mg']:.1f} > limit 30", " ").to_dict()] \
            if fail else []
        serial = f"SN{(i if rng.uniform() > 0.04 else max(0, i - 3)):07d}"
        cal = {"schema": "accelcal.calibration", "version": 1, "model": "12", "input_units": "g",
               "input_per_g": 1.0, "W": (np.eye(3) + rng.normal(0, 0.005, (3, 3))).tolist(),
               "V": rng.normal(0, 0.02, 3).tolist(), "Gamma": [0.0, 0.0, 0.0], "temperature": None, "metadata": {}}
        limits = {"offset_max_mg": 30.0 if i < n // 2 else 35.0, "crossval_rms_mg": 10.0}  # a limit change halfway
        rows.append((float(t[i]), float(t[i]) + 40, serial, STATIONS[i % 8], f"L{i // 5000}",
                     "FAIL" if fail else "PASS", json.dumps(reasons),
                     json.dumps({"measured": measured, "reason_codes": [r["code"] for r in reasons]}),
                     json.dumps(cal), json.dumps(limits)))
    db = sqlite3.connect(path)
    with db:
        db.executemany("INSERT INTO runs (started_at, finished_at, status, device_serial, station_id, lot, verdict,"
                       " reasons, fit_summary, calibration, limits, model, nvm_status)"
                       " VALUES (?, ?, 'complete', ?, ?, ?, ?, ?, ?, ?, ?, '12', 'written')", rows)
    db.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def time_line_page(path: Path) -> list[float]:
    out = []
    for _ in range(7):
        t0 = time.perf_counter()
        with Store(path, create=False) as st:
            ctx = linepage.line_context(st)
        render("line.html", title="Line", page="line", **ctx)
        out.append(time.perf_counter() - t0)
    return out


def _start_server(path: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "serve", "--db", str(path),
                             "--port", str(port)], stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    while True:
        try:
            httpx.get(base + "/api/v1/events/head", timeout=2)
            return proc, base
        except httpx.HTTPError:
            assert time.monotonic() - t0 < 30, "server did not start"
            time.sleep(0.2)


def _get_s(url: str, **params: str) -> float:
    t0 = time.perf_counter()
    r = httpx.get(url, params=params, timeout=300)
    assert r.status_code == 200, r.text[:200]
    return time.perf_counter() - t0


def pages_under_load(path: Path, repeats: int = 5) -> None:
    """Line and lot page over HTTP, alone and the line page while three lot pages load (medians)."""
    proc, base = _start_server(path)
    try:
        _get_s(base + "/"), _get_s(base + "/lot", lot="L3")  # warm
        line = statistics.median(_get_s(base + "/") for _ in range(repeats))
        lot = statistics.median(_get_s(base + "/lot", lot="L3") for _ in range(repeats))
        during, lot3 = [], []
        for _ in range(repeats):
            out: list[float] = []
            threads = [threading.Thread(target=lambda lot=lot_id, out=out: out.append(_get_s(base + "/lot", lot=lot)))
                       for lot_id in ("L3", "L7", "L11")]
            for t in threads:
                t.start()
            time.sleep(0.05)
            during.append(_get_s(base + "/"))
            for t in threads:
                t.join()
            lot3.append(max(out))
        d, all3 = statistics.median(during), statistics.median(lot3)
        print(f"HTTP, median of {repeats}: line page {line * 1e3:.0f} ms; lot page (5,000 runs) {lot * 1e3:.0f} ms; "
              f"line page while 3 lot pages load {d * 1e3:.0f} ms ({d / line:.2f} x alone); "
              f"the 3 lot pages all done in {all3 * 1e3:.0f} ms ({all3 / lot:.2f} x "
              "one lot page: they take turns in one lane)")
    finally:
        proc.terminate()
        proc.wait(10)


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def session() -> Session:
    poses = [PoseRecord(f"p{i}", np.eye(3)[i % 3], None, 100, np.eye(3)[i % 3]) for i in range(6)]
    return Session(poses, units="g")


def stream_soak(path: Path, sim_minutes: float, run_every_s: float, wall_s: float) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "serve", "--db", str(path),
                             "--port", str(port)], stderr=subprocess.DEVNULL)
    try:
        t0 = time.monotonic()
        while True:
            try:
                httpx.get(base + "/api/v1/events/head", timeout=2)
                break
            except httpx.HTTPError:
                assert time.monotonic() - t0 < 30, "server did not start"
                time.sleep(0.2)
        head = httpx.get(base + "/api/v1/events/head").json()["next"]
        clients: list[list[int]] = [[], []]
        stop = threading.Event()
        threads = []
        for got in clients:
            def run(got: list[int] = got) -> None:
                try:
                    with httpx.stream("GET", f"{base}/api/v1/events/stream", params={"after": head},
                                      timeout=None) as r:
                        for line in r.iter_lines():
                            if line.startswith("data: "):
                                got.append(json.loads(line[6:])["id"])
                            if stop.is_set():
                                return
                except httpx.HTTPError:
                    return  # the server stopped at the end
            threads.append(threading.Thread(target=run, daemon=True))
        for t in threads:
            t.start()
        time.sleep(1.0)
        rss0 = rss_kb(proc.pid)
        n_runs = int(sim_minutes * 60 / run_every_s) * len(STATIONS)
        gap = wall_s / n_runs
        with Store(path) as st:
            for i in range(n_runs):
                rid = st.start_run(device_serial=f"SOAK{i:06d}", station_id=STATIONS[i % 8], lot="soak")
                st.finish_run(rid, session=session(), calibration=None, verdict="PASS",
                              fit_summary={"measured": {"residual_rms_mg": 0.03}})
                time.sleep(gap)
        deadline = time.monotonic() + 10
        while min(len(c) for c in clients) < n_runs and time.monotonic() < deadline:
            time.sleep(0.2)
        rss1 = rss_kb(proc.pid)
        stop.set()
        print(f"events stream: {sim_minutes:g} simulated minutes of a line of {len(STATIONS)} stations "
              f"(a run per station every {run_every_s:g} s: {n_runs} runs) written in {wall_s:g} s of wall time; "
              f"clients received {[len(c) for c in clients]} events ({[len(set(c)) for c in clients]} distinct)")
        print(f"server RSS: {rss0 / 1024:.1f} MiB at the start, {rss1 / 1024:.1f} MiB at the end "
              f"({(rss1 - rss0) / 1024:+.1f} MiB)")
    finally:
        proc.terminate()
        proc.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=100_000)
    ap.add_argument("--sim-minutes", type=float, default=10.0)
    ap.add_argument("--run-every-s", type=float, default=6.0)
    ap.add_argument("--wall-s", type=float, default=60.0)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "line.sqlite"
        t0 = time.perf_counter()
        build(path, a.runs)
        size_mib = os.path.getsize(path) / 2**20
        print(f"store: {a.runs} runs built in {time.perf_counter() - t0:.1f} s ({size_mib:.0f} MiB)")
        times = time_line_page(path)
        print(f"line page server time (queries + render, in process): best {min(times) * 1e3:.0f} ms, "
              f"median {statistics.median(times) * 1e3:.0f} ms of 7 over {a.runs} runs")
        pages_under_load(path)
        stream_soak(path, a.sim_minutes, a.run_every_s, a.wall_s)


if __name__ == "__main__":
    main()

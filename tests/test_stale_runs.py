"""Issue 34: a run whose station process is gone reads ``stale``, not ``running``, without another
run starting.  A real ``accelcal run`` process (an operator jig: it blocks on stdin at the first
pose) is killed with SIGKILL; ``report list``, ``report summary`` and the line page then say stale.
Nothing is written to the store by reading it."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.store.liveness import process_started_at, stale_reason
from accelcal_station.store.runs import Store

REPO = Path(__file__).resolve().parents[1]


def _running_row(db: Path, timeout_s: float = 120.0) -> tuple[int, int]:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if db.exists():
            try:
                with sqlite3.connect(db) as c:
                    row = c.execute("SELECT id, pid FROM runs WHERE status = 'running'").fetchone()
                if row:
                    return row
            except sqlite3.Error:
                pass
        time.sleep(0.2)
    raise AssertionError("the station never recorded its run")


def test_a_killed_station_reads_stale(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["jig"] = {"type": "operator"}  # the operator is asked for each pose: the run waits on stdin
    cfg["store"] = {"path": "runs.sqlite"}
    Path("st.yaml").write_text(yaml.safe_dump(cfg))
    exe = [sys.executable, "-m", "accelcal_station.cli"] if not (Path(sys.executable).parent / "accelcal").exists() \
        else [str(Path(sys.executable).parent / "accelcal")]
    proc = subprocess.Popen([*exe, "run", "--config", "st.yaml", "--serial", "SN1", "--operator", "op"],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        run_id, pid = _running_row(tmp_path / "runs.sqlite")
        assert pid == proc.pid
        listed = CliRunner().invoke(cli, ["report", "list", "--db", "runs.sqlite"])
        assert " running " in listed.output and "stale" not in listed.output, listed.output  # alive: running
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    before = hashlib.sha256(Path("runs.sqlite").read_bytes()).hexdigest()
    listed = CliRunner().invoke(cli, ["report", "list", "--db", "runs.sqlite"])
    assert listed.exit_code == 0, listed.output
    line = next(ln for ln in listed.output.splitlines() if ln.split()[0] == str(run_id))
    assert " stale " in line and f"station process {pid}" in line and "running" not in line, listed.output
    for status, n in (("stale", 1), ("running", 0)):  # stored as running, told apart as read
        got = CliRunner().invoke(cli, ["report", "list", "--db", "runs.sqlite", "--status", status, "--json"])
        assert len(json.loads(got.stdout)) == n, got.output
    summary = CliRunner().invoke(cli, ["report", "summary", "--db", "runs.sqlite", "--json"])
    assert '"stale": 1' in summary.output and '"running": 0' in summary.output, summary.output
    pytest.importorskip("fastapi")
    from fastapi.testclient import TestClient

    from accelcal_station.web.app import create_app
    from accelcal_station.web.settings import WebSettings

    client = TestClient(create_app(WebSettings(store="runs.sqlite")))
    runs = client.get("/api/v1/runs").json()["runs"]
    assert [r["status"] for r in runs] == ["stale"], runs
    page = client.get("/fragment/line").text
    assert "stale" in page and ">running<" not in page
    with sqlite3.connect("runs.sqlite") as c:  # reading named it; the row itself is as the station left it
        assert c.execute("SELECT status FROM runs WHERE id = ?", (run_id,)).fetchone()[0] == "running"
    assert hashlib.sha256(Path("runs.sqlite").read_bytes()).hexdigest() == before


def test_a_live_run_and_another_hosts_run_stay_running(tmp_path):
    with Store(tmp_path / "s.sqlite") as st:
        st.start_run(device_serial="SN1")  # this process: alive
    with Store(tmp_path / "s.sqlite") as st:
        assert [r["status"] for r in st.list_runs()] == ["running"]
    row = {"status": "running", "host": "another-host", "pid": 1 << 30, "started_at": time.time()}
    assert stale_reason(row) is None  # no heartbeat (a run recorded before schema 5): not judged from here


def test_another_hosts_run_is_judged_by_its_heartbeat():
    """Schema 5: a run on another host reads stale after STALE_BEATS missed beats, by its own interval."""
    from accelcal_station.store.liveness import STALE_BEATS

    now = 1_800_000_000.0
    row = {"status": "running", "host": "line2-pc", "pid": 4242, "started_at": now - 7200.0,
           "heartbeat_s": 30.0, "heartbeat_at": now - 60.0}
    assert stale_reason(row, now=now) is None  # two beats ago: alive, however old the run
    row["heartbeat_at"] = now - STALE_BEATS * 30.0 - 1.0
    why = stale_reason(row, now=now) or ""
    assert "no heartbeat from the station on line2-pc for 301 s" in why and "every 30 s" in why, why
    for bad in (None, float("nan"), "soon", True, -5.0):  # a damaged or missing interval: not judged
        assert stale_reason({**row, "heartbeat_s": bad}, now=now) is None, bad
    assert stale_reason({**row, "status": "complete"}, now=now) is None


def test_a_station_on_another_host_beats_while_alive_and_reads_stale_once_killed(tmp_path, monkeypatch):
    """A real `accelcal run` (operator jig: it waits on stdin) beats every 0.2 s; its row, moved to
    another host's name as a line database holds a remote station's runs, reads running while the
    process lives, and stale (no heartbeat) shortly after SIGKILL: the pid is never consulted."""
    monkeypatch.chdir(tmp_path)
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["jig"] = {"type": "operator"}
    cfg["store"] = {"path": "runs.sqlite", "heartbeat_s": 0.2}
    Path("st.yaml").write_text(yaml.safe_dump(cfg))
    exe = [sys.executable, "-m", "accelcal_station.cli"] if not (Path(sys.executable).parent / "accelcal").exists() \
        else [str(Path(sys.executable).parent / "accelcal")]
    proc = subprocess.Popen([*exe, "run", "--config", "st.yaml", "--serial", "SN1", "--operator", "op"],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def beat() -> float:
        with sqlite3.connect("runs.sqlite") as c:
            return float(c.execute("SELECT heartbeat_at FROM runs WHERE id = ?", (run_id,)).fetchone()[0])

    try:
        run_id, _ = _running_row(tmp_path / "runs.sqlite")
        with sqlite3.connect("runs.sqlite") as c:
            c.execute("UPDATE runs SET host = 'line2-pc' WHERE id = ?", (run_id,))
        first = beat()
        time.sleep(3.0)  # 15 beats: the waiting station keeps beating
        assert beat() > first + 1.0
        listed = CliRunner().invoke(cli, ["report", "list", "--db", "runs.sqlite", "--json"])
        assert [r["status"] for r in json.loads(listed.stdout)] == ["running"], listed.output
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    last = beat()
    time.sleep(3.0)  # > 10 beats of 0.2 s of silence
    assert beat() == last  # nothing beats for a dead station
    listed = CliRunner().invoke(cli, ["report", "list", "--db", "runs.sqlite", "--json"])
    (row,) = json.loads(listed.stdout)
    assert row["status"] == "stale" and "no heartbeat from the station on line2-pc" in row["status_reason"], row


def test_a_reused_pid_is_stale():
    """The pid exists but its process started after the run: not the station's process."""
    me = os.getpid()
    started = process_started_at(me)
    assert started is not None and abs(started - time.time()) < 7 * 24 * 3600
    import socket

    row = {"status": "running", "host": socket.gethostname(), "pid": me, "started_at": started - 3600.0}
    assert "later process" in (stale_reason(row) or "")
    row["started_at"] = started + 1.0
    assert stale_reason(row) is None


def test_a_store_that_fails_after_the_burn_keeps_the_result_and_says_what_is_where(tmp_path, monkeypatch):
    """SQLite itself refuses the run's final write (a trigger raising as a disk I/O error would, after the
    board's NVM was burned): the station keeps the whole result in the outbox and its one error line says
    what was burned (slot, generation, CRC-32), what the store holds and where the result went."""
    monkeypatch.chdir(tmp_path)
    from accelcal_station.config.sections import default_config_path

    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": "runs.sqlite", "outbox": "outbox.sqlite"}
    cfg["device"]["seed"] = 3
    Path("st.yaml").write_text(yaml.safe_dump(cfg))
    with Store("runs.sqlite"):
        pass
    with sqlite3.connect("runs.sqlite") as c:
        c.execute("CREATE TRIGGER fail BEFORE UPDATE OF status ON runs WHEN NEW.status = 'complete'"
                  " BEGIN SELECT RAISE(ABORT, 'disk I/O error'); END")
    r = CliRunner().invoke(cli, ["run", "--config", "st.yaml", "--serial", "SN7"])
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error")]
    assert r.exit_code != 0 and r.exit_code != 70 and len(errors) == 1, r.output
    line = errors[0]
    with Store("outbox.sqlite", create=False) as ob:
        (kept,) = ob.runs()
    with Store("runs.sqlite", create=False) as st:
        (held,) = st.runs()
    assert kept.status == "complete" and kept.calibration and kept.device_serial == "SN7" and kept.poses
    assert kept.nvm_status == "written" and held.status == "error" and held.calibration is None
    burn = kept.nvm_outcome
    where = f"slot {burn['slot']}, generation {burn['generation']}, CRC-32 0x{burn['crc32']:08x}"
    assert f"NVM WAS written ({where}" in line, line
    assert f"holds run {held.id} as error without a calibration" in line, line
    assert f"kept in the outbox outbox.sqlite as run {kept.id}" in line and "disk I/O error" in line, line

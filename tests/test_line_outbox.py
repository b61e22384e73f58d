"""The line database goes away (tests/pgserver.py's real server, stopped with `pg_ctl stop -m
immediate`) before, during and after the burn of a simulated-board run: the run goes on, its
results kept in the local outbox with one line said, and `accelcal report sync` puts every run
into PostgreSQL with its poses, verdict and NVM outcome, once.  The server is stopped from an
SQLAlchemy cursor hook at the statement named, so "during the burn" is exact, not timed."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from click.testing import CliRunner
from conftest import REPO
from sqlalchemy import event
from sqlalchemy.engine import Engine

from accelcal_station.cli import cli
from accelcal_station.store.runs import Store

# where the server stops: (name, SQL start, a value in its parameters); None: before the run
STOPS = [
    ("before the run", None, None),
    ("at the start of the run", "INSERT INTO runs", None),
    ("as the burn begins", "INSERT INTO events", "nvm_burning"),
    ("after the burn, before its record", "INSERT INTO events", "nvm_burned"),
    ("while the result is recorded", "INSERT INTO poses", None),
]


@pytest.fixture
def line(pg_server, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))  # the default outbox goes there
    yield pg_server, pg_server.new_database()
    if pg_server.halted:  # a failed test never leaves the shared server down for the next ones
        pg_server.resume()


def _stop_at(pg, sql: str, value: str | None):
    fired = []

    def hook(conn, _cursor, statement, parameters, _context, _many):
        if not fired and conn.dialect.name == "postgresql" and statement.startswith(sql) \
                and (value is None or value in str(parameters)):
            fired.append(statement)
            pg.halt()

    event.listen(Engine, "before_cursor_execute", hook)
    return hook, fired


RUN = ["run", "--config", str(REPO / "configs" / "sim.yaml"), "--json", "--store"]
NOTICE = "line database unreachable: results kept locally, 1 waiting"


def _run(url: str, serial: str):
    return CliRunner().invoke(cli, [*RUN, url, "--serial", serial])


def _run_process(url: str, serial: str) -> tuple[int, str, str]:
    """`accelcal run` as the operator starts it: the notice must reach its stderr."""
    p = subprocess.run([sys.executable, "-m", "accelcal_station", *RUN, url, "--serial", serial],
                       capture_output=True, text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


@pytest.mark.parametrize("where, sql, value", STOPS, ids=[s[0] for s in STOPS])
def test_a_run_survives_the_line_database_going_away(line, where, sql, value, caplog):
    pg, url = line
    with Store(url) as st:  # the schema exists, as on a line in use
        st.mark_stale_interrupted()
    if sql is None:  # a separate process: the operator's terminal sees the one line
        pg.halt()
        code, out, err = _run_process(url, "SN-1")
        assert code == 0 and NOTICE in err, err[-2000:]
    else:  # in this process, so the hook sees the statement; the line is logged (caplog has it)
        hook, fired = _stop_at(pg, sql, value)
        try:
            r = _run(url, "SN-1")
        finally:
            event.remove(Engine, "before_cursor_execute", hook)
        assert fired, f"the run never reached {sql} {value}"
        code, out, err = r.exit_code, r.stdout, r.output
        assert code == 0, r.output[-2000:]
        assert [m for m in caplog.messages if NOTICE in m], caplog.messages
    assert "Traceback" not in err and "invalid transaction" not in err
    report = json.loads(out)
    started_on_server = sql is not None and sql != "INSERT INTO runs"
    # a run started while the server answered keeps its id; one started without it has an outbox id (< 0)
    assert report["verdict"] == "PASS" and (report["run_id"] > 0) == started_on_server
    pg.resume()
    s = CliRunner().invoke(cli, ["report", "sync", "--db", url])
    assert s.exit_code == 0 and "replayed 1 run(s)" in s.output, s.output
    with Store(url, create=False) as st:
        recs = st.runs()
    assert len(recs) == 1, [(x.id, x.status) for x in recs]  # a run started on the server is completed, not doubled
    rec = recs[0]
    assert rec.id == report["run_id"] if started_on_server else rec.id > 0
    assert (rec.device_serial, rec.status, rec.verdict) == ("SN-1", "complete", "PASS")
    assert len(rec.poses) == 8 and rec.calibration is not None
    assert rec.nvm_status == "written" and rec.nvm_outcome["ok"] is True
    assert rec.nvm_outcome["generation"] == report["nvm"]["generation"]
    kinds = [e["kind"] for e in rec.events]
    assert kinds.count("nvm_burning") == 1 and kinds.count("nvm_burned") == 1 and "replayed" in kinds
    again = CliRunner().invoke(cli, ["report", "sync", "--db", url, "--json"])
    assert again.exit_code == 0 and json.loads(again.stdout)["replayed"] == []
    with Store(url, create=False) as st:
        assert [len(x.poses) for x in st.runs()] == [8] and len(st.get_run(rec.id).events) == len(rec.events)


def test_replaying_a_run_twice_writes_it_once(line, tmp_path):
    """The outbox's own mark aside (a sync killed between the server's commit and the mark):
    the server's copy is found by start time, host and pid, and nothing is written again."""
    _pg, url = line
    r = _run(f"sqlite:///{tmp_path / 'local.sqlite'}", "SN-2")
    assert r.exit_code == 0, r.output[-1000:]
    with Store(tmp_path / "local.sqlite") as local:
        rec = local.runs()[0]
    with Store(url) as st:
        first = st.replay_run(rec, None, "test")
        second = st.replay_run(rec, first[0], "test")
        third = st.replay_run(rec, None, "test")
        assert first[1] and second == (first[0], False) and third == (first[0], False)
        assert [len(x.poses) for x in st.runs()] == [8]


def test_next_run_replays_the_outbox_and_says_so(line):
    pg, url = line
    with Store(url) as st:
        st.mark_stale_interrupted()
    pg.halt()
    assert _run(url, "SN-3").exit_code == 0
    pg.resume()
    code, _out, err = _run_process(url, "SN-4")
    assert code == 0 and "1 run(s) replayed from the local outbox" in err, err[-1000:]
    with Store(url, create=False) as st:
        assert sorted((x.device_serial, x.status, len(x.poses)) for x in st.runs()) == [
            ("SN-3", "complete", 8), ("SN-4", "complete", 8)]
    s = CliRunner().invoke(cli, ["report", "sync", "--db", url])
    assert s.exit_code == 0 and "nothing to replay" in s.output


def test_no_server_and_no_outbox_is_one_line(line, tmp_path, monkeypatch):
    pg, url = line
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the outbox folder would be\n")
    monkeypatch.setenv("XDG_STATE_HOME", str(blocker))
    pg.halt()
    try:
        r = _run(url, "SN-5")
    finally:
        pg.resume()
    assert r.exit_code == 2 and "local outbox cannot keep the results" in r.stdout, r.output[-1000:]
    assert "Traceback" not in r.output


def test_the_config_names_the_outbox_and_report_sync_finds_it(line, tmp_path):
    pg, url = line
    cfg = tmp_path / "line.yaml"
    box = tmp_path / "box" / "outbox.sqlite"
    text = (REPO / "configs" / "sim.yaml").read_text()
    cfg.write_text(text.replace("  path: accelcal-runs.sqlite", f"  path: '{url}'\n  outbox: '{box}'", 1))
    with Store(url) as st:
        st.mark_stale_interrupted()
    pg.halt()
    r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--serial", "SN-6", "--json"])
    assert r.exit_code == 0 and box.is_file(), r.output[-1000:]
    pg.resume()
    s = CliRunner().invoke(cli, ["report", "sync", "--config", str(cfg), "--json"])
    assert s.exit_code == 0 and len(json.loads(s.stdout)["replayed"]) == 1, s.output
    with Store(url, create=False) as st:
        assert [(x.device_serial, len(x.poses)) for x in st.runs()] == [("SN-6", 8)]

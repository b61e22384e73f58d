"""Issue 12, operators and the MES, through the command line: aborts at a prompt (a real
pty), serial scan, required operator, live reading, timing, --json errors and group
commands, fit figures and burn events in the store, report export/show, pipes."""
from __future__ import annotations

import json
import os
import pty
import select
import signal
import sqlite3
import subprocess
import sys
import time
import tty
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path

REPO = Path(__file__).resolve().parents[1]


def sim_config(tmp_path, **sections) -> str:
    cfg = yaml.safe_load(default_config_path().read_text())
    for k, v in sections.items():
        cfg[k] = {**cfg.get(k, {}), **v} if isinstance(v, dict) and k in ("station", "device") else v
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["seed"] = 7
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def db_row(tmp_path, sql):
    return sqlite3.connect(tmp_path / "runs.sqlite").execute(sql).fetchall()


def _read_until(fd, marker: bytes, timeout_s: float = 60.0) -> bytes:
    buf, t0 = b"", time.monotonic()
    while marker not in buf:
        assert time.monotonic() - t0 < timeout_s, buf.decode(errors="replace")
        r, _, _ = select.select([fd], [], [], 0.5)
        if r:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
    return buf


def panel_config(tmp_path, boards: int = 1) -> str:
    """configs/panel-sim.yaml with the operator jig (the simulated hand holds the fixture)."""
    cfg = yaml.safe_load((REPO / "configs" / "panel-sim.yaml").read_text())
    cfg["jig"] = {"type": "operator", "hand": {}}
    cfg["device"]["boards"] = boards
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def _terminal_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _run_in_pty(tmp_path, how: str, path: str | None = None):
    """`accelcal run` with the operator jig on a pseudo-terminal: accept pose 1, then at the
    second prompt send end of input (Ctrl-D) or Ctrl-C (SIGINT, as the terminal does)."""
    path = path or sim_config(tmp_path, jig={"type": "operator", "hand": {}})
    master, slave = pty.openpty()
    # Ctrl-C as a terminal delivers it: SIGINT neither ignored nor blocked in the station's process (a child
    # inherits both from whatever started it: a background job of a non-interactive shell ignores SIGINT, and
    # a test runner's worker thread may block it; the mask survives exec)
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "run", "--config", path],
                            stdin=slave, stdout=slave, stderr=slave, cwd=tmp_path, close_fds=True,
                            preexec_fn=_terminal_sigint)
    os.close(slave)
    try:
        _read_until(master, b"a=abort")
        os.write(master, b"\r")
        _read_until(master, b"a=abort")
        if how == "eof":
            live = _read_until(master, b"\x1b7\x1b[1A", timeout_s=10)  # the live line redrawn while waiting
            assert b"now [" in live + _read_until(master, b"]", timeout_s=5)
            os.write(master, b"\x04")
        else:
            time.sleep(0.5)  # as a person would: a signal in the instant between the prompt and the read is lost
            proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=20)
        out = b""
        try:
            while True:
                r, _, _ = select.select([master], [], [], 0.2)
                if not r:
                    break
                chunk = os.read(master, 4096)
                if not chunk:
                    break
                out += chunk
        except OSError:
            pass
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    return rc, out.decode(errors="replace")


@pytest.mark.parametrize("how", ["eof", "ctrl-c"])
def test_abort_at_a_prompt_exits_5_one_line_and_is_recorded_interrupted(tmp_path, how):
    rc, out = _run_in_pty(tmp_path, how)
    assert rc == 5, out
    errors = [ln for ln in out.splitlines() if "error" in ln.lower() or "Aborted" in ln]
    assert len(errors) == 1 and "operator aborted at pose p2" in errors[0], out
    assert "Traceback" not in out
    (status, reason), = db_row(tmp_path, "SELECT status, status_reason FROM runs")
    assert status == "interrupted" and "aborted" in reason
    assert db_row(tmp_path, "SELECT count(*) FROM poses") == [(1,)]  # the pose captured so far


def test_live_reading_is_shown_while_placing_and_timing_separates_operator_wait(tmp_path):
    path = sim_config(tmp_path, jig={"type": "operator", "hand": {}})
    r = CliRunner().invoke(cli, ["run", "--config", path], input="\n" * 40)
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    first_prompt = next(i for i, ln in enumerate(lines) if "a=abort" in ln)
    assert any(ln.strip().startswith("now [") for ln in lines[:first_prompt + 1]), r.output
    timing = [ln for ln in lines if ln.startswith("time:")]
    assert timing and "floor" not in " ".join(timing)
    assert any("host compute" in ln for ln in timing)


def test_serial_scan_prompt_and_required_operator(tmp_path):
    path = sim_config(tmp_path, station={"id": "s1", "scan_serial": True, "require_operator": True})
    r = CliRunner().invoke(cli, ["run", "--config", path])
    assert r.exit_code == 2 and "--operator: required" in r.output
    r = CliRunner().invoke(cli, ["run", "--config", path, "--operator", "ana", "--json"],
                           input="bad\x1b[31mserial\nSN-4711\n")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["serial"] == "SN-4711"
    # (the runner echoes typed input as a terminal would; the station's own line is escaped)
    again = [ln for ln in r.stderr.splitlines() if "scan again" in ln]
    assert len(again) == 1 and "\x1b" not in again[0] and "\\x1b" in again[0]
    assert db_row(tmp_path, "SELECT device_serial, operator FROM runs") == [("SN-4711", "ana")]
    r = CliRunner().invoke(cli, ["run", "--config", path, "--operator", "ana"], input="")
    assert r.exit_code == 5 and "serial-number scan" in r.output


def test_json_errors_and_group_commands(tmp_path):
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "absent.yaml"), "--json"])
    assert r.exit_code == 2 and r.stderr == ""
    assert json.loads(r.stdout) == {"error": f"{tmp_path / 'absent.yaml'}: cannot read (No such file or directory)",
                                    "code": 2, "kind": "ConfigError"}
    r = CliRunner().invoke(cli, ["report", "list", "--json", "--no-such-flag"])
    assert r.exit_code == 2 and json.loads(r.stdout)["kind"] == "usage"
    top = json.loads(CliRunner().invoke(cli, ["--json"]).stdout)
    assert {"run", "nvm", "report"} <= {c["name"] for c in top["subcommands"]}
    nvm = json.loads(CliRunner().invoke(cli, ["nvm", "--json"]).stdout)
    assert {c["name"] for c in nvm["subcommands"]} == {"read", "backup", "restore", "erase"}


def test_station_runs_store_fit_figures_burn_events_and_reports(tmp_path):
    path = sim_config(tmp_path)
    db = str(tmp_path / "runs.sqlite")
    assert CliRunner().invoke(cli, ["run", "--config", path]).exit_code == 0
    listed = json.loads(CliRunner().invoke(cli, ["report", "list", "--db", db, "--json"]).stdout)
    assert listed[0]["residual_rms_g"] is not None
    assert json.loads(CliRunner().invoke(cli, ["report", "--db", db, "--json"]).stdout) == listed
    csv = CliRunner().invoke(cli, ["report", "export", "--db", db]).stdout.splitlines()
    head, row = csv[0].split(","), csv[1].split(",")
    for col in ("residual_rms_g", "crossval_rms_g", "condition_number"):
        assert row[head.index(col)] not in ("", "None"), col
    exp = json.loads(CliRunner().invoke(cli, ["report", "export", "--db", db, "--json"]).stdout)
    assert exp["runs"][0]["fit_summary"]["crossval_rms_g"] > 0
    kinds = [e["kind"] for e in exp["runs"][0]["events"]]
    assert kinds.index("nvm_burning") < kinds.index("nvm_burned")
    show = CliRunner().invoke(cli, ["report", "show", "1", "--db", db]).stdout
    for word in ("residual rms", "cross-validated", "verify error", "timing", "event"):
        assert word in show, word


def test_a_bridge_that_does_not_answer_is_recorded_as_error(tmp_path):
    cfg = yaml.safe_load((REPO / "configs" / "mpu6050.yaml").read_text())
    master, slave = os.openpty()  # a port nobody answers on
    tty.setraw(slave)
    try:
        cfg["device"].update(port=os.ttyname(slave), timeout_s=0.05, retries=1, boot_wait_s=0.0)
        cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
        cfg["jig"] = {"type": "operator"}  # the config's motorized jig is opened first (issue 49): the bridge here
        p = tmp_path / "mpu.yaml"
        p.write_text(yaml.safe_dump(cfg))
        r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    finally:
        os.close(master)
        os.close(slave)
    assert r.exit_code == 3 and json.loads(r.stdout)["code"] == 3
    (status, reason), = db_row(tmp_path, "SELECT status, status_reason FROM runs")
    assert status == "error" and reason.startswith("device:") and "no answer" in reason


def test_output_piped_to_head_ends_quietly(tmp_path):
    path = sim_config(tmp_path)
    assert CliRunner().invoke(cli, ["run", "--config", path]).exit_code == 0
    db = tmp_path / "runs.sqlite"
    p = subprocess.run(f"{sys.executable} -m accelcal_station report export --db {db} --poses | head -c 10",
                       shell=True, capture_output=True, text=True, timeout=60)
    assert p.stderr == "" and len(p.stdout) == 10


def _emulate_seed(*args) -> int:
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "emulate", "mpu6050-bridge", "--json", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        return json.loads(proc.stdout.readline())["seed"]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)


def test_emulate_prints_a_seed_that_seed_accepts():
    seed = _emulate_seed()
    assert isinstance(seed, int) and seed >= 0  # fresh entropy: usually beyond 2**32
    assert _emulate_seed("--seed", str(seed)) == seed


def test_lot_report_html_and_run_plot(tmp_path):
    pytest.importorskip("matplotlib")
    path = sim_config(tmp_path)
    db = str(tmp_path / "runs.sqlite")
    for _ in range(2):  # two boards: the fewest a control chart's moving range needs
        assert CliRunner().invoke(cli, ["run", "--config", path]).exit_code == 0
    page = tmp_path / "lot.html"
    r = CliRunner().invoke(cli, ["report", "summary", "--db", db, "--html", str(page)])
    assert r.exit_code == 0, r.output
    text = page.read_text()
    assert "pass rate 100.0 %" in text and text.count("data:image/png;base64,") == 1 + 9
    assert all(f"<h3>{n}</h3>" in text for n in ("W00", "V2 (mg)", "W12"))
    # individuals chart: x = 1, 2, 4 -> centre 7/3, mean moving range 1.5, sigma 1.5 / 1.128
    from accelcal_station.lot.report import control_limits
    c, lo, hi = control_limits(np.array([1.0, 2.0, 4.0]))
    assert c == pytest.approx(7 / 3) and hi - c == pytest.approx(3 * 1.5 / 1.128)
    png = tmp_path / "r1.png"
    r = CliRunner().invoke(cli, ["report", "plot", "1", "--db", db, "-o", str(png)])
    assert r.exit_code == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_crash_during_the_burn_leaves_the_run_burning_with_the_blob_crc(tmp_path):
    """Power is cut (the EEPROM raises mid-page, as the fault injector does) and then the
    station process dies before it can record anything else: the store already says
    `burning`, with the slot, generation and CRC-32 of the blob being written."""
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.settings import StationConfig

    cfg = StationConfig.load(sim_config(tmp_path))
    driver = make_driver(cfg.device)

    class Died(BaseException):
        pass

    def die(*_a, **_k):
        raise Died()
    driver.nvm.write = die  # the process dies at the first byte of the burn
    with pytest.raises(Died):
        make_flow(cfg, echo=lambda s: None, driver=driver).run()[0]
    (status, nvm_status, outcome), = db_row(tmp_path, "SELECT status, nvm_status, nvm_outcome FROM runs")
    assert status == "running" and nvm_status == "burning"
    o = json.loads(outcome)
    assert o["slot"] == "A" and o["generation"] == 1 and isinstance(o["crc32"], int)
    kinds = [k for k, in db_row(tmp_path, "SELECT kind FROM events")]
    assert kinds == ["nvm_burning"]


def test_report_group_db_reaches_its_subcommands(tmp_path):
    path = sim_config(tmp_path)
    assert CliRunner().invoke(cli, ["run", "--config", path]).exit_code == 0
    db = str(tmp_path / "runs.sqlite")
    r = CliRunner().invoke(cli, ["report", "--db", db, "list", "--json"])
    assert r.exit_code == 0 and len(json.loads(r.stdout)) == 1


def test_panel_abort_at_the_operator_prompt_exits_5_and_records_each_board_interrupted(tmp_path):
    """A panel on the operator jig: end of input at the second prompt is an operator abort
    (exit 5, one error line) and every board's run is `interrupted` with the pose it captured."""
    r = CliRunner().invoke(cli, ["run", "--config", panel_config(tmp_path, boards=2)], input="\n")
    assert r.exit_code == 5, r.output
    errors = [ln for ln in r.output.splitlines() if "error" in ln.lower() or "Aborted" in ln]
    assert len(errors) == 1 and "operator aborted at pose p2" in errors[0], r.output
    runs = db_row(tmp_path, "SELECT id, status, status_reason, panel_id FROM runs ORDER BY id")
    assert len(runs) == 2 and all(s == "interrupted" and "operator aborted" in why for _, s, why, _ in runs)
    assert len({p for *_, p in runs}) == 1  # one panel
    poses = dict(db_row(tmp_path, "SELECT run_id, count(*) FROM poses GROUP BY run_id"))
    assert poses.get(runs[0][0]) == 1  # board 1, held by the simulated hand, captured pose p1


def test_panel_ctrl_c_at_the_operator_prompt_on_a_terminal(tmp_path):
    rc, out = _run_in_pty(tmp_path, "ctrl-c", panel_config(tmp_path))
    assert rc == 5, out
    assert "Traceback" not in out and "Aborted!" not in out
    assert out.count("error: ") == 1 and "error: operator aborted at pose p2" in out, out
    (status, reason), = db_row(tmp_path, "SELECT status, status_reason FROM runs")
    assert status == "interrupted" and "aborted" in reason
    assert db_row(tmp_path, "SELECT count(*) FROM poses") == [(1,)]

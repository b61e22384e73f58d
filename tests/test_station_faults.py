"""Issue 49: the station's own faults, serials where they enter, and the operator page exposed only on
purpose.  The missing jig and lost ports are in test_port_faults.py and test_panel_port_faults.py."""
from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.serials import BOARD_SERIAL_MAX, check_serial
from accelcal_station.drivers.factory import make_driver
from accelcal_station.errors import DataError
from accelcal_station.nvm.blob import TEXT_BYTES
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
HOSTILE = "<svg onload=alert(3)>"


def _sim_config(tmp_path: Path, **device: object) -> Path:
    doc = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    doc["device"].update(device)
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    p = tmp_path / "st.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_the_board_serial_limit_is_the_nvm_field():
    assert BOARD_SERIAL_MAX == TEXT_BYTES == 32  # the blob's serial field (docs/data-formats.md: 32 bytes)
    assert check_serial("A" * 32, "x") == "A" * 32
    with pytest.raises(DataError, match="1-32"):
        check_serial("A" * 33, "x")


@pytest.mark.parametrize("serial", [HOSTILE, "=cmd|' /C calc'!A0", "A" * 33, "SN 12", "SN\x1b[2J"])
def test_a_configured_serial_is_refused_before_the_first_pose(tmp_path, serial):
    cfg = _sim_config(tmp_path, serial=serial)
    r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--json"])
    assert r.exit_code == 2, r.output
    err = json.loads(r.stdout)
    assert err["code"] == 2 and err["error"].startswith("device.serial: ") and "serial number" in err["error"]
    assert "[1/" not in r.output and not (tmp_path / "runs.sqlite").exists()  # no pose, no store row


@pytest.mark.parametrize("serial", [HOSTILE, "A" * 33])
def test_the_serial_option_follows_the_same_rule(tmp_path, serial):
    r = CliRunner().invoke(cli, ["run", "--config", str(_sim_config(tmp_path)), "--serial", serial])
    assert r.exit_code == 2 and "--serial" in r.output and "1-32" in r.output, r.output
    assert not (tmp_path / "runs.sqlite").exists()


def test_a_serial_the_device_reports_is_refused_before_the_first_pose(tmp_path):
    """An MPU6050 bridge (on a real pty) that reports a hostile serial: refused at identification,
    before the self-test and the poses, exit 2; the error run names no verdict."""
    doc = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["device"]["port"] = "emulated"
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    cfg = StationConfig.load(tmp_path / "m.yaml")
    driver = make_driver(cfg.device)
    driver.emulator.serial = HOSTILE[:8].encode()  # the bridge's 8-byte serial field: <svg onl
    said: list[str] = []
    with pytest.raises(DataError, match="reports: .* is not a serial number") as err:
        make_flow(cfg, driver=driver, echo=said.append).run()
    assert err.value.exit_code == 2
    assert not any("self-test" in s or "[1/" in s for s in said), said
    rows = sqlite3.connect(tmp_path / "runs.sqlite").execute("SELECT status, verdict FROM runs").fetchall()
    assert rows == [("error", None)]


def test_the_operator_page_beyond_loopback_needs_a_token_or_public(tmp_path):
    cfg = _sim_config(tmp_path)
    for host in ("0.0.0.0", "::", "192.0.2.7", "station.example"):
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--ui", "web", "--ui-host", host, "--json"])
        assert r.exit_code == 2, r.output
        (line,) = r.stdout.strip().splitlines()  # one line, nothing else
        err = json.loads(line)
        assert err["error"].startswith(f"--ui-host {host}: ") and "web.operator_token" in err["error"]
        assert "--public" in err["error"]
    assert not (tmp_path / "runs.sqlite").exists()


def test_a_bad_operator_token_is_refused_in_one_line(tmp_path):
    doc = yaml.safe_load(_sim_config(tmp_path).read_text())
    doc["web"] = {"operator_token": "short"}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "t.yaml"), "--ui", "web"])
    assert r.exit_code == 2 and "web.operator_token" in r.output and "16-200" in r.output, r.output


def test_with_a_token_the_page_answers_only_who_has_it(tmp_path):
    """The operator page with web.operator_token (here on loopback, where the token applies all the same):
    a client without the token is refused 401 on the state and the answers (the run goes on untouched);
    Chromium opening the printed link answers every pose and the run PASSes."""
    pytest.importorskip("fastapi")
    pytest.importorskip("selenium")
    import httpx
    from selenium.webdriver.common.by import By
    from webtools import chromium, free_port

    token = "t0ken-For-The-Operator-42"
    doc = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "web.sqlite")}
    doc["web"] = {"operator_token": token}
    (tmp_path / "web.yaml").write_text(yaml.safe_dump(doc))
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "run", "--config", str(tmp_path / "web.yaml"),
                             "--ui", "web", "--ui-port", str(port), "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                page = httpx.get(base + "/", timeout=2)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline, "the operator page never answered"
                time.sleep(0.2)
        assert page.status_code == 401 and "token" in page.text
        assert httpx.get(base + "/operator/state").status_code == 401
        for body in ({"answer": "abort"}, {"answer": "skip"}, {"answer": "serial", "serial": "X1"}):
            r = httpx.post(base + "/operator/answer", json=body)
            assert r.status_code == 401 and r.json()["code"] == "unauthorized", r.text
        wrong = httpx.post(base + "/operator/answer", json={"answer": "abort"},
                           headers={"Authorization": "Bearer not-the-token-at-all"})
        assert wrong.status_code == 401
        with chromium() as drv:
            drv.get(f"{base}/?token={token}")
            assert "token=" not in drv.current_url  # the token leaves the address bar
            t0 = time.monotonic()
            while not drv.find_element(By.ID, "result").is_displayed():
                assert time.monotonic() - t0 < 180, drv.page_source[-2000:]
                button = drv.find_element(By.ID, "b-accept")
                # as an operator: accept once the live level says the board is still on the right face
                if button.is_enabled() and "READY" in drv.find_element(By.ID, "ready").text:
                    button.click()
                time.sleep(0.15)
            assert drv.find_element(By.ID, "result-verdict").text == "PASS"
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert json.loads(out)["verdict"] == "PASS"
    assert f"?token={token}" in err  # the printed link carries the token


def _emulated_mpu(tmp_path: Path, **emulator: object) -> Path:
    doc = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["device"].update(port="emulated", emulator=emulator)
    p = tmp_path / "mpu.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_an_emulated_clone_is_refused_in_one_line_naming_it(tmp_path):
    """A module whose part answers WHO_AM_I 0x98 (as most MPU-6050 clones on the market do): one line that
    names the value, does not call it an ICM-20689, and gives the config line that accepts it."""
    r = CliRunner().invoke(cli, ["run", "--config", str(_emulated_mpu(tmp_path, who_am_i=0x98)), "--json"])
    assert r.exit_code == 3, r.output
    (line,) = r.stdout.strip().splitlines()
    err = json.loads(line)["error"]
    assert "WHO_AM_I (0x75) reads 0x98" in err and "clone" in err and "device.accept_who_am_i: [0x98]" in err
    assert "ICM-20689)" not in err


def test_an_accepted_clone_is_calibrated_with_its_self_test_skipped(tmp_path):
    doc = yaml.safe_load(_emulated_mpu(tmp_path, who_am_i=0x98).read_text())
    doc["device"]["accept_who_am_i"] = [0x98]  # the line the refusal gives
    (tmp_path / "ok.yaml").write_text(yaml.safe_dump(doc))
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "ok.yaml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["verdict"] == "PASS" and out["self_test"] is None
    assert any(e.startswith("self-test skipped") and "0x98" in e for e in out["events"]), out["events"]


def _emulated_mma(tmp_path: Path, **emulator: object) -> Path:
    doc = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["device"]["emulator"] = emulator
    p = tmp_path / "mma.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_a_held_sda_ends_in_one_line_naming_the_cause(tmp_path):
    r = CliRunner().invoke(cli, ["run", "--config", str(_emulated_mma(tmp_path, sda_held=True)), "--json"])
    assert r.exit_code == 3, r.output
    (line,) = r.stdout.strip().splitlines()
    err = json.loads(line)["error"]
    assert "timed out" in err and "SDA or SCL held low" in err and "power-cycle" in err, err
    assert "Traceback" not in r.output


def test_a_nack_storm_ends_in_one_line_naming_the_cause(tmp_path):
    r = CliRunner().invoke(cli, ["run", "--config", str(_emulated_mma(tmp_path, nack_every=1)), "--json"])
    assert r.exit_code == 3, r.output
    (line,) = r.stdout.strip().splitlines()
    err = json.loads(line)["error"]
    assert "0x1d" in err and "no ACK" in err and "loose contact" in err, err
    rows = sqlite3.connect(tmp_path / "runs.sqlite").execute("SELECT status, verdict FROM runs").fetchall()
    assert rows == [("error", None)]  # the station's error, never the board's FAIL


def test_a_missing_chamber_is_a_station_error_before_any_board_step(tmp_path):
    """A thermal plan whose chamber port does not exist: exit 3 before the board's self-test, an error run
    naming the chamber, no verdict (the jig, an emulator on a real pty, answered)."""
    from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

    pytest.importorskip("pyvisa")
    doc = yaml.safe_load((CONFIGS / "thermal-mpu6050.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["device"]["port"] = "emulated"
    doc["chamber"]["port"] = str(tmp_path / "no-chamber")
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    with JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5)) as jig:
        r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "t.yaml"), "--jig-port", jig.port, "--json"])
    assert r.exit_code == 3, r.output
    assert "self-test" not in r.stderr and "STATION FAULT (chamber" in r.stderr, r.stderr
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    rows = db.execute("SELECT status, verdict, status_reason FROM runs").fetchall()
    assert len(rows) == 1 and rows[0][:2] == ("error", None) and rows[0][2].startswith("station fault (chamber): ")

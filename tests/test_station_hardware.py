"""The station through the real-chip code paths: MPU6050 bridge + motorized jig over two
pseudo-terminals, and the MMA8451 on its emulated I2C bus with the operator jig."""
from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator
from accelcal_station.nvm.writer import CalibrationWriter

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_mpu6050_bridge_with_motorized_jig_end_to_end(tmp_path):
    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    board = SimulatedBoard.from_config(sim, chip="mpu6050", seed=3)
    bridge = MPU6050BridgeEmulator(board)
    port = bridge.start()
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=board, board_lock=bridge.lock)
    jig.start()
    try:
        cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
        cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
        cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)  # fast axes: a quick test
        p = tmp_path / "mpu.yaml"
        p.write_text(yaml.safe_dump(cfg))
        r = CliRunner().invoke(cli, ["run", "--config", str(p), "--port", port, "--jig-port", jig.port, "--json"])
        assert r.exit_code == 0, r.output
        out = json.loads(r.stdout)
        assert out["verdict"] == "PASS" and out["chip"] == "mpu6050" and out["nvm_verified"]
        # the jig visited every planned pose (MOVE commands) and the board's NVM holds the fit
        assert sum(c.startswith("MOVE") for c in jig.received) >= 8
        cal, header, _ = CalibrationWriter(bridge.nvm).read_newest(out["serial"])
        np.testing.assert_allclose(cal.W, out["W"], rtol=0, atol=0)
        # the fitted calibration inverts the board's own errors (truth) to well under 1 mg
        truth = board.truth()
        g = np.array([[0.6, -0.6, 0.52], [0.0, 0.0, 1.0]]) * cal.input_per_g
        np.testing.assert_allclose(cal.apply(g, units="counts"), truth.apply(g, units="counts"), atol=1e-3)
    finally:
        jig.stop()
        bridge.stop()


def test_mma8451_emulated_bus_with_operator_jig(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, ["run", "--config", str(CONFIGS / "mma8451-emulated.yaml"), "--operator", "bo"],
                           input="\n" * 8)
    assert r.exit_code == 0, r.output
    assert "Pose x+1g: put the board x+ up: stand it on its -x edge, +x pointing up" in r.output
    assert "PASS board EMU-0001" in r.output
    db = sqlite3.connect(tmp_path / "accelcal-runs.sqlite")
    assert db.execute("SELECT chip, verdict, nvm_status FROM runs").fetchone() == ("mma8451", "PASS", "written")


def test_emulate_bridge_with_motor_jig_prints_both_ports():
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "emulate", "mpu6050-bridge", "--motor-jig",
                             "--json", "--seed", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        info = json.loads(line)
        assert info["port"].startswith("/dev/") and info["jig_port"].startswith("/dev/")
        assert info["port"] != info["jig_port"]
    finally:
        proc.terminate()
        proc.wait(timeout=30)  # generous: two emulator threads join on a loaded CI machine
    assert proc.returncode == 0


def trim_config(tmp_path, name: str, **plan) -> tuple[dict, Path]:
    """configs/NAME with nvm.offset_trim on and a store in tmp_path, written to tmp_path."""
    cfg = yaml.safe_load((CONFIGS / name).read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["nvm"]["offset_trim"] = True
    cfg["plan"].update(plan)
    p = tmp_path / "trim.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return cfg, p


def test_mma8451_offset_trim_moves_the_offset_into_the_chip(tmp_path):
    cfg, p = trim_config(tmp_path, "mma8451-emulated.yaml")
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"], input="\n" * 8)
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    # the emulated board's offsets are +12, -8, +25 mg: 1/512 g per LSB -> about -6, +4, -13 LSB
    offset_mg = np.array(cfg["device"]["simulator"]["effects"]["offset"]["offset_mg"])
    np.testing.assert_allclose(out["offset_trim_lsb"], -offset_mg / (1000 / 512), atol=1.0)
    # what is left for V is under one trim LSB, and the closed loop through the trimmed chip holds
    assert np.max(np.abs(out["V"])) < 1 / 512
    assert out["verify_error_max_mg"] < 1.0 and out["nvm_verified"]
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    stored_v = json.loads(db.execute("SELECT calibration FROM runs").fetchone()[0])["V"]
    np.testing.assert_allclose(stored_v, out["V"])


def test_offset_trim_is_refused_where_it_cannot_work(tmp_path):
    _, p = trim_config(tmp_path, "sim.yaml")
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    assert r.exit_code == 2 and "the simulated driver has no offset-trim registers" in r.stderr
    _, p = trim_config(tmp_path, "sim.yaml", model=15)
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    assert r.exit_code == 2 and "nvm.offset_trim: the 15-parameter model" in r.stderr

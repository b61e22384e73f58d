"""Bring-up tools (issue 49): `accelcal probe --scan` and `accelcal run --dry-run`, through the real CLI
against the register-level emulators (smbus2's API), the MPU6050 bridge and the jig emulators on real
pseudo-terminals.  The addresses and WHO_AM_I values are the data sheets' (MMA8451Q data sheet, "Device
I2C address": 0x1C with SA0 low, 0x1D with SA0 high; WHO_AM_I register 0x0D reads 0x1A; TCA9548A at
0x70 with A2..A0 low; 24Cxx EEPROMs at 0x50-0x57), written here, not taken from the code."""
from __future__ import annotations

import json
from pathlib import Path

import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
MMA8451Q_SA0_HIGH, MMA8451Q_WHO_AM_I, TCA9548A_DEFAULT, EEPROM_24CXX = 0x1D, 0x1A, 0x70, 0x50


def _scan(config: Path, *extra: str) -> dict:
    r = CliRunner().invoke(cli, ["probe", "--scan", "--config", str(config), "--json", *extra])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_scan_finds_the_emulated_mma8451_at_0x1d():
    out = _scan(CONFIGS / "mma8451-emulated.yaml")
    found = {(int(f["address"], 16), f["chip"], f["who_am_i"]) for f in out["found"]}
    assert (MMA8451Q_SA0_HIGH, "MMA8451Q", f"0x{MMA8451Q_WHO_AM_I:02x}") in found
    assert any(a == EEPROM_24CXX for a, _, _ in found)  # the board's calibration EEPROM
    assert all(a in (MMA8451Q_SA0_HIGH, EEPROM_24CXX) for a, _, _ in found), found  # nothing invented
    text = CliRunner().invoke(cli, ["probe", "--scan", "--config", str(CONFIGS / "mma8451-emulated.yaml")])
    assert text.exit_code == 0 and "0x1d" in text.output and "MMA8451Q (WHO_AM_I 0x1a)" in text.output


def test_scan_looks_behind_every_mux_channel(tmp_path):
    doc = yaml.safe_load((CONFIGS / "panel-mma8451-emulated.yaml").read_text())
    boards = doc["device"]["boards"]
    boards[1]["emulator"] = {"present": False}  # a slot whose chip does not answer
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    out = _scan(tmp_path / "p.yaml")
    mux = [f for f in out["found"] if f["kind"] == "mux"]
    assert [int(f["address"], 16) for f in mux] == [TCA9548A_DEFAULT]
    chips = {f["channel"] for f in out["found"] if f["chip"] == "MMA8451Q"}
    channels = {b.get("channel", i) for i, b in enumerate(boards)}
    assert chips == channels - {boards[1].get("channel", 1)}, (chips, channels)


def test_scan_of_serial_ports_names_the_bridge_and_the_jig():
    from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
    from accelcal_station.drivers.simulated import SimulatedBoard
    from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

    bridge = MPU6050BridgeEmulator(SimulatedBoard.from_config(None, chip="mpu6050", seed=4))
    port = bridge.start()
    try:
        out = _scan(CONFIGS / "mpu6050.yaml", "--port", port)
        (p,) = out["serial_ports"]
        assert p["port"] == port and p["answers"].startswith("MPU6050 bridge") and "0x68" in p["answers"]
    finally:
        bridge.stop()
    with JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5, homed=True)) as jig:
        (p,) = _scan(CONFIGS / "mpu6050.yaml", "--port", jig.port)["serial_ports"]
        assert p["answers"].startswith("motorized jig")
        assert not any(c.startswith(("MOVE", "HOME")) for c in jig.received)  # a probe never moves the jig


def test_dry_run_checks_every_instrument_and_writes_nothing(tmp_path):
    doc = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    before = sorted(p.name for p in tmp_path.iterdir())
    r = CliRunner().invoke(cli, ["run", "--dry-run", "--config", str(tmp_path / "m.yaml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["ok"] and {c["what"] for c in out["checks"]} >= {"config", "store", "device", "jig"}
    device = next(c for c in out["checks"] if c["what"] == "device")
    assert "mma8451" in device["detail"] and "EMU-0001" in device["detail"]
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no store, no file


def test_dry_run_moves_a_motorized_jig_and_names_a_missing_one(tmp_path):
    from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

    doc = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    with JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5)) as jig:
        r = CliRunner().invoke(cli, ["run", "--dry-run", "--config", str(tmp_path / "m.yaml"), "--port", "emulated",
                                     "--jig-port", jig.port])
        moved = sum(c.startswith("MOVE") for c in jig.received)
    assert r.exit_code == 0, r.output
    assert moved >= 1 and "moved to" in r.output
    r = CliRunner().invoke(cli, ["run", "--dry-run", "--config", str(tmp_path / "m.yaml"), "--port", "emulated",
                                 "--jig-port", str(tmp_path / "no-port"), "--json"])
    assert r.exit_code == 3
    out = json.loads(r.stdout)
    jig_check = next(c for c in out["checks"] if c["what"] == "jig")
    assert not out["ok"] and not jig_check["ok"] and "cannot open" in jig_check["detail"]
    assert not (tmp_path / "runs.sqlite").exists()

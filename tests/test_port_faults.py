"""Every device and port fault ends in a recorded verdict (issue 26): the motorized jig's pty hangs
up mid-run, the MPU6050 bridge's port is dropped mid-stream.  Both over real pseudo-terminals with
pyserial; the run is recorded FAIL with a typed reason and the poses captured so far, exit 1 (never
70, never left 'running')."""
from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers.bridge_link import BridgeLink
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.errors import PortLostError
from accelcal_station.fixtures.jig_emulator import JigEmulator
from accelcal_station.fixtures.motorized_jig import MotorizedJig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def rig(tmp_path: Path):
    """An MPU6050 bridge emulator and a jig emulator on two ptys, and a station config for them."""
    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    board = SimulatedBoard.from_config(sim, chip="mpu6050", seed=3)
    bridge = MPU6050BridgeEmulator(board)
    port = bridge.start()
    jig = JigEmulator(board=board, speed_deg_s=4000, accel_deg_s2=1e5, board_lock=bridge.lock)
    jig.start()
    cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)  # fast axes: a quick test
    p = tmp_path / "mpu.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return bridge, port, jig, p


def run_and_check(tmp_path: Path, bridge, port, jig, cfg: Path, code: str) -> dict:
    try:
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--port", port, "--jig-port", jig.port, "--json"])
    finally:
        jig.stop()
        bridge.stop()
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output
    out = json.loads(r.stdout)
    assert out["verdict"] == "FAIL" and code in out["reasons"][0], out["reasons"]
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    db.row_factory = sqlite3.Row
    run = db.execute("SELECT * FROM runs").fetchone()
    assert run["status"] != "running" and run["verdict"] == "FAIL"
    stored = json.loads(run["reasons"])
    assert stored[0]["code"] == code and "lost" in stored[0]["message"]
    poses = db.execute("SELECT COUNT(*) FROM poses WHERE run_id = ?", (run["id"],)).fetchone()[0]
    assert 1 <= poses < 8 and poses == len(out["poses"])  # what was captured before the fault, kept
    return out


def test_jig_pty_hangs_up_mid_run(tmp_path):
    bridge, port, jig, cfg = rig(tmp_path)
    jig.inject("disconnect", after=40)  # a full run sends ~120 commands: this is about the third pose
    run_and_check(tmp_path, bridge, port, jig, cfg, "port_lost")
    assert not jig.running


def test_bridge_port_dropped_mid_stream(tmp_path):
    bridge, port, jig, cfg = rig(tmp_path)

    def drop_after_three_moves() -> None:
        deadline = time.monotonic() + 60
        while sum(c.startswith("MOVE") for c in list(jig.received)) < 3 and time.monotonic() < deadline:
            time.sleep(0.002)
        bridge.stop()  # the bridge's side of the pty closes while the host streams from it

    t = threading.Thread(target=drop_after_three_moves, daemon=True)
    t.start()
    run_and_check(tmp_path, bridge, port, jig, cfg, "port_lost")
    t.join(timeout=5)


def test_lost_ports_are_typed_at_the_driver_boundary():
    """A pty that hangs up under pyserial (EIO, termios.error on tcflush) is a PortLostError, not a crash."""
    with JigEmulator(speed_deg_s=4000, accel_deg_s2=1e5, homed=True) as emu:
        jig = MotorizedJig(emu.port, timeout_s=0.2, retries=0, home_on_open=False)
        jig.open()
        emu.stop()  # both ends of the emulator's pty close
        with pytest.raises(PortLostError, match="connection lost"):
            jig.status()
        jig.close()  # closing a lost port is quiet
    board = SimulatedBoard.from_config(None, chip="mpu6050", seed=1)
    bridge = MPU6050BridgeEmulator(board)
    link = BridgeLink(bridge.start(), timeout_s=0.2, retries=0)
    link.open()
    bridge.stop()
    with pytest.raises(PortLostError, match="lost serial port"):
        for _ in range(50):  # the first write may still land in the tty buffer
            link.send(1)
            time.sleep(0.01)
    link.close()


def test_nack_storm_mid_run_is_a_recorded_fail(tmp_path):
    """The emulated MMA8451 NACKs every transaction from ~1/3 of the way through a run (a whole run
    is ~5,800 transactions): the run is FAIL with reason code 'device', its poses so far recorded."""
    import sqlite3 as sq

    from accelcal_station.config.sections import device_section
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.settings import StationConfig

    doc = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "st.yaml").write_text(yaml.safe_dump(doc))
    dev = make_driver(device_section(str(tmp_path / "st.yaml")))
    with dev:
        emu = dev.dev.smbus
    emu.nack_next(k=100_000, address=emu.address, after=2_000)
    rep = make_flow(StationConfig.load(tmp_path / "st.yaml"), driver=dev, echo=lambda s: None).run()[0]
    assert rep.verdict == "FAIL" and rep.reasons[0].code == "device" and emu.nacked >= 3  # retried, then gave up
    (status, verdict, reasons), = sq.connect(tmp_path / "runs.sqlite").execute(
        "SELECT status, verdict, reasons FROM runs").fetchall()
    assert (status, verdict) == ("complete", "FAIL") and json.loads(reasons)[0]["code"] == "device"
    n = sq.connect(tmp_path / "runs.sqlite").execute("SELECT COUNT(*) FROM poses").fetchone()[0]
    assert 1 <= n < 6 and n == len(rep.poses)

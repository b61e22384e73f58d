"""Every device and port fault ends in a recorded run (issue 26), and it is the station's error, never
the board's verdict (issue 49): the motorized jig's pty hangs up mid-run, the MPU6050 bridge's port is
dropped mid-stream, the MMA8451's bus NACKs.  Over real pseudo-terminals with pyserial (and smbus2's
API against the register emulator); the run is recorded ``error`` with the typed station reason and the
poses captured so far, no verdict, exit 3 (never 1, never 70, never left 'running')."""
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
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator
from accelcal_station.fixtures.motorized_jig import JigAxes, JigLink, MotorizedJig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def rig(tmp_path: Path):
    """An MPU6050 bridge emulator and a jig emulator on two ptys, and a station config for them."""
    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    board = SimulatedBoard.from_config(sim, chip="mpu6050", seed=3)
    bridge = MPU6050BridgeEmulator(board)
    port = bridge.start()
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=board, board_lock=bridge.lock)
    jig.start()
    cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)  # fast axes: a quick test
    p = tmp_path / "mpu.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return bridge, port, jig, p


def run_and_check(tmp_path: Path, bridge, port, jig, cfg: Path, instrument: str) -> dict:
    try:
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--port", port, "--jig-port", jig.port, "--json"])
    finally:
        jig.stop()
        bridge.stop()
    assert r.exit_code == 3, r.output  # the station's error, not a board's FAIL (1)
    assert "Traceback" not in r.output
    out = json.loads(r.stdout)
    assert set(out) >= {"error", "code"} and out["code"] == 3 and "lost" in out["error"], out
    assert "STATION FAULT" in r.stderr and "not judged" in r.stderr
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    db.row_factory = sqlite3.Row
    run = db.execute("SELECT * FROM runs").fetchone()
    assert run["status"] == "error" and run["verdict"] is None  # counted in no yield
    assert run["status_reason"].startswith(f"station fault ({instrument}): ") and "lost" in run["status_reason"]
    poses = db.execute("SELECT COUNT(*) FROM poses WHERE run_id = ?", (run["id"],)).fetchone()[0]
    assert 1 <= poses < 8  # what was captured before the fault, kept
    return out


def test_jig_pty_hangs_up_mid_run(tmp_path):
    bridge, port, jig, cfg = rig(tmp_path)
    jig.inject("disconnect", after=40)  # a full run sends ~120 commands: this is about the third pose
    run_and_check(tmp_path, bridge, port, jig, cfg, "jig")
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
    run_and_check(tmp_path, bridge, port, jig, cfg, "device")
    t.join(timeout=5)


def test_lost_ports_are_typed_at_the_driver_boundary():
    """A pty that hangs up under pyserial (EIO, termios.error on tcflush) is a PortLostError, not a crash."""
    with JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5, homed=True)) as emu:
        jig = MotorizedJig(emu.port, JigLink(timeout_s=0.2, retries=0), JigAxes(home_on_open=False))
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


def test_nack_storm_mid_run_is_a_station_error(tmp_path):
    """The emulated MMA8451 NACKs every transaction from ~1/3 of the way through a run (a whole run
    is ~7,200 transactions): the run ends as the station's error (status error, no verdict), its poses
    so far recorded, and the error names the NACKs."""
    import sqlite3 as sq

    from accelcal_station.config.sections import device_section
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.errors import DeviceError
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.settings import StationConfig

    doc = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "st.yaml").write_text(yaml.safe_dump(doc))
    dev = make_driver(device_section(str(tmp_path / "st.yaml")))
    with dev:
        emu = dev.dev.smbus
    emu.nack_next(k=100_000, address=emu.address, after=3_000)
    said: list[str] = []
    with pytest.raises(DeviceError) as err:
        make_flow(StationConfig.load(tmp_path / "st.yaml"), driver=dev, echo=said.append).run()
    assert err.value.exit_code == 3 and emu.nacked >= 3  # retried, then gave up
    assert any(s.startswith("STATION FAULT (device") for s in said), said
    (status, verdict, why), = sq.connect(tmp_path / "runs.sqlite").execute(
        "SELECT status, verdict, status_reason FROM runs").fetchall()
    assert (status, verdict) == ("error", None) and why.startswith("station fault (device): ")
    n = sq.connect(tmp_path / "runs.sqlite").execute("SELECT COUNT(*) FROM poses").fetchone()[0]
    assert 1 <= n < 6


def test_missing_jig_port_is_a_station_error_before_any_board_step(tmp_path):
    """`run --jig-port /no/such/port` (issue 49): exit 3 before the board's self-test, an error run
    with the station reason and no verdict; the board is neither passed nor failed."""
    cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "mpu.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "mpu.yaml"), "--port", "emulated",
                                 "--jig-port", str(tmp_path / "no-such-port"), "--json"])
    assert r.exit_code == 3, r.output
    out = json.loads(r.stdout)
    assert out["code"] == 3 and "jig on" in out["error"] and "cannot open" in out["error"]
    assert "self-test" not in r.stderr  # no board step ran
    assert "check the jig's cable" in r.stderr
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    rows = db.execute("SELECT status, verdict, status_reason FROM runs").fetchall()
    assert len(rows) == 1 and rows[0][:2] == ("error", None) and rows[0][2].startswith("station fault (jig): ")
    assert db.execute("SELECT COUNT(*) FROM poses").fetchone()[0] == 0


def test_a_lost_cable_is_a_station_error_on_the_line_page_not_a_yield_loss(tmp_path):
    """Issue 49: one board PASSes, the next loses its jig cable mid-run; on `accelcal serve`'s line
    page and API the second run is the station's error, named, and the station's yield stays 100 %
    (a board not judged counts in no yield, first-pass yield or failure reasons)."""
    pytest.importorskip("fastapi")
    import httpx
    from webtools import live_server

    bridge, port, jig, cfg = rig(tmp_path)
    try:
        ok = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--port", port, "--jig-port", jig.port,
                                      "--serial", "SN-GOOD", "--json"])
        assert ok.exit_code == 0, ok.output
        jig.inject("disconnect", after=40)
        lost = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--port", port, "--jig-port", jig.port,
                                        "--serial", "SN-CABLE", "--json"])
        assert lost.exit_code == 3, lost.output
    finally:
        jig.stop()
        bridge.stop()
    with live_server(str(tmp_path / "runs.sqlite")) as base:
        y = httpx.get(base + "/api/v1/yield").json()
        (station,) = y["stations"]
        assert (station["runs"], station["pass"], station["yield"]) == (1, 1, 1.0), station
        assert not y["failure_reasons"], y
        runs = httpx.get(base + "/api/v1/runs").json()["runs"]
        err = next(r for r in runs if r["device_serial"] == "SN-CABLE")
        assert err["status"] == "error" and err["verdict"] is None
        assert err["status_reason"].startswith("station fault (jig): ") and "lost" in err["status_reason"]
        page = httpx.get(base + "/").text
        assert "SN-CABLE" in page and ">error<" in page

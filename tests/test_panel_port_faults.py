"""Every device and port fault ends in a recorded run, for the PANEL stations too (issue 26), and it is
the station's error, never a board's verdict (issue 49): the motorized jig's pty hangs up mid-run, a
board's bridge port is dropped mid-stream (real ptys, pyserial), the multiplexed I2C bus NACKs every
transaction from mid-run (the emulator's fault option).  Each affected board's run is recorded
``error`` with the typed station reason and the poses it captured, no verdict, on a real SQLite store;
the command exits 3 (never 1 or 70) and no run is left 'running'."""
from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path

import yaml
from click.testing import CliRunner
from test_port_faults import rig

from accelcal_station.cli import cli
from accelcal_station.config.schema import validate_device
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def panel_rig(tmp_path: Path):
    """A panel (device.boards) of one MPU6050 bridge on a pty, moved by a jig emulator on another pty:
    test_port_faults' rig, with the bridge as the panel's one board and the jig's port in the config."""
    bridge, port, jig, single = rig(tmp_path)
    cfg = yaml.safe_load(single.read_text())
    cfg["jig"]["port"] = jig.port
    cfg["device"]["boards"] = [{"port": port}]
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return bridge, jig, p


def runs_of(tmp_path: Path) -> list[sqlite3.Row]:
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    db.row_factory = sqlite3.Row
    rows = db.execute("SELECT r.*, (SELECT COUNT(*) FROM poses p WHERE p.run_id = r.id) AS n_poses "
                      "FROM runs r ORDER BY r.id").fetchall()
    db.close()
    return rows


def run_panel(tmp_path: Path, bridge, jig, cfg: Path, instrument: str) -> dict:
    try:
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--json"])
    finally:
        jig.stop()
        bridge.stop()
    assert r.exit_code == 3, r.output
    assert "Traceback" not in r.output
    board = json.loads(r.stdout)["boards"][0]
    assert board["verdict"] == "ERROR" and board["reasons"] == [], board
    assert board["station_fault"].startswith(f"station fault ({instrument}): ") and "lost" in board["station_fault"]
    run, = runs_of(tmp_path)
    assert (run["status"], run["verdict"]) == ("error", None)  # counted in no yield
    assert run["status_reason"] == board["station_fault"]
    assert 1 <= run["n_poses"] < 8 and run["n_poses"] == len(board["poses"])  # captured before the fault, kept
    return board


def test_panel_jig_pty_hangs_up_mid_run(tmp_path):
    bridge, jig, cfg = panel_rig(tmp_path)
    jig.inject("disconnect", after=40)  # a full run sends ~120 commands: about the third pose
    run_panel(tmp_path, bridge, jig, cfg, "jig")


def test_panel_bridge_port_dropped_mid_stream(tmp_path):
    bridge, jig, cfg = panel_rig(tmp_path)

    def drop_after_three_moves() -> None:
        deadline = time.monotonic() + 60
        while sum(c.startswith("MOVE") for c in list(jig.received)) < 3 and time.monotonic() < deadline:
            time.sleep(0.002)
        bridge.stop()

    t = threading.Thread(target=drop_after_three_moves, daemon=True)
    t.start()
    run_panel(tmp_path, bridge, jig, cfg, "device")
    t.join(timeout=5)


def test_thermal_panel_jig_pty_hangs_up_mid_plan(tmp_path):
    """A thermal plan over a panel (simulated boards in the emulated chamber), moved by a motorized jig on
    a real pty that hangs up during the first set point: every board's run an error with the jig's station
fault, no verdict, its poses kept."""
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.fixtures.factory import board_of
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.panel_config import panel_sections
    from accelcal_station.station.settings import StationConfig

    doc = yaml.safe_load((CONFIGS / "thermal-panel-sim.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["device"]["boards"] = 1
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    (sec, path), = panel_sections(validate_device(doc["device"]))
    driver = make_driver(sec, path)
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=board_of(driver))
    jig.start()
    doc["jig"] = {"type": "motorized", "port": jig.port, "timeout_s": 0.5, "speed_deg_s": 4000,
                  "accel_deg_s2": 1e5, "settle_s": 0.0}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    jig.inject("disconnect", after=40)
    try:
        reps = make_flow(StationConfig.load(tmp_path / "t.yaml"), drivers=[driver],
                                   echo=lambda s: None).run()
    finally:
        jig.stop()
    rep, = reps
    assert rep.verdict == "ERROR" and rep.station_fault.startswith("station fault (jig): "), rep.station_fault
    run, = runs_of(tmp_path)
    assert (run["status"], run["verdict"]) == ("error", None)
    assert "lost" in run["status_reason"]
    assert 1 <= run["n_poses"] < 8  # the poses of the first set point captured before the hang-up


def test_nack_storm_on_the_multiplexed_bus_mid_run(tmp_path):
    """Three emulated MMA8451 boards behind the emulated TCA9548A; from ~1/3 of the run every board's
    emulator NACKs every transaction (the emulator's nack_next fault, armed after 3,000 of its own
    transactions; a whole run is ~7,200): each board's run an error with the station fault, no verdict, its
poses so far recorded."""
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.panel_config import panel_sections
    from accelcal_station.station.settings import StationConfig

    doc = yaml.safe_load((CONFIGS / "panel-mma8451-emulated.yaml").read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["device"]["boards"] = doc["device"]["boards"][:3]
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    buses: dict = {}
    drivers = [make_driver(sec, path, buses) for sec, path in panel_sections(validate_device(doc["device"]))]
    for d in drivers:
        d.emulator.nack_next(k=100_000, after=3_000)
    reps = make_flow(StationConfig.load(tmp_path / "p.yaml"), drivers=drivers, echo=lambda s: None).run()
    assert [r.verdict for r in reps] == ["ERROR"] * 3
    assert all(r.station_fault.startswith("station fault (device): ") for r in reps), [r.station_fault for r in reps]
    assert all(d.emulator.nacked >= 3 for d in drivers)  # retried, then gave up
    runs = runs_of(tmp_path)
    assert [(r["status"], r["verdict"]) for r in runs] == [("error", None)] * 3
    assert all(r["status_reason"].startswith("station fault (device): ") for r in runs)
    assert all(1 <= r["n_poses"] < 8 for r in runs) and [r["n_poses"] for r in runs] == [len(r.poses) for r in reps]

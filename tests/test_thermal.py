"""Temperature calibration in an emulated chamber: the thermal plan end to end, its failures,
the chamber driver over a pseudo-terminal, and the chamber's first-order physics."""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers.simulated import VirtualClock
from accelcal_station.instruments.chamber import AsciiChamber, ChamberError
from accelcal_station.instruments.chamber_emulator import ChamberEmulator, ChamberPhysics
from accelcal_station.instruments.factory import make_chamber

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _config(tmp_path, name="t.yaml", faults=None, **device):
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    if faults:
        cfg["chamber"]["emulator"]["faults"] = faults
    if device:
        cfg["device"] = device
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def _run(path):
    r = CliRunner().invoke(cli, ["run", "--config", str(path), "--json"])
    return r, json.loads(r.stdout)


def _stored(tmp_path):
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    return db.execute("SELECT status, verdict, reasons, nvm_status FROM runs").fetchall()


def test_thermal_sim_burns_a_three_temperature_table_that_verifies_at_45c(tmp_path):
    r, out = _run(_config(tmp_path))
    assert r.exit_code == 0, r.output
    th = out["thermal"]
    assert out["verdict"] == "PASS" and out["chip"] == "mpu6050" and out["nvm_verified"]
    assert len(th["table"]["temps_c"]) == 3 and th["temp_source"] == "die"
    # the table's temperatures are the die's, near the set points (self-heating 1.5 C, a lagging board)
    np.testing.assert_allclose(th["table"]["temps_c"], [-20 + 1.5, 25 + 1.5, 70 + 1.5], atol=0.5)
    (v,) = th["verify"]
    assert v["set_point_c"] == 45 and v["within_limit"] and v["error_max_mg"] <= v["limit_mg"]
    # the board's temperature effect at 45 C is many mg: one calibration alone would fail
    assert not v["without_table_within_limit"] and v["without_table_error_max_mg"] > 2 * v["limit_mg"]
    t = out["timing"]
    assert t["soak_s"] > 0.8 * t["board_time_s"]  # soak dominates
    assert t["soak_s"] + t["sampling_floor_s"] + t["rest_s"] == pytest.approx(t["board_time_s"])
    assert _stored(tmp_path) == [("complete", "PASS", "[]", "written")]
    # against the simulator's own truth (its physics, not the fit): the stored table inverts the
    # board at a calibration temperature to well under 1 mg, and at 45 C within the linear
    # interpolation error of the quadratic offset term (0.0025 mg/C^2 x 20 C x 25 C = 1.25 mg on z)
    from accelcal_station.calibration import Calibration
    from accelcal_station.drivers.simulated import SimulatedBoard

    db = sqlite3.connect(tmp_path / "runs.sqlite")
    cal = Calibration.from_dict(json.loads(db.execute("SELECT calibration FROM runs").fetchone()[0]))
    device = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())["device"]
    dev = {k: v for k, v in device.items() if k != "driver"}
    board = SimulatedBoard.from_config(dev)
    g = np.array([[0.0, 0.0, 1.0], [0.6, -0.6, 0.52], [-1.0, 0.0, 0.0]]) * cal.input_per_g
    for temp_c, tol_mg in ((th["table"]["temps_c"][1], 0.5), (v["board_temp_c"], 2.0)):
        err = cal.apply(g, units="counts", temp_c=temp_c) - board.truth(temp_c).apply(g, units="counts")
        assert np.max(np.abs(err)) * 1e3 < tol_mg, (temp_c, err)


@pytest.mark.parametrize("faults, kind", [
    ({"min_air_c": -5}, "set point -20 C not reached"),       # refrigeration cannot go below -5 C
    ({"alarm_at_s": 1000, "alarm_code": 3}, "alarm 3 (refrigeration fault) during the soak at -20 C"),
])
def test_chamber_faults_end_in_a_recorded_fail_and_nothing_burned(tmp_path, faults, kind):
    r, out = _run(_config(tmp_path, faults=faults))
    assert r.exit_code == 1, r.output
    assert out["verdict"] == "FAIL" and kind in out["reasons"][0] and out["nvm"] is None
    (row,) = _stored(tmp_path)
    assert row[:2] == ("complete", "FAIL") and kind in row[2] and row[3] == "none"


def test_door_opened_mid_capture_fails_the_run_and_burns_nothing(tmp_path):
    _, clean = _run(_config(tmp_path, "clean.yaml"))
    visit = next(v for v in clean["thermal"]["visits"] if v["set_point_c"] == 25)
    mid = (visit["t_soaked_s"] + visit["t_end_s"]) / 2  # the same seed runs the same timeline up to here
    (tmp_path / "runs.sqlite").unlink()
    r, out = _run(_config(tmp_path, faults={"door_open_at_s": mid, "door_open_s": 20}))
    assert r.exit_code == 1
    assert "door opened during the capture" in out["reasons"][0] and "at 25 C" in out["reasons"][0]
    assert out["nvm"] is None and not out["nvm_verified"]
    (row,) = _stored(tmp_path)
    assert row[1] == "FAIL" and "door opened" in row[2] and row[3] == "none"


def test_through_the_mpu6050_bridge_and_the_chamber_on_pseudo_terminals(tmp_path):
    """Bridge emulator (pyserial on a pty) and chamber emulator (pyvisa on a pty) around one board;
    the table is burned in the bridge's 1 KiB EEPROM (a 484-byte blob in a 512-byte slot) and read back."""
    sim = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())["device"]
    dev = {"driver": "mpu6050", "port": "emulated", "seed": 15, "range_g": 2, "odr_hz": 100,
           "simulator": {"self_heating_c": 1.5, "simulator": sim["simulator"]}}
    r, out = _run(_config(tmp_path, **dev))
    assert r.exit_code == 0, r.output
    (v,) = out["thermal"]["verify"]
    assert out["verdict"] == "PASS" and out["chip"] == "mpu6050" and out["thermal"]["temp_source"] == "die"
    assert v["within_limit"] and not v["without_table_within_limit"]
    assert out["nvm_verified"] and out["nvm"]["ok"] and out["nvm"]["length"] == 484
    assert len(out["thermal"]["table"]["temps_c"]) == 3


def test_chamber_driver_over_a_pty_sets_reads_and_reports_alarms():
    clock = VirtualClock()
    emu = ChamberEmulator(ChamberPhysics(clock, start_c=25.0, air_tau_s=100.0, board_tau_s=200.0))
    port = emu.start()
    try:
        with AsciiChamber(port, timeout_s=0.5, retries=0, min_c=-40, max_c=120) as ch:
            ch.set_point(-20.0)
            assert emu.received[-2:] == ["TEMP, S-20.0", "MODE, CONSTANT"]
            clock.sleep(100.0)  # one air time constant: 63.2 % of the way
            st = ch.status()
            assert st.mode == "CONSTANT" and st.alarms == ()
            assert st.air_c == pytest.approx(25 - 45 * (1 - np.exp(-1)), abs=0.06)  # 0.1 C resolution
            emu.open_door(clock.now() + 1.0, 30.0)
            clock.sleep(2.0)
            assert ch.status().door_open
            with pytest.raises(Exception, match="out of the chamber's range"):
                ch.set_point(150.0)
            with pytest.raises(ChamberError, match="refused 'BOGUS'"):
                ch.query("BOGUS")
        emu.stop()
        with pytest.raises(ChamberError, match="cannot open|no answer"), AsciiChamber(port, timeout_s=0.1, retries=0):
            pass
    finally:
        emu.stop()


def test_chamber_physics_matches_a_fine_numerical_integration():
    clock = VirtualClock()
    ph = ChamberPhysics(clock, start_c=25.0, air_tau_s=240.0, board_tau_s=420.0)
    ph.set_point_c, ph.running = 70.0, True
    air, board, dt = 25.0, 25.0, 0.01
    for _ in range(int(900 / dt)):  # explicit Euler of the cascade, independent of the closed form
        air, board = air + dt * (70.0 - air) / 240.0, board + dt * (air - board) / 420.0
    clock.sleep(900.0)
    assert ph.air_temperature_c() == pytest.approx(air, abs=0.01)
    assert ph.board_temperature_c() == pytest.approx(board, abs=0.01)


def test_thermal_config_errors_name_the_key(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["thermal"]["set_points_c"] = [-20, 70]
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 2 and "thermal.set_points_c" in r.output and "3 or more" in r.output


def test_emulate_chamber_then_set_and_read_it_as_the_hint_says():
    import select
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "emulate", "chamber", "--speed", "1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert select.select([proc.stdout], [], [], 60.0)[0], "emulator printed nothing within 60 s"
        port = proc.stdout.readline().split()[3]
        hint = proc.stdout.readline().strip()
        assert hint == f"try: accelcal chamber set --temp-c -20 --port {port}; accelcal chamber status --port {port}"
        r = CliRunner().invoke(cli, ["chamber", "set", "--temp-c", "-20", "--port", port, "--json"])
        assert r.exit_code == 0, r.output
        first = json.loads(r.stdout)
        assert first["mode"] == "CONSTANT" and first["alarms"] == []
        import time

        time.sleep(1.5)  # 1500 s of chamber time: more than six air time constants
        r = CliRunner().invoke(cli, ["chamber", "status", "--port", port, "--json"])
        assert json.loads(r.stdout)["air_c"] == pytest.approx(-20.0, abs=0.2)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=10)
    assert proc.returncode == 0


def test_a_chamber_that_stops_answering_mid_plan_is_recorded_with_what_it_had(tmp_path):
    _, clean = _run(_config(tmp_path, "clean.yaml"))
    second = next(v for v in clean["thermal"]["visits"] if v["set_point_c"] == 25)
    (tmp_path / "runs.sqlite").unlink()
    p = _config(tmp_path, faults={"stall_at_s": second["t_start_s"] + 60})
    cfg = yaml.safe_load(p.read_text())
    cfg["chamber"].update(timeout_s=0.2, retries=1)  # a quick test: 2 attempts of 0.2 s
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 3 and "no answer to 'MON?' within 0.2 s (2 attempts)" in r.output  # one line, exit 3
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    (status, why, nvm), = db.execute("SELECT status, status_reason, nvm_status FROM runs").fetchall()
    assert status == "error" and "at set point 25 C (2/4)" in why and "8 poses captured" in why and nvm is None
    temps = [t for (t,) in db.execute("SELECT temp_c FROM poses")]
    assert len(temps) == 8 and all(abs(t - (-18.5)) < 1.0 for t in temps)  # the -20 C poses, die temperature


def test_mma8451_has_no_sensor_so_the_station_uses_the_chamber_air_and_says_so(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["chip"] = "mma8451"
    cfg["device"]["simulator"]["effects"]["noise"]["density_ug_per_rthz"] = [99.0] * 3
    cfg["thermal"]["soak"]["hold_s"] = 2400  # no die sensor: hold long enough for the lagging board (tau 420 s)
    p = tmp_path / "mma.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r, out = _run(p)
    assert r.exit_code == 0, r.output
    assert out["thermal"]["temp_source"] == "chamber_air"
    assert any("no temperature sensor" in e and "chamber air" in e for e in out["events"])
    assert out["thermal"]["table"]["temps_c"] == [-20.0, 25.0, 70.0]  # the air, 0.1 C resolution
    assert out["thermal"]["verify"][0]["within_limit"]


def test_quadratic_table_and_a_per_temperature_limit_that_fails(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["thermal"]["method"] = "quadratic"
    p = tmp_path / "q.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r, out = _run(p)
    assert r.exit_code == 0, r.output
    assert out["thermal"]["table"]["method"] == "quadratic" and out["thermal"]["table"]["verdict"] == "PASS"
    assert out["thermal"]["verify"][0]["within_limit"]
    # the board's z offset at 70 C is ~60 + 0.45 * 46 + 0.0025 * 46^2 = 86 mg: a 75 mg limit fails there only
    cfg["acceptance"]["offset_max_mg"] = 75
    p.write_text(yaml.safe_dump(cfg))
    r, out = _run(p)
    assert r.exit_code == 1 and out["nvm"] is None
    verdicts = {v["set_point_c"]: v["verdict"] for v in out["thermal"]["visits"] if v["role"] == "calibrate"}
    assert verdicts == {-20.0: "PASS", 25.0: "PASS", 70.0: "FAIL"}
    assert out["reasons"][0].startswith("at 70 C: offset_max_mg")


def test_a_chamber_without_a_thermal_plan_is_refused(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    del cfg["thermal"]
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    assert r.exit_code == 2 and "needs both thermal: and chamber:" in r.output


def test_chamber_driver_over_tcp_through_pyvisa_socket():
    """host:port opens TCPIP::host::port::SOCKET; the emulator's protocol answers on a local socket."""
    import socket
    import threading

    clock = VirtualClock()
    emu = ChamberEmulator(ChamberPhysics(clock, start_c=25.0))
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]

    def serve():
        conn, _ = srv.accept()
        with conn:
            buf = b""
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                while b"\r\n" in buf:
                    line, buf = buf.split(b"\r\n", 1)
                    conn.sendall(emu.answer(line.decode()).encode() + b"\r\n")

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        with AsciiChamber(f"127.0.0.1:{port}", timeout_s=2.0) as ch:
            assert ch.resource_name == f"TCPIP::127.0.0.1::{port}::SOCKET"
            ch.set_point(70.0)
            clock.sleep(3000.0)
            assert ch.status().air_c == pytest.approx(70.0, abs=0.1)
    finally:
        srv.close()


def test_chamber_driver_never_imports_its_emulator():
    import ast

    src = (Path(__file__).resolve().parents[1] / "accelcal_station" / "instruments" / "chamber.py").read_text()
    names = {a.name for n in ast.walk(ast.parse(src)) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module or "" for n in ast.walk(ast.parse(src)) if isinstance(n, ast.ImportFrom)}
    assert not any("emulator" in n for n in names), names


def test_the_hardware_thermal_config_is_valid():
    from accelcal_station.station.settings import StationConfig
    from accelcal_station.station.thermal_plan import ThermalPlan

    cfg = StationConfig.load(CONFIGS / "thermal-mpu6050.yaml")
    assert cfg.schema.thermal is not None and cfg.schema.chamber is not None
    plan = ThermalPlan.from_section(cfg.schema.thermal, cfg.model)
    assert plan.visits() == [(-20.0, "calibrate"), (25.0, "calibrate"), (45.0, "verify"), (70.0, "calibrate")]
    ch = make_chamber(cfg.schema.chamber)  # every key known, port and limits accepted: a real chamber
    assert isinstance(ch, AsciiChamber) and (ch.port, ch.visa_library, ch.min_c, ch.max_c) == (
        "/dev/ttyUSB2", "@py", -40, 85)



def test_a_run_stopped_mid_capture_keeps_the_poses_of_that_set_point_it_had(tmp_path):
    _, clean = _run(_config(tmp_path, "clean.yaml"))
    second = next(v for v in clean["thermal"]["visits"] if v["set_point_c"] == 25)
    (tmp_path / "runs.sqlite").unlink()
    p = _config(tmp_path, faults={"stall_at_s": (second["t_soaked_s"] + second["t_end_s"]) / 2})
    cfg = yaml.safe_load(p.read_text())
    cfg["chamber"].update(timeout_s=0.2, retries=0)
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 3
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    names = [n for (n,) in db.execute("SELECT name FROM poses")]
    at25 = [n for n in names if n.endswith("@25C")]
    assert len(names) - len(at25) == 8 and 0 < len(at25) < 8  # all of -20 C, part of 25 C

"""`accelcal run --shift` (issue 36): one station process calibrates board after board, each started by
its scanned serial, through the real CLI in a subprocess; a device whose port vanishes between boards
(a USB serial adapter unplugged: its /dev node goes away) is waited for, not a crash."""
from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml

from accelcal_station.station.shift import ShiftTally, summary_lines

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
ENTERS = "\n" * 8  # the emulated MMA8451's operator jig: 6 poses and 2 verification poses, Enter at each


def _accelcal(*args: str, stdin: str, cwd: Path, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "accelcal_station", *args], input=stdin, capture_output=True,
                          text=True, timeout=timeout, cwd=cwd)


def _runs(store: Path) -> list[tuple[str, str, str]]:
    db = sqlite3.connect(store)
    try:
        return db.execute("SELECT device_serial, status, verdict FROM runs ORDER BY id").fetchall()
    finally:
        db.close()


def test_a_shift_of_two_boards_in_the_terminal(tmp_path):
    cfg = str(CONFIGS / "mma8451-emulated.yaml")
    # a scanner types the serial and Enter; stray Enters between boards are ignored
    feed = "SN-A\n" + ENTERS + "\n\n" + "SN-B\n" + ENTERS
    r = _accelcal("run", "--shift", "--config", cfg, "--store", "s.sqlite", stdin=feed, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr + r.stdout
    assert _runs(tmp_path / "s.sqlite") == [("SN-A", "complete", "PASS"), ("SN-B", "complete", "PASS")]
    assert "PASS board SN-A" in r.stdout and "PASS board SN-B" in r.stdout
    assert "boards 2 (2 serials): PASS 2, FAIL 0" in r.stdout and "first-pass yield 100.0 %" in r.stdout
    # the blank lines only asked again (no refusal); the prompt for board 3 met end of input
    assert "Board 3: scan the serial number" in r.stderr and "Board 4" not in r.stderr
    assert "is not a serial number" not in r.stderr


def test_a_shift_under_json_prints_one_object_per_board_and_one_for_the_shift(tmp_path):
    cfg = str(CONFIGS / "mma8451-emulated.yaml")
    # SN-A is aborted at its first pose, scanned again and passes: a retest (first-pass yield 1 of 2);
    # a bad scan is said and asked again
    feed = "SN-A\na\n" + "bad serial!\n" + "SN-A\n" + ENTERS + "SN-B\n" + ENTERS
    r = _accelcal("run", "--shift", "--json", "--config", cfg, "--store", "s.sqlite", stdin=feed, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    objs = [json.loads(line) for line in r.stdout.splitlines()]  # every stdout line is one JSON object
    assert [(o["kind"], o.get("serial"), o.get("verdict")) for o in objs] == [
        ("board", "SN-A", "ABORTED"), ("board", "SN-A", "PASS"), ("board", "SN-B", "PASS"),
        ("shift", None, None)]
    shift = objs[-1]
    assert (shift["boards"], shift["serials"], shift["pass"], shift["fail"], shift["aborted"]) == (3, 2, 2, 0, 1)
    assert shift["first_pass_yield"] == 0.5 and shift["reasons_by_code"] == {"aborted": 1}
    assert objs[1]["retest"] is True and objs[2]["retest"] is False
    assert "is not a serial number" in r.stderr
    runs = _runs(tmp_path / "s.sqlite")
    assert [(s, st) for s, st, _ in runs] == [("SN-A", "interrupted"), ("SN-A", "complete"), ("SN-B", "complete")]
    assert [o["run_id"] for o in objs[:3]] == [1, 2, 3]


def test_a_shift_refuses_a_serial_option_and_a_panel(tmp_path):
    r = _accelcal("run", "--shift", "--serial", "X1", "--config", str(CONFIGS / "mma8451-emulated.yaml"),
                  "--store", "s.sqlite", stdin="", cwd=tmp_path)
    assert r.returncode == 2 and "--serial" in r.stderr and "Traceback" not in r.stderr


def test_the_tally_counts_first_passes_by_serial():
    """First-pass yield by hand: A fails then passes on retest, B passes, C fails: 1 first pass of 3 serials."""
    t = ShiftTally("st1")
    t.add("A", 1, "FAIL", [("offset_max_mg", "offset_max_mg 200 > limit 150")])
    t.add("B", 2, "PASS", [])
    t.add("A", 3, "PASS", [])
    t.add("C", 4, "FAIL", [("offset_max_mg", "x"), ("residual_rms_mg", "y")])
    s = t.summary()
    assert (s["boards"], s["serials"], s["pass"], s["fail"]) == (4, 3, 2, 2)
    assert abs(s["first_pass_yield"] - 1 / 3) < 1e-12
    assert s["reasons_by_code"] == {"offset_max_mg": 2, "residual_rms_mg": 1}
    assert "first-pass yield 33.3 %" in "\n".join(summary_lines(s))


def _mpu_rig(tmp_path: Path):
    """The MPU6050 bridge and motorized jig emulators on ptys (as tests/test_port_faults.py), the bridge
    reached through a symlink that stands for the adapter's /dev node."""
    from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
    from accelcal_station.drivers.simulated import SimulatedBoard
    from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    board = SimulatedBoard.from_config(sim, chip="mpu6050", seed=3)
    bridge = MPU6050BridgeEmulator(board)
    pty = bridge.start()
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=board, board_lock=bridge.lock)
    jig.start()
    node = tmp_path / "ttyACM0"
    node.symlink_to(pty)
    cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)
    p = tmp_path / "mpu.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return bridge, jig, node, pty, p


def test_a_device_unplugged_between_boards_is_waited_for(tmp_path):
    bridge, jig, node, pty, cfg = _mpu_rig(tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "run", "--shift", "--json", "--config",
                             str(cfg), "--port", str(node), "--jig-port", jig.port, "--device-wait", "60"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(iter(proc.stderr.readline, "")), daemon=True)
    reader.start()
    try:
        proc.stdin.write("SN-1\n")
        proc.stdin.flush()
        first = json.loads(proc.stdout.readline())
        assert first["serial"] == "SN-1" and first["verdict"] == "PASS", first
        node.unlink()  # unplugged between boards
        proc.stdin.write("SN-2\n")
        proc.stdin.flush()
        t0 = time.monotonic()
        while not any("waiting up to 60 s" in e for e in err):
            assert time.monotonic() - t0 < 30 and proc.poll() is None, "".join(err)[-2000:]
            time.sleep(0.1)
        time.sleep(1.5)  # gone for a while: the station keeps waiting
        assert proc.poll() is None
        node.symlink_to(pty)  # plugged back in
        second = json.loads(proc.stdout.readline())
        proc.stdin.close()
        shift = json.loads(proc.stdout.readline())
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        jig.stop()
        bridge.stop()
    text = "".join(err)
    assert proc.returncode == 0, text[-2000:]
    assert second["serial"] == "SN-2" and second["verdict"] == "PASS"
    assert shift["boards"] == 2 and shift["pass"] == 2 and "Traceback" not in text
    gone = [e for e in err if "device not answering" in e]
    assert len(gone) == 1 and "device back after" in text  # one line, not one per retry
    assert _runs(tmp_path / "runs.sqlite") == [("SN-1", "complete", "PASS"), ("SN-2", "complete", "PASS")]


def test_a_device_that_stays_away_ends_the_shift_with_its_summary(tmp_path):
    bridge, jig, node, pty, cfg = _mpu_rig(tmp_path)
    node.unlink()
    try:
        r = _accelcal("run", "--shift", "--config", str(cfg), "--port", str(node), "--jig-port", jig.port,
                      "--device-wait", "2", stdin="SN-1\n", cwd=tmp_path)
    finally:
        jig.stop()
        bridge.stop()
    assert r.returncode == 3, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "device still not answering after 2 s" in r.stderr
    assert "boards 0 (0 serials)" in r.stdout and "ended by device gone" in r.stdout
    assert not os.path.exists(tmp_path / "runs.sqlite") or _runs(tmp_path / "runs.sqlite") == []

"""`accelcal emulate mpu6050-bridge` as a new user runs it, and `accelcal probe` on its port."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator

REPO = Path(__file__).resolve().parents[1]
CONFIG = str(REPO / "configs" / "mpu6050.yaml")


def start_emulator(*args: str) -> tuple[subprocess.Popen, str]:
    """Run `accelcal emulate mpu6050-bridge ARGS` and return it with its first stdout line."""
    proc = subprocess.Popen([sys.executable, "-m", "accelcal_station", "emulate", "mpu6050-bridge", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    ready, _, _ = select.select([proc.stdout], [], [], 60.0)
    if not ready:
        proc.kill()
        pytest.fail("emulator printed nothing within 60 s")
    return proc, proc.stdout.readline()


def stop(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("emulator did not exit within 10 s of the signal")
    return proc.returncode, err


def test_emulate_then_probe_end_to_end():
    proc, line = start_emulator("--seed", "5")
    try:
        assert line.startswith("MPU6050 bridge emulator on /dev/")
        port = line.split()[4]
        hint = proc.stdout.readline()
        assert hint.strip() == f"try: accelcal probe --config configs/mpu6050.yaml --port {port}"
        # in-process, JSON
        r = CliRunner().invoke(cli, ["probe", "--config", CONFIG, "--port", port, "--json", "--samples", "200"])
        assert r.exit_code == 0, r.output
        out = json.loads(r.output)
        assert out["chip"] == "mpu6050" and out["chip_id"] == 0x68 and out["interface"] == f"serial:{port}"
        assert out["counts_per_g"] == 16384 and out["odr_hz"] == 100
        assert out["temperature_c"] == pytest.approx(25.0, abs=0.01)
        for rd in out["readings"]:
            # ideal default chip, flat: 1 g on z; SEM 45/sqrt(200) counts = 2e-4 g, tolerance 10 SEM
            assert rd["n"] == 200 and rd["dropped"] == 0
            assert rd["mean_g"][2] == pytest.approx(1.0, abs=2e-3) and abs(rd["mean_g"][0]) < 2e-3
        # as a user types it, in a second process, on the same emulator
        p = subprocess.run([sys.executable, "-m", "accelcal_station", "probe", "--config", "configs/mpu6050.yaml",
                            "--port", port], capture_output=True, text=True, cwd=REPO, timeout=120)
        assert p.returncode == 0, p.stderr
        assert "mpu6050 (chip id 0x68)" in p.stdout and "temperature  25.00 C" in p.stdout
    finally:
        code, err = stop(proc, signal.SIGINT)
    assert code == 0 and "emulator stopped" in err and "Traceback" not in err


def test_emulate_json_with_board_config_and_sigterm():
    proc, line = start_emulator("--config", "configs/sim.yaml", "--seed", "9", "--json")
    try:
        info = json.loads(line)
        assert info["emulator"] == "mpu6050-bridge" and info["seed"] == 9 and info["port"].startswith("/dev/")
        r = CliRunner().invoke(cli, ["probe", "--config", CONFIG, "--port", info["port"], "--json",
                                     "--readings", "1", "--samples", "400"])
        assert r.exit_code == 0, r.output
        z = json.loads(r.output)["readings"][0]["mean_g"][2]
        # configs/sim.yaml's board: +41 mg z offset, z gain 1.021 (cross-axis < 1 %): z reads ~1.06 g
        assert z == pytest.approx(1.021 + 0.041, abs=0.01)
    finally:
        code, err = stop(proc, signal.SIGTERM)
    assert code == 0 and "Traceback" not in err


def test_emulate_rejects_a_hardware_config():
    r = CliRunner().invoke(cli, ["emulate", "mpu6050-bridge", "--config", str(REPO / "configs" / "mma8451.yaml")])
    assert r.exit_code == 2
    assert r.output.count("\n") == 1 and r.output.startswith("error: ") and "driver: simulated" in r.output
    r = CliRunner().invoke(cli, ["emulate", "mma8451-bridge"])
    assert r.exit_code == 2 and "mpu6050-bridge" in r.output


@pytest.mark.parametrize("port,text", [
    ("/dev/ttyUSB97", "serial port /dev/ttyUSB97 does not exist"),
    # mode 0444 /proc/sys file: EACCES on O_RDWR even for root, as a dialout tty for a non-member
    ("/proc/sys/kernel/osrelease", "dialout group"),
])
def test_probe_port_errors_are_one_line(port, text):
    r = CliRunner().invoke(cli, ["probe", "--config", CONFIG, "--port", port])
    assert r.exit_code == 3
    assert r.output.count("\n") == 1 and r.output.startswith("error: ") and text in r.output


def test_probe_wrong_chip_and_no_answer(tmp_path):
    with MPU6050BridgeEmulator(seed=1, who_am_i=0x71) as emu:
        r = CliRunner().invoke(cli, ["probe", "--config", CONFIG, "--port", emu.port])
    assert r.exit_code == 3 and r.output.count("\n") == 1
    assert "WHO_AM_I (0x75) reads 0x71 (MPU-9250" in r.output  # named by its value (drivers/mpu6050_parts.py)

    cfg = tmp_path / "quick.yaml"  # short timeouts so the silent port fails fast
    cfg.write_text("device: {driver: mpu6050, port: /dev/null, timeout_s: 0.1, retries: 1, boot_wait_s: 0.2}\n")
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        t0 = time.monotonic()
        r = CliRunner().invoke(cli, ["probe", "--config", str(cfg), "--port", os.ttyname(slave)])
        assert time.monotonic() - t0 < 3.0
    finally:
        os.close(master)
        os.close(slave)
    assert r.exit_code == 3 and r.output.count("\n") == 1 and "no answer" in r.output

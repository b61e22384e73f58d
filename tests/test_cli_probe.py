"""`accelcal probe` through the CLI, on the emulated MMA8451 and the simulated board."""
from __future__ import annotations

import errno
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import smbus2
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli

REPO = Path(__file__).resolve().parents[1]
EMULATED = REPO / "configs" / "mma8451-emulated.yaml"
REAL = REPO / "configs" / "mma8451.yaml"


def probe(*args):
    return CliRunner().invoke(cli, ["probe", *map(str, args)])


def station_config(tmp_path, device: dict, name: str = "station.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump({"device": device, "plan": {"design": "six-face"}}))
    return p


def one_error_line(r) -> str:
    assert r.exit_code != 0 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr
    return lines[0]


def test_probe_emulated_text():
    r = probe("--config", EMULATED)
    assert r.exit_code == 0, r.output
    out = r.stdout
    assert "mma8451 (chip id 0x1A) on i2c:emulated@0x1d, serial EMU-0001" in out
    assert "+-2 g, 4096 counts/g" in out and "100 Hz" in out and "high_resolution" in out
    assert "temperature  none: chip has no sensor" in out
    assert "24Cxx at 0x50, 4096 bytes, 32-byte pages" in out
    rows = [line for line in out.splitlines() if line.strip()[:2].strip().isdigit()]
    assert len(rows) == 3


def test_probe_emulated_json_matches_the_simulated_board():
    r = probe("--config", EMULATED, "--json", "--readings", "2", "--samples", "100")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert (d["chip"], d["chip_id"], d["counts_per_g"], d["range_g"], d["odr_hz"]) == ("mma8451", 0x1A, 4096, 2, 100)
    assert d["temperature_c"] is None and len(d["readings"]) == 2
    for rd in d["readings"]:
        assert rd["n"] == 100 and rd["dropped"] == 0 and rd["t_end"] > rd["t_start"]
        # the config's board: offset (12, -8, 25) mg, gains (1.004, 0.997, 1.006), small cross-axis terms;
        # flat, expected (0.012 - 0.001 * 1.004, -0.008 + 0.003 * 0.997, 1.006 + 0.025) g within 1 mg (SEM ~0.07 mg)
        np.testing.assert_allclose(rd["mean_g"], [0.012 - 0.001 * 1.004, -0.008 + 0.003 * 0.997, 1.031], atol=1e-3)
        # noise (data sheet): 99 ug/sqrt(Hz) * sqrt(50 Hz) = 0.70 mg = 2.87 counts at the normal mode's
        # oversampling (4 at 100 Hz); the config's high-resolution mode averages 16: 2.87 * sqrt(4/16) = 1.43
        assert all(1.0 < s < 2.0 for s in rd["std_counts"])


def test_probe_as_a_new_user_runs_it():
    r = subprocess.run([sys.executable, "-m", "accelcal_station", "probe", "--config", "configs/mma8451-emulated.yaml"],
                       cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "chip has no sensor" in r.stdout and r.stderr == ""


def test_probe_simulated_driver_and_bare_device_section(tmp_path):
    p = tmp_path / "dev.yaml"
    p.write_text("driver: simulated\nchip: mma8451\nseed: 3\n")
    d = json.loads(probe("--config", p, "--json").stdout)
    assert d["chip"] == "mma8451" and d["interface"] == "simulated" and d["temperature_c"] is None


@pytest.mark.parametrize("emulator, expected", [
    ({"chip_id": 0x2A}, "error: found chip id 0x2a (MMA8452Q) at bus emulated address 0x1d: not an MMA8451 "
                        "(expects WHO_AM_I 0x1A)"),
    ({"present": False}, "error: read i2c bus emulated address 0x1d register 0x0D (WHO_AM_I) failed after 4 attempts"),
    ({"never_ready": True}, "error: i2c bus emulated address 0x1d register 0x00 (STATUS): no data ready (ZYXDR)"),
])
def test_probe_device_faults_are_one_line(tmp_path, emulator, expected):
    cfg = station_config(tmp_path, {"driver": "mma8451", "bus": "emulated", "emulator": emulator})
    r = probe("--config", cfg)
    assert one_error_line(r).startswith(expected)
    assert r.exit_code == 3


def test_probe_no_such_bus_and_port_override(tmp_path):
    line = one_error_line(probe("--config", REAL))
    assert line.startswith("error: i2c bus 1: /dev/i2c-1 does not exist")
    line = one_error_line(probe("--config", REAL, "--port", "7"))
    assert "/dev/i2c-7 does not exist" in line


def test_probe_permission_denied(monkeypatch):
    def denied(bus):  # smbus2.SMBus for a user outside the i2c group (the tests run as root)
        raise PermissionError(errno.EACCES, "Permission denied", f"/dev/i2c-{bus}")
    monkeypatch.setattr(smbus2, "SMBus", denied)
    line = one_error_line(probe("--config", REAL))
    assert "permission denied on /dev/i2c-1; add the user to the i2c group" in line


def test_probe_config_errors(tmp_path):
    assert "cannot read" in one_error_line(probe("--config", tmp_path / "missing.yaml"))
    p = tmp_path / "nodevice.yaml"
    p.write_text("plan: {design: six-face}\n")
    assert "no 'device' section" in one_error_line(probe("--config", p))
    cfg = station_config(tmp_path, {"driver": "mma8451", "bus": "emulated", "range_g": 16})
    assert one_error_line(probe("--config", cfg)) == "error: device.range_g: 16; allowed: 2, 4, 8"
    cfg = station_config(tmp_path, {"driver": "simulated"}, "sim.yaml")
    assert "simulated driver has no port" in one_error_line(probe("--config", cfg, "--port", "/dev/ttyUSB0"))

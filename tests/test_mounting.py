"""device.mount: a chip turned on its board (or a board turned in its jig) is found, named, and fixed
by one config line; the boards here are emulated with the chip really turned (true_mount)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.conventions import all_mounts, fit_mount, mount_hint, mount_label, mount_matrix
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.errors import ConfigError
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
TURNED = ["y", "-x", "z"]
HINT = "set device.mount: [y, -x, z]"


def test_the_24_mountings_are_the_proper_rotations_and_round_trip():
    mounts = all_mounts()
    assert len(mounts) == 24 and len({m.tobytes() for m in mounts}) == 24
    for m in mounts:
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=0)
        assert np.linalg.det(m) == pytest.approx(1.0)
        np.testing.assert_array_equal(mount_matrix(mount_label(m)), m)
    # [y, -x, z]: the board's +x is read by the chip's +y, the board's +y by the chip's -x
    np.testing.assert_array_equal(mount_matrix(TURNED) @ [1, 0, 0], [0, 1, 0])
    np.testing.assert_array_equal(mount_matrix(TURNED) @ [0, 1, 0], [-1, 0, 0])
    for bad in (["y", "x", "z"], ["x", "x", "z"], ["x", "y"], ["q", "y", "z"], ["--x", "y", "z"]):
        with pytest.raises(ValueError):
            mount_matrix(bad)


def test_two_poses_single_out_a_mounting_and_one_names_the_smallest_turn():
    P = mount_matrix(TURNED)
    one = mount_hint([[1, 0, 0]], [P @ [1, 0, 0]])
    assert one.startswith("reads +y where the pose expects +x: the board looks turned 90 deg about z") and HINT in one
    r = np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]])
    for true in all_mounts():  # every mounting is found from three faces
        best, worst, unique = fit_mount(r, r @ true.T)
        np.testing.assert_array_equal(best, true)
        assert worst < 1e-6 and unique
    assert mount_hint(r, r, np.eye(3)) is None  # the configured mounting fits: nothing to say


def _run(cfg: dict, tmp_path: Path, *extra: str, stdin: str | None = None):
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return CliRunner().invoke(cli, ["run", "--config", str(p), *extra], input=stdin)


def test_simulated_board_turned_is_named_then_passes_with_mount(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["true_mount"] = TURNED
    r = _run(cfg, tmp_path, "--json")
    out = json.loads(r.stdout)
    assert out["verdict"] != "PASS" and HINT in r.stdout, r.output
    assert "the board looks turned 90 deg about z" in r.stdout
    cfg["device"]["mount"] = TURNED
    r = _run(cfg, tmp_path, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["verdict"] == "PASS"


def test_emulated_mma8451_with_operator_named_then_passes_with_mount(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = yaml.safe_load((CONFIGS / "mma8451-emulated.yaml").read_text())
    cfg["device"]["simulator"]["true_mount"] = TURNED
    r = _run(cfg, tmp_path, stdin="\n" * 8)
    assert r.exit_code != 0 and HINT in r.output and "PASS" not in r.output
    cfg["device"]["mount"] = TURNED
    r = _run(cfg, tmp_path, stdin="\n" * 8)
    assert r.exit_code == 0 and "PASS board EMU-0001" in r.output, r.output


@pytest.mark.parametrize("configured", [None, TURNED])
def test_mpu6050_bridge_on_motorized_jig_turned(tmp_path, configured):
    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    board = SimulatedBoard.from_config({**sim, "true_mount": TURNED}, chip="mpu6050", seed=3)
    bridge = MPU6050BridgeEmulator(board)
    port = bridge.start()
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=board, board_lock=bridge.lock)
    jig.start()
    try:
        cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
        cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
        cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)
        if configured:
            cfg["device"]["mount"] = configured
        r = _run(cfg, tmp_path, "--port", port, "--jig-port", jig.port, "--json")
        out = json.loads(r.stdout)
        if configured:
            assert r.exit_code == 0 and out["verdict"] == "PASS", r.output
        else:
            assert out["verdict"] != "PASS" and HINT in r.stdout, r.output
    finally:
        jig.stop()
        bridge.stop()


def test_a_mirror_mounting_is_one_config_line(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    cfg["device"]["mount"] = ["y", "x", "z"]
    r = _run(cfg, tmp_path)
    assert r.exit_code == 2 and "device.mount" in r.output and "proper rotation" in r.output
    assert "Traceback" not in r.output
    with pytest.raises(ConfigError, match="true_mount"):
        SimulatedBoard.from_config({"true_mount": ["x", "y", "-z"]})


def test_thermal_plan_reads_on_until_the_mounting_is_singled_out(tmp_path):
    """One cube-vertex pose fits three mountings (turns about its diagonal): the plan reads the
    next pose before naming one, and names the true one."""
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["true_mount"] = ["z", "x", "y"]
    r = _run(cfg, tmp_path)
    assert r.exit_code != 0 and "set device.mount: [z, x, y]" in r.output, r.output
    cfg["device"]["mount"] = ["z", "x", "y"]
    r = _run(cfg, tmp_path)
    assert r.exit_code == 0 and "PASS board" in r.output, r.output


def test_one_place_turns_a_mount_into_a_matrix_and_one_writes_it():
    """Issue 52: ``device.mount`` (a panel board's ``mount``, ``true_mount``) becomes a matrix only in
    config/kinds.py ``mount_p`` (through conventions.mount_matrix) and is written as text only by
    conventions.mount_label: no module parses or spells a mounting on its own."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    files = [f for d in ("accelcal_station", "drivers", "fixtures") for f in sorted((root / d).rglob("*.py"))]
    assert len(files) > 50  # the scan itself sees the package
    calls = {name: sorted(f"{f.relative_to(root)}" for f in files
                          if re.search(rf"(?<!def ){name}\(", f.read_text()))
             for name in ("mount_matrix", "mount_label")}
    assert calls["mount_matrix"] == ["accelcal_station/config/kinds.py"], calls
    assert set(calls["mount_label"]) <= {"accelcal_station/config/kinds.py", "accelcal_station/conventions.py"}, calls
    # the matrix comes from mount_p: no module builds one from the section's list itself
    direct = [f"{f.relative_to(root)}" for f in files
              if re.search(r"np\.array\([^)]*\.mount\b|mount_matrix\([^)]*\.mount\b", f.read_text())]
    assert not direct, direct

"""The station end to end on the simulated board: the issue's done-when items."""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.drivers.factory import make_driver
from accelcal_station.nvm.writer import CalibrationWriter
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig


def sim_config(tmp_path, **changes) -> str:
    """The default station config with sections replaced, written to tmp_path."""
    cfg = yaml.safe_load(default_config_path().read_text())
    for key, value in changes.items():
        section, _, sub = key.partition("__")
        if sub:
            cfg.setdefault(section, {})[sub] = value
        else:
            cfg[section] = value
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["seed"] = 7  # reproducible boards: the scripted bump lands inside the averaging
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def test_default_run_passes_and_leaves_verified_nvm_and_a_record(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, ["run", "--json", "--operator", "ci"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["verdict"] == "PASS" and out["nvm"]["ok"] and out["nvm_verified"]
    assert out["verify_error_max_mg"] < 2.0
    db = sqlite3.connect(tmp_path / "accelcal-runs.sqlite")
    status, verdict, nvm = db.execute("SELECT status, verdict, nvm_status FROM runs").fetchone()
    assert (status, verdict, nvm) == ("complete", "PASS", "written")
    assert db.execute("SELECT count(*) FROM poses").fetchone()[0] == 8


def test_station_burns_the_fitted_calibration_into_the_board(tmp_path):
    cfg = StationConfig.load(sim_config(tmp_path))
    st = make_flow(cfg, echo=lambda s: None)
    (rep,) = st.run()
    assert rep.verdict == "PASS"
    cal, header, slot = CalibrationWriter(st.boards[0].driver.nvm).read_newest(rep.serial)
    np.testing.assert_array_equal(cal.W, rep.fit.W)
    assert header.station_id == "sim-station-1" and slot == "A"
    # the fit recovers the simulator's truth at mg level (the design's predicted error is ~0.05 mg)
    truth = st.boards[0].driver.board.truth()
    g = np.array([[0.3, -0.5, 0.81], [1.0, 0.0, 0.0]]) * 4096
    np.testing.assert_allclose(cal.apply(g, units="counts"), truth.apply(g, units="counts"), atol=1e-3)


def test_board_beyond_limits_fails_with_reasons_and_nvm_untouched(tmp_path):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["device"]["simulator"]["effects"]["offset"]["offset_mg"] = [180.0, -27.0, 41.0]
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(cfg))
    st = make_flow(StationConfig.load(p), echo=lambda s: None)
    (rep,) = st.run()
    assert rep.verdict == "FAIL"
    # |V| = 180 mg / gain
    assert any(r.startswith("offset_max_mg 17") and "> limit 120" in r for r in rep.reasons), rep.reasons
    assert rep.nvm is None
    assert set(st.boards[0].driver.nvm.read(0, st.boards[0].driver.nvm.size)) == {0xFF}  # never written
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    assert r.exit_code == 1 and "FAIL" in r.output and "offset_max_mg" in r.output


def test_power_loss_between_page_writes_keeps_the_previous_calibration(tmp_path):
    cfg = StationConfig.load(sim_config(tmp_path))
    driver = make_driver(cfg.device)
    first = make_flow(cfg, echo=lambda s: None, driver=driver).run()[0]
    assert first.verdict == "PASS"
    driver.board.eeprom.inject_power_loss(at_write=2, fail_bytes=10)  # dies inside the 2nd page write
    second = make_flow(cfg, echo=lambda s: None, driver=driver).run()[0]
    assert second.verdict == "FAIL" and second.nvm is not None and not second.nvm["ok"]
    assert any("untouched" in r for r in second.reasons), second.reasons
    cal, header, _ = CalibrationWriter(driver.nvm).read_newest(first.serial)
    assert header.generation == 1
    np.testing.assert_array_equal(cal.W, first.fit.W)
    # a corrupted newest slot is detected by its CRC and ignored
    third = make_flow(cfg, echo=lambda s: None, driver=driver).run()[0]
    assert third.verdict == "PASS" and third.nvm["generation"] == 2
    w = CalibrationWriter(driver.nvm)
    addr = w.slot_addr(1) + 40
    driver.nvm.write(addr, bytes([driver.nvm.read(addr, 1)[0] ^ 0xFF]))
    cal, header, slot = w.read_newest(first.serial)
    assert header.generation == 1 and slot == "A"
    assert [s.state for s in w.status()] == ["valid", "corrupt"]


# the bump comes 1.5 s after the board is placed: after ~0.6 s of live checks and the 0.3 s
# hold, inside the ~2 s of averaging
OPERATOR_JIG = {"type": "operator", "hand": {"wrong_face": ["p2"], "bump": ["p3"], "bump_after_s": 1.5}}


def test_operator_flow_through_the_command_line(tmp_path):
    path = sim_config(tmp_path, jig=OPERATOR_JIG)
    # pose 1: accept; pose 2 is on the wrong face: Enter is refused, r re-places it, Enter;
    # poses 3-8 and the 3 verification poses: accept
    answers = "\n" + "\n" + "r\n" + "\n" + "\n" * 6 + "\n" * 3
    r = CliRunner().invoke(cli, ["run", "--config", path, "--operator", "ana"], input=answers)
    assert r.exit_code == 0, r.output
    out = r.output
    assert "put the board" in out and "pitch" in out
    # the wrong face is refused, naming the face the board is actually on
    assert "WRONG FACE: board is on 'z- down" in out or "WRONG FACE: board is on '" in out
    wrong = out.split("WRONG FACE: board is on '")[1].split("'")[0]
    assert wrong and "not accepted" in out
    # the bumped board's capture is discarded and re-captured
    assert "moved during capture" in out
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    retries = dict(db.execute("SELECT name, retries FROM poses"))
    assert retries["p3"] >= 1 and retries["p1"] == 0
    assert db.execute("SELECT operator, verdict FROM runs").fetchone() == ("ana", "PASS")


def test_wrong_face_message_names_the_actual_face(tmp_path):
    path = sim_config(tmp_path, jig={"type": "operator", "hand": {"wrong_face": ["p1"]}})
    r = CliRunner().invoke(cli, ["run", "--config", path], input="\na\n")
    assert r.exit_code == 5
    face_line = [ln for ln in r.output.splitlines() if "WRONG FACE" in ln][0]
    # p1 expects about (+0.57, -0.58, +0.58) g; the hand turned it a quarter turn about x
    assert "board is on '" in face_line and "deg off" in face_line


def test_operator_abort_is_recorded_as_interrupted(tmp_path):
    path = sim_config(tmp_path, jig={"type": "operator", "hand": {}})
    r = CliRunner().invoke(cli, ["run", "--config", path], input="\n\na\n")
    assert r.exit_code == 5 and "operator aborted at pose p3" in r.output
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    status, reason = db.execute("SELECT status, status_reason FROM runs").fetchone()
    assert status == "interrupted" and "aborted" in reason
    assert db.execute("SELECT count(*) FROM poses").fetchone()[0] == 2


@pytest.mark.parametrize("changes,message", [
    ({"plan__design": "an4399-99"}, "unknown design"),
    ({"plan__model": 7}, "plan.model: 7; allowed: 6, 9, 12, 15"),
    ({"jig": {"type": "robot"}}, "jig.type: 'robot'; allowed: simulated, operator, motorized"),
    ({"capture__hold_sec": 1}, "capture.hold_sec: unknown key"),
    ({"acceptance__residual_rms_mg": -1}, "acceptance.residual_rms_mg: -1 out of range"),
    # the default acceptance limits the verification error: with no verification it would never be judged
    ({"verify__poses": 0}, "acceptance.verify_error_max_mg: needs verification captures (verify.poses: 0)"),
])
def test_config_errors_name_the_key(tmp_path, changes, message):
    r = CliRunner().invoke(cli, ["run", "--config", sim_config(tmp_path, **changes)])
    assert r.exit_code == 2
    assert message in r.stderr and r.stderr.count("\n") == 1 and "Traceback" not in r.output


def test_a_long_capture_shows_a_progress_bar_and_a_virtual_one_does_not(capsys):
    from accelcal_station.cli.operator_terminal import CaptureProgress
    from accelcal_station.drivers.simulated import SimulatedBoard, SimulatedDriver
    from accelcal_station.station.capture import CaptureSettings, gated_capture

    settings = CaptureSettings(target_sem_mg=0.12, hold_s=0.1, min_samples=32)
    for realtime in (True, False):
        board = SimulatedBoard.from_config({"realtime": realtime, "effects": {"noise": {}, "quantization": {}}},
                                           seed=1)
        with SimulatedDriver(board) as drv:
            bar = CaptureProgress(f"capturing realtime={realtime}", after_s=0.2)
            gc = gated_capture(drv, settings, None, progress=bar)
            bar.close()
        assert gc.reached_target
    err = capsys.readouterr().err
    assert "capturing realtime=True" in err and "capturing realtime=False" not in err


def test_a_binary_config_is_one_line(tmp_path):
    p = tmp_path / "garbage.yaml"
    p.write_bytes(bytes(range(128, 256)))
    r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    assert r.exit_code == 2 and r.stderr == f"error: {p}: not a text file (expected a YAML configuration)\n"


def test_non_finite_config_numbers_are_one_line(tmp_path):
    for value, key in ((float("inf"), "verify__poses"), (float("nan"), "capture__max_s")):
        p = sim_config(tmp_path, **{key: value})  # YAML .inf / .nan
        section, sub = key.split("__")
        assert (".inf" if value > 0 else ".nan") in Path(p).read_text()
        r = CliRunner().invoke(cli, ["run", "--config", p])
        assert r.exit_code == 2 and f"{section}.{sub}:" in r.stderr and "not a finite number" in r.stderr, r.output


def test_a_simulated_board_kept_between_commands(tmp_path, monkeypatch):
    """With device.seed and device.eeprom.image the simulated board survives between commands,
    so `accelcal nvm read` shows what `accelcal run` burned."""
    monkeypatch.chdir(tmp_path)
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["device"]["seed"] = 11
    cfg["device"]["eeprom"]["image"] = "board.eeprom"
    cfg["store"] = {"path": "runs.sqlite"}
    (tmp_path / "kept.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", "kept.yaml", "--json"])
    assert r.exit_code == 0, r.output
    burned = json.loads(r.stdout)
    assert (tmp_path / "board.eeprom").stat().st_size == 4096
    r = CliRunner().invoke(cli, ["nvm", "read", "--config", "kept.yaml", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert json.dumps(doc).count(burned["serial"]) >= 1
    assert str(burned["W"][0][0])[:8] in json.dumps(doc)
    (tmp_path / "board.eeprom").write_bytes(b"\xff" * 100)
    r = CliRunner().invoke(cli, ["nvm", "read", "--config", "kept.yaml"])
    assert r.exit_code != 0 and "EEPROM image is 100 bytes; this EEPROM has 4096" in r.stderr

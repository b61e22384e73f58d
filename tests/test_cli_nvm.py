"""`accelcal nvm read|backup|restore|erase` through the CLI on the emulated MMA8451 and the simulated board.

A board's NVM lives in its process, so the round trips run the CLI on one in-process
device (``obj={"driver": drv}``, a real driver built from a config by make_driver);
restoring onto a fresh board through ``--config`` shows the cross-process path.
"""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.config.schema import validate_device
from accelcal_station.config.sections import device_section
from accelcal_station.drivers.factory import make_driver
from accelcal_station.nvm.writer import CalibrationWriter

REPO = Path(__file__).resolve().parents[1]
EMU_SERIAL = "EMU-0001"  # configs/mma8451-emulated.yaml's simulated board


def cal(k: int) -> Calibration:
    rng = np.random.default_rng(k)
    return Calibration("12", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3), np.zeros(3),
                       "counts", 4096.0)


def emulated_config(tmp_path: Path, **device) -> Path:
    doc = yaml.safe_load((REPO / "configs" / "mma8451-emulated.yaml").read_text())
    doc["device"].update(device)
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def simulated_config(tmp_path: Path) -> Path:
    p = tmp_path / "sim-station.yaml"
    p.write_text(yaml.safe_dump({"device": {"driver": "simulated", "seed": 5, "serial": EMU_SERIAL}}))
    return p


@pytest.fixture(params=["mma8451-emulated", "simulated"])
def board(request, tmp_path, monkeypatch):
    """(config path, an in-process driver built from it with two calibrations burned)."""
    monkeypatch.chdir(tmp_path)  # automatic backups of erase land here
    cfg = emulated_config(tmp_path) if request.param == "mma8451-emulated" else simulated_config(tmp_path)
    dev = make_driver(device_section(str(cfg)))
    with dev:
        w = CalibrationWriter(dev.nvm)
        w.burn(cal(1), EMU_SERIAL, "st1", time=1_700_000_000)
        w.burn(cal(2), EMU_SERIAL, "st2", time=1_700_000_100)
    return cfg, dev


def nvm(*args, driver=None, input=None):
    return CliRunner().invoke(cli, ["nvm", *map(str, args)], obj=None if driver is None else {"driver": driver},
                              input=input)


def one_error_line(r) -> str:
    assert r.exit_code != 0 and r.stdout == "", r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr, r.stderr
    return lines[0]


def newest_w(dev):
    with dev:
        got = CalibrationWriter(dev.nvm).read_newest()
    return None if got is None else got[0].W


def test_read_backup_erase_restore_round_trip(board, tmp_path):
    cfg, dev = board
    r = nvm("read", "--json", driver=dev)
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert [s["state"] for s in d["slots"]] == ["valid", "valid"]
    n = d["newest"]
    assert (n["slot"], n["generation"], n["serial"], n["station_id"], n["model"]) == ("B", 2, EMU_SERIAL, "st2", "12")
    assert n["serial_match"] is True and n["time"] == 1_700_000_100
    np.testing.assert_array_equal(n["W"], cal(2).W)
    np.testing.assert_array_equal(n["V"], cal(2).V)

    text = nvm("read", driver=dev).stdout
    assert "slot A  valid   generation 1" in text and "(newest)" in text and "model 12, generation 2" in text

    r = nvm("backup", "--out", tmp_path / "b.json", driver=dev)
    assert r.exit_code == 0 and "backup written to" in r.stdout, r.output

    r = nvm("erase", driver=dev, input="n\n")  # the prompt goes to stderr, stdout stays clean
    assert r.exit_code == 1 and "Erase both calibration slots" in r.stderr and "cancelled" in r.stderr
    np.testing.assert_array_equal(newest_w(dev), cal(2).W)
    assert not list(tmp_path.glob("nvm-backup-*.json"))

    r = nvm("erase", driver=dev, input="y\n")
    assert r.exit_code == 0, r.output
    erase_backups = list(tmp_path.glob("nvm-backup-*.json"))
    assert len(erase_backups) == 1 and EMU_SERIAL in erase_backups[0].name
    assert newest_w(dev) is None
    d = json.loads(nvm("read", "--json", driver=dev).stdout)
    assert d["newest"] is None and [s["state"] for s in d["slots"]] == ["empty", "empty"]

    r = nvm("restore", tmp_path / "b.json", "--json", driver=dev)
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["newest"]["generation"] == 2 and [s["state"] for s in d["slots"]] == ["valid", "valid"]
    np.testing.assert_array_equal(newest_w(dev), cal(2).W)
    # the blank NVM it replaced was saved next to the image first
    pre = json.loads(Path(d["backup"]).read_text())
    assert Path(d["backup"]).parent == tmp_path and [s["state"] for s in pre["slots"]] == ["empty", "empty"]

    # the erase backup restores too (it holds both calibrations)
    r = nvm("restore", erase_backups[0], "--backup-to", tmp_path / "again.json", driver=dev)
    assert r.exit_code == 0 and (tmp_path / "again.json").is_file(), r.output


def test_restore_through_config_on_a_fresh_board(tmp_path, monkeypatch):
    """The NVM does not survive the process: a config-built board starts blank, and a backup restores onto it."""
    monkeypatch.chdir(tmp_path)
    cfg = emulated_config(tmp_path)
    dev = make_driver(device_section(str(cfg)))
    with dev:
        CalibrationWriter(dev.nvm).burn(cal(3), EMU_SERIAL, "st1")
    assert nvm("backup", "--out", "b.json", driver=dev).exit_code == 0
    assert json.loads(nvm("read", "--config", cfg, "--json").stdout)["newest"] is None
    r = nvm("restore", "b.json", "--config", cfg, "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["device"]["interface"] == "i2c:emulated@0x1d" and d["newest"]["serial"] == EMU_SERIAL
    np.testing.assert_array_equal(d["newest"]["W"], cal(3).W)


def test_damaged_or_foreign_backup_is_refused_with_one_line(board, tmp_path):
    _, dev = board
    assert nvm("backup", "--out", tmp_path / "b.json", driver=dev).exit_code == 0
    doc = json.loads((tmp_path / "b.json").read_text())
    img = bytearray(base64.b64decode(doc["image_base64"]))
    img[100] ^= 0x01  # one flipped bit inside slot A's coefficients
    doc["image_base64"] = base64.b64encode(bytes(img)).decode()
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    (tmp_path / "junk.json").write_text("not json at all")
    before = sorted(tmp_path.iterdir())

    line = one_error_line(r := nvm("restore", tmp_path / "bad.json", driver=dev))
    assert r.exit_code == 4 and "bad.json" in line and "damaged" in line
    line = one_error_line(nvm("restore", tmp_path / "junk.json", driver=dev))
    assert "junk.json: not an NVM backup" in line
    line = one_error_line(nvm("restore", tmp_path / "missing.json", driver=dev))
    assert "missing.json: cannot read" in line
    assert sorted(tmp_path.iterdir()) == before  # nothing backed up, nothing written
    np.testing.assert_array_equal(newest_w(dev), cal(2).W)


def test_image_of_another_board_needs_force(board, tmp_path):
    _, dev = board
    other = make_driver(validate_device({"driver": "simulated", "seed": 9, "serial": "OTHER-7"}))
    with other:
        CalibrationWriter(other.nvm).burn(cal(4), "OTHER-7", "st9")
    assert nvm("backup", "--out", tmp_path / "other.json", driver=other).exit_code == 0

    line = one_error_line(r := nvm("restore", tmp_path / "other.json", driver=dev))
    assert r.exit_code == 4 and "'OTHER-7'" in line and EMU_SERIAL in line
    np.testing.assert_array_equal(newest_w(dev), cal(2).W)

    r = nvm("restore", tmp_path / "other.json", "--force", driver=dev)
    assert r.exit_code == 0, r.output
    assert "warning: bound to serial 'OTHER-7', not this board's 'EMU-0001'" in r.stdout
    np.testing.assert_array_equal(newest_w(dev), cal(4).W)


def test_backups_are_never_overwritten(board, tmp_path):
    _, dev = board
    keep = tmp_path / "keep.json"
    keep.write_text("precious\n")
    line = one_error_line(r := nvm("backup", "--out", keep, driver=dev))
    assert r.exit_code == 4 and "exists" in line
    line = one_error_line(nvm("erase", "--yes", "--backup-to", keep, driver=dev))
    assert "exists" in line and keep.read_text() == "precious\n"
    np.testing.assert_array_equal(newest_w(dev), cal(2).W)  # not erased without its backup


def test_erase_yes_json_is_one_json_object(board, tmp_path):
    _, dev = board
    r = nvm("erase", "--yes", "--json", "--backup-to", tmp_path / "e.json", driver=dev)
    assert r.exit_code == 0 and r.stderr == "", r.output
    d = json.loads(r.stdout)
    assert d["newest"] is None and d["backup"] == str(tmp_path / "e.json")
    saved = json.loads((tmp_path / "e.json").read_text())
    assert [s["state"] for s in saved["slots"]] == ["valid", "valid"]


def test_default_config_is_the_simulated_board():
    r = nvm("read", "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["device"]["interface"] == "simulated" and d["newest"] is None


def test_config_errors_name_the_key(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump({"device": {"driver": "mma8452"}}))
    line = one_error_line(r := nvm("read", "--config", p))
    assert r.exit_code == 2 and "device.driver: 'mma8452'; allowed: simulated, mma8451, mpu6050" in line
    line = one_error_line(nvm("read", "--config", emulated_config(tmp_path, odr_hz=123)))
    assert "device.odr_hz" in line and "800" in line
    line = one_error_line(r := nvm("read", "--config", emulated_config(tmp_path, eeprom=None)))
    assert r.exit_code == 4 and "has no NVM" in line
    line = one_error_line(nvm("read", "--config", tmp_path / "nope.yaml"))
    assert "nope.yaml: cannot read" in line

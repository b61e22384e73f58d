"""Restore and burn never leave a board worse off (issue 26), through the emulated MMA8451 (smbus2 API,
24C32 at 0x50) with a lying bus, and through the real bridge firmware in simavr.

The lying bus (``emulator.corrupt_reads`` in the device config) flips one bit in a read message with
the given probability; the EEPROM itself keeps what was written.  What the board "really holds" is read
with the lie switched off afterwards.
"""
from __future__ import annotations

import base64
import json
import zlib
from pathlib import Path

import numpy as np
import yaml
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.config.sections import device_section
from accelcal_station.drivers.factory import make_driver
from accelcal_station.errors import NVMError
from accelcal_station.nvm.writer import BurnError, CalibrationWriter

REPO = Path(__file__).resolve().parents[1]
SERIAL = "EMU-0001"


def cal(k: int) -> Calibration:
    rng = np.random.default_rng(k)
    return Calibration("12", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3), np.zeros(3),
                       "counts", 4096.0)


def emulated_config(tmp_path: Path, emulator: dict | None = None) -> Path:
    doc = yaml.safe_load((REPO / "configs" / "mma8451-emulated.yaml").read_text())
    if emulator:
        doc["device"]["emulator"] = emulator
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def corrupt_both_slots(backup: Path, out: Path, slot_size: int) -> None:
    """The backup with one byte of each slot's blob flipped and the file's own CRC recomputed:
    the file is intact, both copies of the calibration in it are corrupt."""
    doc = json.loads(backup.read_text())
    img = bytearray(base64.b64decode(doc["image_base64"]))
    for slot in (0, 1):
        img[slot * slot_size + 120] ^= 0x40  # inside W: the blob's CRC no longer matches
    doc["image_base64"] = base64.b64encode(bytes(img)).decode()
    doc["crc32"] = zlib.crc32(bytes(img))
    out.write_text(json.dumps(doc))


def raw(dev) -> bytes:
    """The whole NVM (the CLI closes the device it is given; it is opened again here)."""
    with dev:
        return bytes(dev.nvm.read(0, dev.nvm.size))


def newest(dev, serial: str):
    with dev:
        return CalibrationWriter(dev.nvm).read_newest(serial)


def restore_refused(dev, tmp_path: Path) -> None:
    """Back up a board holding two calibrations, corrupt both copies, restore: refused, board unchanged."""
    before = raw(dev)
    with dev:
        slot_size = CalibrationWriter(dev.nvm).slot_size
    r = CliRunner().invoke(cli, ["nvm", "backup", "--out", str(tmp_path / "b.json")], obj={"driver": dev})
    assert r.exit_code == 0, r.output
    corrupt_both_slots(tmp_path / "b.json", tmp_path / "bad.json", slot_size)
    listing = sorted(tmp_path.iterdir())
    r = CliRunner().invoke(cli, ["nvm", "restore", str(tmp_path / "bad.json")], obj={"driver": dev})
    lines = r.stderr.strip().splitlines()
    assert r.exit_code == 4 and r.stdout == "" and len(lines) == 1, r.output
    assert "bad.json: the backup holds no valid calibration" in lines[0] and "nothing was written" in lines[0]
    assert raw(dev) == before  # not a byte changed
    assert sorted(tmp_path.iterdir()) == listing  # not even the pre-restore backup was made
    r = CliRunner().invoke(cli, ["nvm", "restore", str(tmp_path / "bad.json"), "--json"], obj={"driver": dev})
    assert r.exit_code == 4 and "no valid calibration" in json.loads(r.stdout)["error"]


def test_restore_of_a_backup_with_both_copies_corrupt_is_refused_mma8451(tmp_path):
    dev = make_driver(device_section(str(emulated_config(tmp_path))))
    with dev:
        w = CalibrationWriter(dev.nvm)
        w.burn(cal(1), SERIAL, "st")
        w.burn(cal(2), SERIAL, "st")
    restore_refused(dev, tmp_path)
    got, h, slot = newest(dev, SERIAL)
    assert (h.generation, slot) == (2, "B") and np.array_equal(got.W, cal(2).W)


def test_restore_of_a_backup_from_another_chip_is_refused(tmp_path):
    dev = make_driver(device_section(str(emulated_config(tmp_path))))
    with dev:
        CalibrationWriter(dev.nvm).burn(cal(1), SERIAL, "st")
    assert CliRunner().invoke(cli, ["nvm", "backup", "--out", str(tmp_path / "b.json")],
                              obj={"driver": dev}).exit_code == 0
    doc = json.loads((tmp_path / "b.json").read_text())
    assert doc["chip"] == "mma8451"
    doc["chip"] = "mpu6050"
    (tmp_path / "other.json").write_text(json.dumps(doc))
    before = raw(dev)
    r = CliRunner().invoke(cli, ["nvm", "restore", str(tmp_path / "other.json")], obj={"driver": dev})
    assert r.exit_code == 4 and "taken from a mpu6050 chip, this board is a mma8451" in r.stderr
    assert raw(dev) == before


def test_restore_refused_through_the_simavr_bridge(tmp_path):
    from test_mpu6050_firmware import LINK, make_bridge

    from accelcal_station.drivers.mpu6050 import MPU6050Bridge

    bridge = make_bridge("simavr")
    bridge.start()
    try:
        dev = MPU6050Bridge(bridge.port, **LINK["simavr"])
        with dev:
            sn = dev.identify().serial
            w = CalibrationWriter(dev.nvm)
            w.burn(cal(1), sn, "st")
            w.burn(cal(2), sn, "st")
        restore_refused(dev, tmp_path)
        got, h, slot = newest(dev, sn)
        assert (h.generation, slot) == (2, "B") and np.array_equal(got.W, cal(2).W)
    finally:
        bridge.stop()


def burn_on_a_lying_bus(tmp_path: Path, seed: int, rate: float) -> tuple[str, object, object]:
    """Burn cal(1) on a clean bus, then cal(2) with reads of the EEPROM corrupted; returns
    (what happened, the outcome or error, what the board really holds afterwards)."""
    cfg = emulated_config(tmp_path, {"corrupt_reads": {"rate": 0.0, "seed": seed}})
    dev = make_driver(device_section(str(cfg)))
    with dev:
        emu = dev.dev.smbus
        w = CalibrationWriter(dev.nvm)
        w.burn(cal(1), SERIAL, "st")
        emu.corrupt_reads(rate, seed)
        try:
            res: object = w.burn(cal(2), SERIAL, "st")
            kind = "ok"
        except BurnError as e:
            kind, res = "burn-failed", e
        except NVMError as e:
            kind, res = "refused", e
        lies = emu.corrupted
        emu.corrupt_reads(0.0)
        truth = w.holds()
    assert lies > 0 or kind == "ok"
    return kind, res, truth


def test_a_burn_on_a_lying_bus_keeps_the_previous_calibration_and_records_what_nvm_holds(tmp_path):
    """40 boards, a read message in 6 corrupted (a 4 KiB image is 16 messages of 256 bytes).  Every burn
    either verifies and says so, or fails and the board still holds the previous calibration, which
    the outcome names exactly (slot, generation, CRC-32); never 'no previous calibration'."""
    kinds = []
    for seed in range(40):
        kind, res, truth = burn_on_a_lying_bus(tmp_path, seed, 1 / 6)
        kinds.append(kind)
        assert truth is not None and truth["slot"] is not None
        if kind == "ok":
            assert (truth["slot"], truth["generation"]) == ("B", 2) and truth == res.nvm_after
            continue
        # the previous calibration is the board's newest, exactly as before
        assert (truth["slot"], truth["generation"]) == ("A", 1), (seed, kind, str(res))
        assert "no previous calibration" not in str(res)
        if kind == "burn-failed":
            out = res.outcome
            assert out.previous == truth and out.nvm_after in (truth, None)
            assert "previous calibration (slot A, generation 1) is untouched" in str(res) or out.nvm_after is None
        else:
            assert "nothing was written" in str(res) or "reads disagree" in str(res)
    # the sweep exercised every path (fixed seeds: deterministic)
    assert {"ok", "burn-failed"} <= set(kinds), kinds


def test_station_run_on_a_lying_bus_keeps_the_previous_calibration_and_records_it(tmp_path):
    """A whole station run (emulated MMA8451, simulated jig) whose EEPROM reads are mostly corrupted
    when it burns: the run is FAIL with an nvm reason, the board still holds its previous calibration,
    and the run's NVM outcome names exactly that (slot, generation, CRC-32)."""
    from accelcal_station.station.flow import make_flow
    from accelcal_station.station.settings import StationConfig

    doc = yaml.safe_load((REPO / "configs" / "mma8451-emulated.yaml").read_text())
    doc["jig"] = {"type": "simulated", "move_time_s": 0.0}
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    (tmp_path / "st.yaml").write_text(yaml.safe_dump(doc))
    cfg = StationConfig.load(tmp_path / "st.yaml")
    dev = make_driver(device_section(str(tmp_path / "st.yaml")))
    with dev:
        before = CalibrationWriter(dev.nvm).burn(cal(1), SERIAL, "old-station")
        emu = dev.dev.smbus
    emu.corrupt_reads(0.9, seed=2)  # nine read messages in ten come back with a flipped bit
    rep = make_flow(cfg, driver=dev, echo=lambda s: None).run()[0]
    emu.corrupt_reads(0.0)
    with dev:
        truth = CalibrationWriter(dev.nvm).holds()
        got = CalibrationWriter(dev.nvm).read_newest(SERIAL)
    assert rep.verdict == "FAIL" and rep.reasons[0].code == "nvm"
    assert "no previous calibration" not in rep.reasons[0]
    assert truth == {"slot": "A", "generation": 1, "crc32": before.crc32, "serial": SERIAL}
    assert np.array_equal(got[0].W, cal(1).W)
    assert rep.nvm["previous"] == truth and rep.nvm["nvm_after"] == truth and not rep.nvm["verified"]
    import sqlite3

    row = sqlite3.connect(tmp_path / "runs.sqlite").execute("SELECT status, verdict FROM runs").fetchone()
    assert row == ("complete", "FAIL")

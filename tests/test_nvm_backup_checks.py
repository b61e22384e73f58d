"""Issue 53: `nvm restore` checks each slot's own CRC in the backup before writing anything, and a
backup's target and fields are named as what they are.

On the emulated MMA8451's EEPROM (configs/mma8451-emulated.yaml, a real driver over the emulated
I2C bus): two calibrations are burned, a backup is taken, one byte inside slot A's blob is flipped
and the backup's overall CRC-32 computed again (zlib, as an outside tool would), so only the slot's
own CRC can tell.  The restore must refuse in one line, the EEPROM's bytes unchanged.
"""
from __future__ import annotations

import base64
import json
import zlib
from pathlib import Path

import pytest
from test_cli_nvm import EMU_SERIAL, cal, emulated_config, nvm, one_error_line

from accelcal_station.config.sections import device_section
from accelcal_station.drivers.factory import make_driver
from accelcal_station.nvm.blob import HEADER_SIZE
from accelcal_station.nvm.writer import CalibrationWriter


@pytest.fixture()
def emulated(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = emulated_config(tmp_path)
    dev = make_driver(device_section(str(cfg)))
    with dev:
        w = CalibrationWriter(dev.nvm)
        w.burn(cal(1), EMU_SERIAL, "st1", time=1_700_000_000)
        w.burn(cal(2), EMU_SERIAL, "st2", time=1_700_000_100)
    r = nvm("backup", "--out", tmp_path / "good.json", driver=dev)
    assert r.exit_code == 0, r.output
    return dev, tmp_path / "good.json"


def _eeprom(dev) -> bytes:
    with dev:
        return CalibrationWriter(dev.nvm).image()


def _rewritten(src: Path, dst: Path, edit) -> Path:
    doc = json.loads(src.read_text())
    img = bytearray(base64.b64decode(doc["image_base64"]))
    edit(img, doc)
    doc["image_base64"] = base64.b64encode(bytes(img)).decode()
    doc["crc32"] = zlib.crc32(bytes(img))  # the overall checksum made to match again
    dst.write_text(json.dumps(doc))
    return dst


@pytest.mark.parametrize("offset", [HEADER_SIZE + 5, 40])  # a coefficient byte; a header byte
def test_a_flipped_byte_in_slot_a_is_refused_before_anything_is_written(emulated, tmp_path, offset):
    dev, good = emulated

    def flip(img: bytearray, doc: dict) -> None:
        img[offset] ^= 0x01  # slot A starts at offset 0 of the image

    bad = _rewritten(good, tmp_path / "bad.json", flip)
    before = _eeprom(dev)
    r = nvm("restore", bad, "--any-serial", "--backup-to", tmp_path / "pre.json", driver=dev)
    line = one_error_line(r)
    assert "slot A of the backup" in line and "nothing was written" in line, line
    assert _eeprom(dev) == before
    assert not (tmp_path / "pre.json").exists()  # not even the pre-restore backup


def test_the_untouched_backup_still_restores(emulated, tmp_path):
    dev, good = emulated
    r = nvm("restore", good, "--any-serial", "--backup-to", tmp_path / "pre.json", driver=dev)
    assert r.exit_code == 0, r.output


def test_a_wrong_length_field_is_named(emulated, tmp_path):
    dev, good = emulated

    def lie(img: bytearray, doc: dict) -> None:
        doc["length"] = 4095

    bad = _rewritten(good, tmp_path / "len.json", lie)
    line = one_error_line(nvm("restore", bad, "--backup-to", tmp_path / "pre.json", driver=dev))
    assert "field 'length' is 4095; expected 4096" in line, line


def test_a_backup_to_a_device_says_what_it_is(emulated):
    dev, _ = emulated
    line = one_error_line(nvm("backup", "--out", "/dev/full", driver=dev))
    assert "/dev/full: a character device, not a regular file" in line, line
    assert "exists" not in line


def test_an_existing_backup_is_still_never_overwritten(emulated):
    dev, good = emulated
    before = good.read_bytes()
    line = one_error_line(nvm("backup", "--out", good, driver=dev))
    assert "backup file exists" in line and good.read_bytes() == before

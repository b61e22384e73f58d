"""A/B slot writer on a 24C32 EEPROM model (drivers/eeprom.py) and on a plain byte-array NVM."""
from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from accelcal_station.calibration import Calibration, TemperatureTable
from accelcal_station.drivers.base import NVM
from accelcal_station.drivers.eeprom import EEPROM24
from accelcal_station.errors import NVMError
from accelcal_station.nvm.blob import blob_size, decode, encode
from accelcal_station.nvm.writer import BurnError, CalibrationWriter

SERIAL, STATION = "SN-0001", "station-1"


class ByteNVM(NVM):
    """Any byte-addressed NVM (no pages): the writer needs only the NVM interface."""

    def __init__(self, size: int = 1024, stuck_zero: int | None = None):
        self.size, self.page_size = size, 1
        self.mem = bytearray(b"\xff" * size)
        self.stuck_zero = stuck_zero  # address of a worn cell stuck at 0x00

    def read(self, addr: int, n: int) -> bytes:
        self._check_range(addr, n)
        return bytes(self.mem[addr:addr + n])

    def write(self, addr: int, data: bytes) -> None:
        self._check_range(addr, len(data))
        self.mem[addr:addr + len(data)] = data
        if self.stuck_zero is not None:
            self.mem[self.stuck_zero] = 0


def cal(seed: int, k: int = 0) -> Calibration:
    rng = np.random.default_rng(seed)
    table = None
    if k:
        table = TemperatureTable(np.linspace(0, 50, k), np.eye(3) + rng.normal(0, 0.01, (k, 3, 3)),
                                 rng.normal(0, 0.02, (k, 3)), np.zeros((k, 3)))
    return Calibration("12", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3),
                       input_units="counts", input_per_g=4096.0, temperature=table)


def same(a: Calibration, b: Calibration) -> bool:
    return bool(np.array_equal(a.W, b.W) and np.array_equal(a.V, b.V) and np.array_equal(a.Gamma, b.Gamma))


@pytest.fixture
def eeprom() -> EEPROM24:
    return EEPROM24(4096, 32)


def test_layout_and_alternating_slots(eeprom):
    w = CalibrationWriter(eeprom)
    assert (w.slot_size, w.slot_addr(1)) == (2048, 2048)
    assert w.read_newest() is None and [s.state for s in w.status()] == ["empty", "empty"]
    for i, slot in enumerate("ABAB"):
        out = w.burn(cal(i), SERIAL, STATION, time=1000 + i)
        assert (out.ok, out.verified, out.slot, out.generation) == (True, True, slot, i + 1)
        got, h, s = CalibrationWriter(eeprom).read_newest(SERIAL)  # a fresh reader, as after a reboot
        assert same(got, cal(i)) and (h.generation, h.time, s) == (i + 1, 1000 + i, slot)
    st = w.status()
    assert [s.generation for s in st] == [3, 4] and [s.newest for s in st] == [False, True]
    prev_crc = decode(eeprom.read(0, 2048))[1].crc32
    assert out.previous == {"slot": "A", "generation": 3, "crc32": prev_crc, "serial": SERIAL}
    assert out.nvm_after == {"slot": "B", "generation": 4, "crc32": out.crc32, "serial": SERIAL}


@pytest.mark.parametrize("history", [1, 2])  # target slot blank / target slot holds an older blob
@pytest.mark.parametrize("fail_bytes", [0, None])  # nothing / half of the page reaches the cells
def test_power_loss_between_page_writes_keeps_previous(eeprom, history, fail_bytes):
    """Done-when: an injected failure between two page writes leaves the previous calibration loadable."""
    w = CalibrationWriter(eeprom)
    for i in range(history):
        w.burn(cal(i), SERIAL, STATION)
    prev_slot = "AB"[(history - 1) % 2]
    pages = -(-blob_size(0) // 32)
    assert pages == 7
    for k in range(1, pages + 1):
        eeprom.inject_power_loss(at_write=k, fail_bytes=fail_bytes)
        with pytest.raises(BurnError, match="power loss.*previous calibration") as e:
            w.burn(cal(99), SERIAL, STATION)
        assert e.value.outcome.ok is False and e.value.outcome.slot != prev_slot
        got, h, s = CalibrationWriter(eeprom).read_newest(SERIAL)
        assert same(got, cal(history - 1)) and h.generation == history and s == prev_slot, k
    out = w.burn(cal(99), SERIAL, STATION)  # power is back: the retry succeeds
    assert out.ok and out.generation == history + 1
    assert same(CalibrationWriter(eeprom).read_newest()[0], cal(99))


def test_corrupted_slot_detected_by_crc_and_ignored(eeprom):
    """Done-when: a corrupted slot is detected by its CRC and ignored."""
    w = CalibrationWriter(eeprom)
    w.burn(cal(1), SERIAL, STATION)
    w.burn(cal(2), SERIAL, STATION)  # slot B, newest
    addr = w.slot_addr(1) + 150  # inside V
    eeprom.write(addr, bytes([eeprom.read(addr, 1)[0] ^ 0x10]))
    st = w.status()
    assert (st[1].state, st[1].crc_ok, st[1].newest) == ("corrupt", False, False)
    assert "CRC mismatch" in st[1].error and st[0].newest
    got, h, s = w.read_newest()
    assert same(got, cal(1)) and s == "A"
    out = w.burn(cal(3), SERIAL, STATION)  # the corrupt slot is the one overwritten
    assert (out.slot, out.generation) == ("B", 2)
    eeprom.write(w.slot_addr(0), b"\0")  # break slot A's magic too
    assert w.read_newest()[2] == "B"
    eeprom.write(w.slot_addr(1) + 216, b"\0\0\0\0")  # and B's CRC: nothing valid is left
    assert w.read_newest() is None
    assert [s.state for s in w.status()] == ["corrupt", "corrupt"]


def test_generation_wraps_and_orders(eeprom):
    w = CalibrationWriter(eeprom)
    eeprom.write(0, encode(cal(1), SERIAL, STATION, 0xFFFFFFFF, 0))
    out = w.burn(cal(2), SERIAL, STATION)
    assert (out.slot, out.generation) == ("B", 0)
    got, h, s = w.read_newest()
    assert s == "B" and h.generation == 0 and same(got, cal(2))  # 0 is newer than 0xFFFFFFFF
    out = w.burn(cal(3), SERIAL, STATION)
    assert (out.slot, out.generation) == ("A", 1)
    # two valid slots that are not consecutive: serial-number arithmetic decides
    eeprom.write(2048, encode(cal(4), SERIAL, STATION, 0x80000000, 0))
    assert w.read_newest()[2] == "B"  # 0x80000000 is 2**31 - 1 after 1: newer
    eeprom.write(2048, encode(cal(4), SERIAL, STATION, 0x80000002, 0))
    assert w.read_newest()[2] == "A"  # 1 is 2**31 - 1 after 0x80000002: newer


def test_blob_larger_than_slot_refused_before_writing(eeprom):
    w = CalibrationWriter(eeprom, slot_size=512)
    w.burn(cal(1), SERIAL, STATION)
    before, writes = eeprom.read(0, 4096), eeprom.page_writes
    with pytest.raises(NVMError, match="blob is 604 bytes; an NVM slot holds 512; nothing was written"):
        w.burn(cal(2, k=3), SERIAL, STATION)
    assert eeprom.read(0, 4096) == before and eeprom.page_writes == writes
    big = CalibrationWriter(eeprom)  # 2048-byte slots hold a 3-point temperature table
    out = big.burn(cal(2, k=3), SERIAL, STATION)
    got = big.read_newest()[0]
    assert out.length == 604 and np.array_equal(got.temperature.W, cal(2, k=3).temperature.W)


def test_read_back_mismatch_is_a_failed_burn():
    nvm = ByteNVM(1024, stuck_zero=512 + 100)  # a worn cell in slot B's coefficients
    w = CalibrationWriter(nvm)
    w.burn(cal(1), SERIAL, STATION)
    payload = encode(cal(2), SERIAL, STATION, 2, 5)
    assert payload[100] != 0, "the test needs a non-zero byte at the stuck cell"
    want = r"read-back differs at address 612 .*slot A, generation 1\) is untouched .*CRC-32 0x[0-9a-f]{8}"
    with pytest.raises(BurnError, match=want) as e:
        w.burn(cal(2), SERIAL, STATION, time=5)
    assert e.value.outcome.ok is False and not e.value.outcome.verified
    got, h, s = w.read_newest()
    assert same(got, cal(1)) and s == "A"


def test_serial_binding():
    w = CalibrationWriter(ByteNVM())
    w.burn(cal(1), "SN-A", STATION)
    assert w.read_newest("SN-A")[1].serial == "SN-A"
    with pytest.raises(NVMError, match="bound to serial 'SN-A', not this board's 'SN-B'") as e:
        w.read_newest("SN-B")
    assert "\n" not in str(e.value)
    assert same(w.read_newest("SN-B", allow_other_serial=True)[0], cal(1))


def test_layout_checked():
    with pytest.raises(NVMError, match="multiples of the 32-byte page"):
        CalibrationWriter(EEPROM24(4096, 32), base_addr=10)
    with pytest.raises(NVMError, match="do not fit"):
        CalibrationWriter(EEPROM24(4096, 32), slot_size=4096)
    with pytest.raises(NVMError, match="allowed slot size 220"):
        CalibrationWriter(ByteNVM(300))
    w = CalibrationWriter(EEPROM24(4096, 32), slot_size=1024, base_addr=1024)
    w.burn(cal(1), SERIAL, STATION)
    assert [s.addr for s in w.status()] == [1024, 2048]


def test_backup_restore_erase(eeprom, tmp_path):
    w = CalibrationWriter(eeprom)
    w.burn(cal(1), SERIAL, STATION)
    w.burn(cal(2), SERIAL, STATION)
    saved = eeprom.read(0, 4096)
    info = w.backup(tmp_path / "b1.json")
    assert info["length"] == 4096 and [s["generation"] for s in info["slots"]] == [1, 2]
    with pytest.raises(NVMError, match="backup file exists"):
        w.backup(tmp_path / "b1.json")

    w.burn(cal(3), SERIAL, STATION)  # overwrites slot A
    status = w.restore(tmp_path / "b1.json", serial=SERIAL, backup_to=tmp_path / "before-restore.json")
    assert eeprom.read(0, 4096) == saved and status[1].newest
    assert same(w.read_newest()[0], cal(2))
    assert w.load_image(tmp_path / "before-restore.json")[1]["slots"][0]["generation"] == 3

    st = w.erase(backup_to=tmp_path / "before-erase.json")
    assert [s.state for s in st] == ["empty", "empty"] and w.read_newest() is None
    assert eeprom.read(0, 4096) == b"\xff" * 4096
    w.restore(tmp_path / "before-erase.json")
    assert same(w.read_newest()[0], cal(2))


def test_restore_refuses_bad_images(eeprom, tmp_path):
    w = CalibrationWriter(eeprom)
    w.burn(cal(1), SERIAL, STATION)
    w.backup(tmp_path / "b.json")
    doc = json.loads((tmp_path / "b.json").read_text())
    w.burn(cal(2), SERIAL, STATION)
    before = eeprom.read(0, 4096)

    img = bytearray(base64.b64decode(doc["image_base64"]))
    img[3000] ^= 1
    damaged = dict(doc, image_base64=base64.b64encode(bytes(img)).decode())
    (tmp_path / "damaged.json").write_text(json.dumps(damaged))
    with pytest.raises(NVMError, match="does not match the recorded .* the backup is damaged"):
        w.restore(tmp_path / "damaged.json")
    with pytest.raises(NVMError, match="bound to serial 'SN-0001', not this board's 'SN-9'"):
        w.restore(tmp_path / "b.json", serial="SN-9")
    with pytest.raises(NVMError, match="image is for slots of 2048 bytes at 0; this NVM has slots of 1024"):
        CalibrationWriter(eeprom, slot_size=1024).restore(tmp_path / "b.json")
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(NVMError, match="junk.json: not an NVM backup"):
        w.restore(tmp_path / "junk.json")
    with pytest.raises(NVMError, match="cannot read"):
        w.restore(tmp_path / "missing.json")
    (tmp_path / "binary.json").write_bytes(bytes(range(128, 256)))
    with pytest.raises(NVMError, match="binary.json: not an NVM backup \\(not a text file\\)"):
        w.restore(tmp_path / "binary.json")
    assert eeprom.read(0, 4096) == before  # nothing refused was written


@pytest.mark.parametrize("at_write", [3, 64, 65, 70, 128])  # pages 1-64: slot written first; 65-128: second
def test_power_loss_during_restore_keeps_a_valid_calibration(eeprom, tmp_path, at_write):
    """Restoring an image whose slot B is blank over A (newest) + B: whichever slot is being
    written, the other must hold a valid calibration (old or restored)."""
    w = CalibrationWriter(eeprom)
    w.burn(cal(1), SERIAL, STATION)  # A, generation 1
    w.backup(tmp_path / "img.json")  # image: A valid, B blank
    w.burn(cal(2), SERIAL, STATION)  # B, generation 2
    w.burn(cal(3), SERIAL, STATION)  # A, generation 3 (newest)
    eeprom.inject_power_loss(at_write=at_write)
    with pytest.raises(NVMError, match="power loss"):
        w.restore(tmp_path / "img.json")
    got = CalibrationWriter(eeprom).read_newest(SERIAL)
    assert got is not None, f"no valid calibration left after power loss at page write {at_write}"
    assert any(same(got[0], cal(i)) for i in (1, 2, 3))
    w.restore(tmp_path / "img.json")  # power is back: the restore completes
    assert same(w.read_newest()[0], cal(1)) and [s.state for s in w.status()] == ["valid", "empty"]


@pytest.mark.parametrize("driver", ["mma8451", "simulated"])
def test_burn_through_a_driver_nvm_survives_power_loss(driver):
    """The board's own NVM path: MMA8451 over smbus2 i2c_rdwr to the emulated 24C32 at 0x50,
    and the simulated board's EEPROM; power is lost in the 4th page write of a burn."""
    from accelcal_station.config.schema import validate_device
    from accelcal_station.drivers.factory import make_driver

    cfg = {"driver": driver, "seed": 3, **({"bus": "emulated"} if driver == "mma8451" else {})}
    with make_driver(validate_device(cfg)) as dev:
        serial = dev.identify().serial
        eeprom = dev.dev.smbus.board.eeprom if driver == "mma8451" else dev.board.eeprom
        w = CalibrationWriter(dev.nvm)
        w.burn(cal(1), serial, STATION)
        eeprom.inject_power_loss(at_write=4)
        with pytest.raises(BurnError, match="slot B.*power loss.*slot A, generation 1\\) is untouched"):
            w.burn(cal(2), serial, STATION)
        got, h, s = CalibrationWriter(dev.nvm).read_newest(serial)
        assert same(got, cal(1)) and (h.generation, s) == (1, "A")
        assert CalibrationWriter(dev.nvm).status()[1].state == "empty"  # the torn slot's header was erased
        assert w.burn(cal(2), serial, STATION).verified
        assert same(CalibrationWriter(dev.nvm).read_newest(serial)[0], cal(2))


def test_a_readback_error_after_the_blob_landed_says_so():
    class FlakyReadEEPROM(EEPROM24):
        """A 24C32 whose bus glitches on the first read after a write, once armed."""
        armed = fail_next_read = False

        def write(self, addr, data):
            super().write(addr, data)
            self.fail_next_read = self.armed

        def read(self, addr, n):
            if self.fail_next_read:
                self.armed = self.fail_next_read = False
                raise OSError(121, "Remote I/O error")
            return super().read(addr, n)

    nvm = FlakyReadEEPROM()
    w = CalibrationWriter(nvm)
    w.burn(cal(1), "SN1", "st")
    nvm.armed = True
    with pytest.raises(BurnError) as e:
        w.burn(cal(2), "SN1", "st")
    # the new blob landed but was not verified: it is invalidated, the previous one is the newest again
    assert "previous calibration (slot A, generation 1" in str(e.value) and "is untouched" in str(e.value)
    assert not e.value.outcome.ok and e.value.outcome.nvm_after["slot"] == "A"
    assert e.value.outcome.nvm_after == {**e.value.outcome.previous}
    c, h, slot = w.read_newest("SN1")
    assert h.generation == 1 and slot == "A" and same(c, cal(1))

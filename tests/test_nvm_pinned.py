"""Issue 53, the NVM writer pinned: the post-burn check that the new blob is the newest valid one,
the slot a burn writes when a slot is corrupt (kept as evidence, or recorded before it is
overwritten), and a CRC-valid blob with flags this station does not know (a typed content error).

The NVMs here are byte-level models of a 24C32 (drivers/eeprom.py) with the faults a shared or
failing bus can show: a second writer, a slot that changes after its read-back, reads that never
settle.  The expected bytes are the bytes written, taken before the burn."""
from __future__ import annotations

import base64
import json
import struct
import zlib

import numpy as np
import pytest

from accelcal_station.calibration import Calibration, TemperatureTable
from accelcal_station.drivers.eeprom import EEPROM24
from accelcal_station.errors import NVMError
from accelcal_station.nvm.blob import BlobError, decode, encode
from accelcal_station.nvm.writer import BurnError, CalibrationWriter

SERIAL, STATION = "SN-53", "station-53"
SLOT = 2048  # 24C32: two 2048-byte slots


def cal(seed: int) -> Calibration:
    rng = np.random.default_rng(seed)
    return Calibration("12", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3),
                       input_units="counts", input_per_g=4096.0)


class RacingEEPROM(EEPROM24):
    """A 24C32 shared with another writer: ``after_write(addr)`` runs once the first write at
    ``trigger`` has been read back once (the writer's own verification read passes)."""

    def __init__(self, trigger: int, race) -> None:
        super().__init__(4096, 32)
        self.trigger, self.race, self.armed, self.fired = trigger, race, False, False

    def write(self, addr, data):
        super().write(addr, data)
        if addr == self.trigger and not self.fired:
            self.armed = True

    def read(self, addr, n):
        out = super().read(addr, n)
        if self.armed:  # the read-back of the burn itself: then the other writer strikes
            self.armed, self.fired = False, True
            self.race(self)
        return out


def _put(nvm: EEPROM24, addr: int, data: bytes) -> None:
    EEPROM24.write(nvm, addr, data)


@pytest.mark.parametrize("race,why", [
    # another writer puts a newer calibration into slot A: the new blob in B is not the newest
    (lambda e: _put(e, 0, encode(cal(9), SERIAL, "other", 7, 1)), "another slot newer"),
    # slot B is replaced after its read-back by another blob of the same generation: same slot, other CRC
    (lambda e: _put(e, SLOT, encode(cal(9), SERIAL, "other", 2, 1)), "same slot, other blob"),
])
def test_a_burn_whose_blob_is_not_the_newest_valid_afterwards_fails(race, why):
    nvm = RacingEEPROM(SLOT, race)
    w = CalibrationWriter(nvm)
    w.burn(cal(1), SERIAL, STATION, time=1)  # slot A, generation 1
    with pytest.raises(BurnError, match="burn of NVM slot B: slot is not the newest valid after writing") as e:
        w.burn(cal(2), SERIAL, STATION, time=2)
    o = e.value.outcome
    assert not o.ok and not o.verified and o.slot == "B" and o.generation == 2, why


class UnsettledAfterWrite(EEPROM24):
    """Reads that never agree once a write at ``trigger`` has been read back (a bus gone bad)."""

    def __init__(self, trigger: int) -> None:
        super().__init__(4096, 32)
        self.trigger, self.state, self.rng = trigger, 0, np.random.default_rng(5)

    def write(self, addr, data):
        super().write(addr, data)
        if addr == self.trigger and self.state == 0:
            self.state = 1

    def read(self, addr, n):
        out = super().read(addr, n)
        if self.state == 1:  # the burn's own read-back passes
            self.state = 2
            return out
        if self.state == 2:
            return self.rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        return out


def test_a_burn_whose_nvm_cannot_be_read_afterwards_is_not_called_verified():
    nvm = UnsettledAfterWrite(SLOT)
    w = CalibrationWriter(nvm)
    w.burn(cal(1), SERIAL, STATION, time=1)
    with pytest.raises(BurnError, match="slot is not the newest valid after writing") as e:
        w.burn(cal(2), SERIAL, STATION, time=2)
    assert e.value.outcome.nvm_after is None and not e.value.outcome.ok
    assert "could not be read" in str(e.value)


def _corrupt(nvm: EEPROM24, slot: int, seed: int) -> bytes:
    """A blob in ``slot`` with one byte flipped inside its coefficients (its CRC fails); its bytes."""
    addr = slot * SLOT
    _put(nvm, addr, encode(cal(seed), SERIAL, STATION, 4, 1))
    _put(nvm, addr + 120, bytes([nvm.read(addr + 120, 1)[0] ^ 0x5A]))
    return bytes(nvm.read(addr, SLOT))


def _slot(nvm: EEPROM24, slot: int) -> bytes:
    return bytes(nvm.read(slot * SLOT, SLOT))


def test_a_corrupt_slot_is_kept_as_evidence_when_the_other_is_erased():
    for corrupt, erased in ((0, 1), (1, 0)):
        nvm = EEPROM24(4096, 32)
        evidence = _corrupt(nvm, corrupt, 3)
        w = CalibrationWriter(nvm)
        assert [s.state for s in w.status()][corrupt] == "corrupt"
        out = w.burn(cal(1), SERIAL, STATION, time=1)
        assert out.slot == "AB"[erased] and out.ok and out.overwrote is None
        assert _slot(nvm, corrupt) == evidence  # byte for byte
        got, h, slot = w.read_newest(SERIAL)
        assert slot == "AB"[erased] and h.generation == 1 and np.array_equal(got.W, cal(1).W)


def test_a_corrupt_slot_that_must_be_written_is_recorded_before_it_is():
    """Slot A holds the only valid calibration and B is corrupt: the burn must write B (never the only
    valid one), and the outcome, recorded before the first byte, carries B's bytes as they were."""
    nvm = EEPROM24(4096, 32)
    w = CalibrationWriter(nvm)
    w.burn(cal(1), SERIAL, STATION, time=1)
    evidence = _corrupt(nvm, 1, 3)
    seen = []
    out = w.burn(cal(2), SERIAL, STATION, time=2, before_write=lambda o: seen.append(dict(o.overwrote or {})))
    assert out.slot == "B" and out.ok and out.generation == 2
    assert seen and seen[0]["state"] == "corrupt" and seen[0]["slot"] == "B" and "CRC" in seen[0]["error"]
    assert base64.b64decode(seen[0]["raw_base64"]) == evidence
    # the next burn writes A over an older valid calibration: its status is recorded, no raw bytes
    out = w.burn(cal(3), SERIAL, STATION, time=3)
    assert out.slot == "A" and out.overwrote["state"] == "valid" and out.overwrote["generation"] == 1
    assert "raw_base64" not in out.overwrote


def test_both_slots_corrupt_the_burn_writes_a_and_records_it():
    nvm = EEPROM24(4096, 32)
    a, b = _corrupt(nvm, 0, 3), _corrupt(nvm, 1, 4)
    out = CalibrationWriter(nvm).burn(cal(1), SERIAL, STATION, time=1)
    assert out.slot == "A" and base64.b64decode(out.overwrote["raw_base64"]) == a
    assert _slot(nvm, 1) == b


def _with_flags(blob: bytes, flags: int, k: int | None = None) -> bytes:
    """``blob`` with its flags byte (and K) replaced and its CRC recomputed: CRC-valid."""
    x = bytearray(blob)
    x[7] = flags
    if k is not None:
        x[15] = k
    x[-4:] = struct.pack("<I", zlib.crc32(bytes(x[:-4])))
    return bytes(x)


TABLE = TemperatureTable(np.array([0.0, 50.0]), np.stack([np.eye(3), 1.01 * np.eye(3)]), np.zeros((2, 3)),
                         np.zeros((2, 3)))


@pytest.mark.parametrize("flags,k", [(0x08, None), (0x10, None), (0x80, None), (0xF8, None),
                                     (0x04, None),  # no base coefficients and no table
                                     (0x01, None),  # a table announced, none present
                                     (0x02, None)])  # quadratic interpolation of no table
def test_a_crc_valid_blob_with_unknown_or_inconsistent_flags_is_a_content_error(flags, k):
    blob = _with_flags(encode(cal(1), SERIAL, STATION, 1, 1), flags, k)
    if flags == 0x04:  # the length the flags announce (no base: 100 bytes), so the CRC is reached
        blob = _with_flags(blob[:12] + struct.pack("<H", 100) + blob[14:96] + blob[-4:], flags)
    with pytest.raises(BlobError) as e:
        decode(blob, "NVM slot A")
    msg = str(e.value)
    assert e.value.kind == "content" and "\n" not in msg, msg
    assert msg.startswith("NVM slot A: CRC is valid but the content is not a calibration (flags "
                          f"0x{flags:02x} inconsistent with 0 temperature points)"), msg


def test_a_table_blob_with_an_unknown_flag_is_a_content_error_and_a_corrupt_slot():
    c = Calibration("12", np.eye(3), np.zeros(3), input_units="counts", input_per_g=4096.0, temperature=TABLE)
    good = encode(c, SERIAL, STATION, 1, 1)
    assert decode(good)[0].temperature is not None
    bad = _with_flags(good, good[7] | 0x40)
    with pytest.raises(BlobError, match=r"flags 0x4[0-9a-f] inconsistent with 2 temperature points") as e:
        decode(bad)
    assert e.value.kind == "content"
    nvm = EEPROM24(4096, 32)
    _put(nvm, 0, bad)
    st = CalibrationWriter(nvm).status()[0]
    assert (st.state, st.crc_ok) == ("corrupt", True) and "flags" in st.error


class LoggingEEPROM(EEPROM24):
    """A 24C32 that logs the address of every write (the order slots are written in)."""

    def __init__(self) -> None:
        super().__init__(4096, 32)
        self.writes: list[int] = []

    def write(self, addr, data):
        self.writes.append(addr)
        super().write(addr, data)


def test_slot_status_after_burns_and_the_burn_backup(tmp_path):
    nvm = LoggingEEPROM()
    w = CalibrationWriter(nvm)
    assert w.holds() == {"slot": None}
    assert [s.state for s in w.status()] == ["empty", "empty"]
    out = w.burn(cal(1), SERIAL, STATION, time=1234)
    st = w.status()[0]
    assert (st.state, st.crc_ok, st.generation, st.serial, st.station_id, st.time, st.model, st.length, st.newest) \
        == ("valid", True, 1, SERIAL, STATION, 1234, "12", 220, True)
    assert (st.slot, st.addr, st.size) == ("A", 0, SLOT)
    assert w.holds() == {"slot": "A", "generation": 1, "crc32": out.crc32, "serial": SERIAL}
    out = w.burn(cal(2), SERIAL, STATION, time=1300, backup_to=tmp_path / "before.json")
    assert out.backup == str(tmp_path / "before.json") and (tmp_path / "before.json").exists()
    assert [s.newest for s in w.status()] == [False, True]
    # erase writes the slot without the newest calibration first (B is newest: A, then B)
    nvm.writes.clear()
    assert [s.state for s in w.erase()] == ["empty", "empty"]
    assert [a // SLOT for a in nvm.writes] == [0, 1]
    w.burn(cal(3), SERIAL, STATION, time=1400)  # A, generation 1
    nvm.writes.clear()
    w.erase()
    assert [a // SLOT for a in nvm.writes] == [1, 0]


def test_a_backup_whose_image_has_another_length_is_refused_and_nothing_written(tmp_path):
    nvm = EEPROM24(4096, 32)
    w = CalibrationWriter(nvm)
    w.burn(cal(1), SERIAL, STATION, time=1)
    path = tmp_path / "b.json"
    w.backup(path)
    doc = json.loads(path.read_text())
    img = base64.b64decode(doc["image_base64"])[:-32]  # one page short, CRC and length field made to agree
    doc.update(image_base64=base64.b64encode(img).decode(), crc32=zlib.crc32(img), length=len(img))
    path.write_text(json.dumps(doc))
    before = w.image()
    with pytest.raises(NVMError, match=f"{len(img)} bytes"):  # the image's own length named
        w.restore(path)
    assert w.image() == before


def test_a_blob_that_fills_its_slot_exactly_is_burned():
    from accelcal_station.nvm.blob import blob_size

    nvm = EEPROM24(1024, 1)  # byte pages: a slot of exactly one blob
    w = CalibrationWriter(nvm, slot_size=blob_size(0))
    out = w.burn(cal(1), SERIAL, STATION, time=1)
    assert out.ok and out.length == w.slot_size == 220
    with pytest.raises(NVMError, match="nothing was written"):
        CalibrationWriter(nvm, slot_size=blob_size(0)).burn(
            Calibration("12", np.eye(3), np.zeros(3), input_units="counts", input_per_g=4096.0, temperature=TABLE),
            SERIAL, STATION, time=2)


def test_a_restore_whose_safe_order_is_b_then_a_lands_the_backup_byte_for_byte(tmp_path):
    """Backup: A generation 1, B generation 2 (newest).  Board now: A generation 5 (newest), B 4.
    Writing A first would leave B generation 4 newest (neither the board's nor the backup's newest)
    if power failed after it: the restore writes B, then A, and ends with the backup's image."""
    nvm = EEPROM24(4096, 32)
    w = CalibrationWriter(nvm)
    for t in (1, 2):
        w.burn(cal(t), SERIAL, STATION, time=t)
    w.backup(tmp_path / "b.json")
    saved = w.image()
    for t in (3, 4, 5):
        w.burn(cal(t), SERIAL, STATION, time=t)
    assert [s.generation for s in w.status()] == [5, 4]
    w.restore(tmp_path / "b.json")
    assert w.image() == saved
    assert w.read_newest(SERIAL)[1].generation == 2

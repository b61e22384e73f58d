"""`nvm restore` is as power-safe as a burn: after a power loss at ANY page write and ANY
byte count within it, the board's newest valid blob is, bit for bit, either its previous
newest blob or the image's newest blob (issue 12).  The sweep counts every injected fault."""
from __future__ import annotations

import numpy as np
import pytest

from accelcal_station.calibration import Calibration
from accelcal_station.drivers.eeprom import EEPROM24, PowerLossError
from accelcal_station.errors import NVMError
from accelcal_station.nvm.writer import CalibrationWriter

SERIAL, STATION = "SN-0001", "station-1"
SIZE, PAGE = 512, 16  # two 256-byte slots of 16 pages (a 220-byte blob fits): every page write is swept


class _Clock:
    """A virtual clock so write cycles cost no wall time."""

    def __init__(self):
        self.t = 0.0

    def now(self):
        return self.t

    def sleep(self, dt):
        self.t += max(dt, 0.0)


def cal(seed: int) -> Calibration:
    rng = np.random.default_rng(seed)
    return Calibration("12", np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.02, 3),
                       input_units="counts", input_per_g=4096.0)


def board(burns: int, first_seed: int) -> EEPROM24:
    e = EEPROM24(SIZE, PAGE, clock=_Clock())
    w = CalibrationWriter(e)
    for i in range(burns):
        w.burn(cal(first_seed + i), SERIAL, STATION, time=1.7e9 + i)
    return e


def newest_blob(e: EEPROM24) -> bytes | None:
    """Bytes of the newest valid blob (header length), read straight from the cells."""
    w = CalibrationWriter(e)
    got = w.read_newest()
    if got is None:
        return None
    i = 0 if got[2] == "A" else 1
    return bytes(e.read(w.slot_addr(i), got[1].length))


# (burns on the board, burns in the image): the image's generations older, newer, equal,
# its newest in either slot, one slot blank -- the failing case is an image older
# than the board whose other slot is newer than the board's newest.  An image with no valid
# calibration at all is refused before any write (test_cli_nvm.py, test_restore_refuses_...).
SCENARIOS = [(3, 1), (1, 3), (2, 2), (0, 2), (2, 1)]


def sweep(burns_board: int, burns_image: int, tmp_path) -> tuple[int, int]:
    img_board = board(burns_image, 100)
    CalibrationWriter(img_board).backup(tmp_path / "img.json", overwrite=True)
    want_image = newest_blob(img_board)
    faults = survived = 0
    start = board(burns_board, 1).cells.copy()
    k = 1
    while True:
        for nbytes in range(PAGE + 1):
            e = EEPROM24(SIZE, PAGE, clock=_Clock())
            e.cells[:] = start
            before = newest_blob(e)
            e.inject_power_loss(at_write=k, fail_bytes=nbytes)
            try:
                CalibrationWriter(e).restore(tmp_path / "img.json")
            except NVMError as err:
                assert isinstance(err, PowerLossError) or "power loss" in str(err)
            else:
                return faults, survived  # the restore needs fewer than k page writes: sweep done
            faults += 1
            got = newest_blob(e)
            assert got in (before, want_image), (
                f"board {burns_board} burns, image {burns_image}: power loss at page write {k}, "
                f"{nbytes} bytes: newest blob is neither the board's previous nor the image's")
            survived += 1
        k += 1


@pytest.mark.parametrize("burns_board,burns_image", SCENARIOS)
def test_restore_survives_power_loss_at_every_page_write_and_byte(burns_board, burns_image, tmp_path):
    faults, survived = sweep(burns_board, burns_image, tmp_path)
    assert faults >= 2 * (SIZE // 2 // PAGE) * (PAGE + 1) - 1 or burns_board == burns_image == 0
    assert survived == faults
    # power is back: a full restore leaves the image bit for bit
    e = board(burns_board, 1)
    CalibrationWriter(e).restore(tmp_path / "img.json")
    assert bytes(e.read(0, SIZE)) == bytes(board(burns_image, 100).read(0, SIZE))

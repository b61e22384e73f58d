"""The simulated board's EEPROM (drivers/eeprom.py): its NVM face (pages, write cycles on the board's
clock), power loss mid-page, and its I2C face (24-series page roll-over, NACK while busy)."""
from __future__ import annotations

import errno

import pytest

from accelcal_station.drivers.eeprom import EEPROM24, PowerLossError
from accelcal_station.drivers.simulated import SimulatedBoard, VirtualClock
from accelcal_station.errors import DeviceError, NVMError


def test_eeprom_nvm_face_splits_pages_and_waits_write_cycles():
    clock = VirtualClock()
    e = EEPROM24(clock=clock)
    assert e.read(0, 4) == b"\xff" * 4  # erased
    data = bytes(range(40))
    e.write(20, data)  # 20..59 spans pages 0 (20..31) and 1 (32..59)
    assert e.page_writes == 2 and clock.now() == pytest.approx(0.010)
    assert e.read(20, 40) == data and e.read(19, 1) == b"\xff" and e.read(60, 1) == b"\xff"
    with pytest.raises(DeviceError, match="outside 0..4096"):
        e.read(4090, 10)


def test_eeprom_power_loss_leaves_a_partly_written_page():
    e = EEPROM24(clock=VirtualClock(), fail_at_write=2)
    e.write(0, b"A" * 32)
    with pytest.raises(PowerLossError, match="page write 2 at 0x0020: 16 of 32 bytes"):
        e.write(32, b"B" * 64)
    assert isinstance(PowerLossError("x"), NVMError)
    assert e.read(0, 96) == b"A" * 32 + b"B" * 16 + b"\xff" * 48
    e.write(32, b"C" * 32)  # one-shot: power is back
    assert e.read(32, 32) == b"C" * 32
    e.inject_power_loss(1, fail_bytes=3)
    with pytest.raises(PowerLossError):
        e.write(64, b"D" * 8)
    assert e.read(64, 8) == b"DDD" + b"\xff" * 5


def test_eeprom_i2c_face_rolls_over_within_the_page_and_nacks_while_busy():
    clock = VirtualClock()
    e = EEPROM24(clock=clock)
    e.i2c_write(bytes([0x00, 30]) + b"wxyz")  # 30, 31, then wraps to 0, 1 of the same page
    with pytest.raises(OSError) as busy:
        e.i2c_write(bytes([0, 0]))
    assert busy.value.errno == errno.EREMOTEIO == 121
    with pytest.raises(OSError):
        e.i2c_read(1)
    clock.sleep(0.005)
    e.i2c_write(bytes([0, 0]))  # set the pointer (random read)
    assert e.i2c_read(2) == b"yz" and e.i2c_read(1) == b"\xff"
    e.i2c_write(bytes([0, 30]))
    assert e.i2c_read(2) == b"wx"
    e.i2c_write(bytes([0x0F, 0xFF]))  # last byte; sequential reads roll over to 0
    assert e.i2c_read(3) == b"\xff" + b"yz"
    e.i2c_write(bytes([0, 64]) + bytes(range(40)))  # more than a page: the last 32 bytes sent win
    clock.sleep(0.005)
    e.i2c_write(bytes([0, 64]))
    page = e.i2c_read(32)
    assert page == bytes(range(32, 40)) + bytes(range(8, 32))


def test_board_eeprom_uses_the_board_clock_and_config():
    b = SimulatedBoard.from_config({"eeprom": {"size_bytes": 8192, "page_bytes": 64, "write_cycle_ms": 10,
                                               "fail_at_write": 1}})
    assert (b.eeprom.size, b.eeprom.page_size) == (8192, 64)
    with pytest.raises(PowerLossError):
        b.eeprom.write(0, b"x" * 10)
    t = b.clock.now()
    b.eeprom.write(0, b"y" * 10)
    assert b.clock.now() == pytest.approx(t + 0.010)


# -- jig --------------------------------------------------------------------------------------

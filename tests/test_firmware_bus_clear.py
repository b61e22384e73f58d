"""The bridge firmware clears a held I2C bus at start-up and leaves the AVR's internal pull-ups off
(issue 49; docs/firmware.md, "Wiring and the I2C bus"), run on a simulated ATmega328P.

The harness models the I2C pins before the TWI takes them: with ``sda_held_clocks=N`` the MPU-6050 holds
SDA low at power-on (left mid-byte by a reset) until it has seen N SCL clocks.  What the test expects is
the I2C specification's (NXP UM10204, 3.1.16 "Bus clear": up to nine clocks, then a STOP) and the
ATmega328P data sheet's (PORTC bits 4 and 5 are SDA and SCL's pull-up enables when TWI is on), written
here, not read from the firmware."""
from __future__ import annotations

import pytest
from test_mpu6050_firmware import FACTORY, LINK, require_simavr

from accelcal_station.drivers.mpu6050 import MPU6050Bridge
from accelcal_station.drivers.mpu6050_simavr import SimavrBridge
from accelcal_station.drivers.simulated import SimulatedBoard

UM10204_MAX_CLOCKS = 9


@pytest.mark.parametrize("held", [0, 1, 5, 9])
def test_a_held_sda_is_clocked_free_then_stopped_and_the_bridge_answers(held):
    require_simavr()
    board = SimulatedBoard.from_config(None, chip="mpu6050", seed=11)
    with SimavrBridge(board, factory_offsets=FACTORY, sda_held_clocks=held) as sim:
        dev = MPU6050Bridge(sim.port, **LINK["simavr"])
        with dev:
            ident = dev.identify()
        st = sim.stats()
    assert ident.chip_id == 0x68  # the chip answered over the bus the firmware cleared
    assert st["sda_held"] == 0  # released
    # as many clocks as the slave needed, never more than nine, none on a free bus
    assert st["scl_clocks"] == held and held <= UM10204_MAX_CLOCKS
    assert st["bus_stops"] >= 1  # the STOP after the clocks
    assert st["portc_sda_scl"] == 0  # the internal pull-ups (to 5 V) off once the TWI runs


def test_a_slave_that_never_lets_go_gets_nine_clocks_only():
    """More than nine clocks cannot help (a slave mid-byte releases within nine): the firmware stops
    there and boots all the same (simavr's TWI does not model the pins, so the chip still answers here;
    on a real bus the driver names the I2C error: test_station_faults.py)."""
    require_simavr()
    board = SimulatedBoard.from_config(None, chip="mpu6050", seed=12)
    with SimavrBridge(board, factory_offsets=FACTORY, sda_held_clocks=40) as sim:
        dev = MPU6050Bridge(sim.port, **LINK["simavr"])
        with dev:
            dev.identify()
        st = sim.stats()
    assert st["scl_clocks"] == UM10204_MAX_CLOCKS and st["sda_held"] == 1

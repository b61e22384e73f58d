"""A jig's move takes settle + angle / rated speed (issue 51): the expected seconds are written from the
config's numbers (configs/sim.yaml: rated_speed_dps 100, settle_s 0.2), not taken from the code."""
from __future__ import annotations

import pytest

from accelcal_station.config.schema import validate_jig
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.factory import jig_motion
from accelcal_station.fixtures.jig_motion import JigMotion
from accelcal_station.fixtures.simulated_jig import SimulatedJig

SIM = JigMotion(rated_speed_dps=100.0, settle_s=0.2)


def test_move_time_from_angle():
    assert SIM.move_time_s(90.0) == pytest.approx(0.2 + 0.9)   # 90 deg at 100 deg/s, then 0.2 s settle
    assert SIM.move_time_s(180.0) == pytest.approx(2.0)        # the largest reorientation keeps today's 2.0 s
    assert SIM.largest_move_s == pytest.approx(2.0)
    assert SIM.move_time_s(0.0) == 0.0                         # the jig stays where it is


def test_the_config_states_the_motion():
    m = jig_motion(validate_jig({"type": "simulated", "rated_speed_dps": 50, "settle_s": 0.5}))
    assert m is not None and m.move_time_s(90.0) == pytest.approx(0.5 + 90 / 50)
    fixed = jig_motion(validate_jig({"type": "simulated", "move_time_s": 1.5}))
    assert fixed is not None and fixed.move_time_s(10.0) == fixed.move_time_s(180.0) == 1.5


def test_the_simulated_jig_spends_the_move_on_the_boards_clock():
    board = SimulatedBoard.from_config({"effects": {}}, chip="mma8451", seed=1)
    jig = SimulatedJig(board, motion=SIM)
    jig.present(PoseSpec("x-up", -90.0, 0.0))  # from home (flat, z up): a quarter turn
    assert board.clock.now() == pytest.approx(1.1)
    jig.present(PoseSpec("x-down", 90.0, 0.0))  # a half turn
    assert board.clock.now() == pytest.approx(1.1 + 2.0)
    assert jig.moves_s == pytest.approx(3.1)

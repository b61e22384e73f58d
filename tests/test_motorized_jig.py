"""The motorized jig: host driver against the controller emulator on a real pseudo-terminal."""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
import serial

from accelcal_station.config.schema import validate_jig
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.errors import ConfigError, DeviceError
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.factory import make_jig
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator, run_jig_emulator_forever
from accelcal_station.fixtures.motorized_jig import (
    JigAxes,
    JigLink,
    MotorizedJig,
    checksum,
    frame,
    move_time_s,
    profile_deg,
    unframe,
)

# fast motion so the suite stays quick: a 180 degree move takes 0.085 s
FAST = {"speed_deg_s": 4000.0, "accel_deg_s2": 100000.0}


class ManualClock:
    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t


@pytest.fixture
def emu():
    e = JigEmulator(EmulatedAxes(**FAST))
    e.start()
    yield e
    e.stop()


def jig_for(e: JigEmulator, **kw) -> MotorizedJig:
    """The jig on the emulator's port; keywords go to its link (JigLink) or its axes (JigAxes) by name."""
    kw = {"timeout_s": 0.2, "move_margin_s": 0.3, **kw}
    link = {k: v for k, v in kw.items() if k in JigLink.__dataclass_fields__}
    return MotorizedJig(e.port, JigLink(**link), JigAxes(**{k: v for k, v in kw.items() if k not in link}))


def raw_session(port: str):
    return serial.Serial(port, 115200, timeout=0.5)


def ask(ser: serial.Serial, line: bytes) -> str:
    ser.write(line)
    reply = ser.readline()
    payload = unframe(reply)
    assert payload is not None, f"controller sent a line without a valid checksum: {reply!r}"
    return payload


# -- protocol pieces ----------------------------------------------------------------------

def test_checksum_is_nmea_xor():
    # NMEA's own example sentence body and its published checksum
    assert checksum("GPGLL,5300.97914,N,00259.98174,E,125926,A") == "28"
    assert frame("ID?") == b"ID?*32\n"
    assert unframe(b"ID?*32\r\n") == "ID?"
    assert unframe(b"ID?*33\n") is None
    assert unframe(b"ID?\n") is None and unframe(b"ID?\n", require_checksum=False) == "ID?"
    assert unframe(b"\xffID?*32\n") is None


def test_trapezoid_profile_is_continuous_and_ends_at_target():
    for d in (0.5, 90.0, -200.0):  # triangular, trapezoidal, negative
        total = move_time_s(d, 30.0, 90.0)
        t = np.linspace(0, total, 2001)
        s = np.array([profile_deg(d, 30.0, 90.0, x) for x in t])
        assert s[0] == 0.0 and s[-1] == pytest.approx(d)
        assert np.all(np.diff(s) * np.sign(d) >= -1e-12)  # monotone towards the target
        # velocity never exceeds the speed limit (finite differences of a continuous curve)
        assert np.max(np.abs(np.diff(s) / np.diff(t))) <= 30.0 + 1e-6
        assert profile_deg(d, 30.0, 90.0, total / 2) == pytest.approx(d / 2)  # symmetric profile
    assert move_time_s(90.0, 30.0, 90.0) == pytest.approx(90 / 30 + 30 / 90)
    assert move_time_s(2.5, 30.0, 90.0) == pytest.approx(2 * np.sqrt(2.5 / 90))


# -- the controller (emulator) on the wire ---------------------------------------------------

def test_controller_replies_identify_limits_and_errors(emu):
    with raw_session(emu.port) as s:
        assert ask(s, b"ID?\n") == "ID ACCELCAL-JIG2 EMU0001 1.0"
        assert ask(s, frame("limits?")) == "LIMITS -100.000 100.000 -190.000 190.000"
        assert ask(s, b"MOVE 10 10\n").startswith("ERR 4 NOT_HOMED")
        assert ask(s, b"FROB\n") == "ERR 1 UNKNOWN_COMMAND FROB"
        assert ask(s, b"MOVE 10\n").startswith("ERR 2 BAD_ARGUMENT")
        assert ask(s, b"MOVE 10 nan\n").startswith("ERR 2 BAD_ARGUMENT")
        assert ask(s, b"MOVE 10 10*00\n").startswith("ERR 3 CHECKSUM")
        assert ask(s, b"X" * 200 + b"\n").startswith("ERR 9 LINE_TOO_LONG")
        assert ask(s, b"HOME\n") == "OK HOME"
        time.sleep(0.05)
        assert ask(s, b"STATUS?\n") == "STATUS IDLE 0.000 0.000 1 0"
        assert ask(s, frame("MOVE 120 0")) == "ERR 5 SOFT_LIMIT A 120.000 outside -100.000..100.000"
        assert ask(s, frame("MOVE 0 -190.5")).startswith("ERR 5 SOFT_LIMIT B -190.500")
        # blank lines are ignored: the next reply is the STATUS
        assert ask(s, b"\n\r\nSTATUS?\n").startswith("STATUS IDLE")


def test_motion_follows_the_trapezoid_on_an_injected_clock():
    clock = ManualClock()
    with JigEmulator(EmulatedAxes(speed_deg_s=30.0, accel_deg_s2=90.0, homed=True), clock=clock) as e, \
            raw_session(e.port) as s:
        assert ask(s, frame("MOVE 90 -20")) == "OK MOVE"
        total = move_time_s(90.0, 30.0, 90.0)
        clock.t += 0.5  # 0.5 s in: A still ramping (1/3 s ramp) -> 5 + 30 * (0.5 - 1/3) deg
        st = ask(s, frame("STATUS?")).split()
        assert st[1] == "MOVING" and float(st[2]) == pytest.approx(10.0, abs=0.005)
        assert float(st[3]) == pytest.approx(profile_deg(-20.0, 30.0, 90.0, 0.5), abs=0.005)
        assert ask(s, frame("MOVE 10 10")) == "ERR 6 BUSY MOVING"
        assert ask(s, frame("MOVE 90 -20")) == "OK MOVE"  # a resend of the move under way
        assert ask(s, frame("SPEED 10")) == "ERR 6 BUSY MOVING"
        clock.t += total / 2 - 0.5  # half the move time: half the distance on the longer axis
        assert float(ask(s, frame("STATUS?")).split()[2]) == pytest.approx(45.0, abs=0.005)
        clock.t += total / 2 - 1e-3
        assert ask(s, frame("STATUS?")).split()[1] == "MOVING"
        clock.t += 2e-3
        assert ask(s, frame("STATUS?")) == "STATUS IDLE 90.000 -20.000 1 0"
        # STOP freezes the axes where they are
        assert ask(s, frame("MOVE 0 -20")) == "OK MOVE"
        clock.t += total / 2
        assert ask(s, frame("STOP")) == "OK STOP"
        clock.t += 10
        assert ask(s, frame("STATUS?")) == "STATUS IDLE 45.000 -20.000 1 0"


def test_controller_fault_latches_until_clear_and_loses_homing():
    clock = ManualClock()
    with JigEmulator(EmulatedAxes(homed=True), clock=clock) as e, raw_session(e.port) as s:
        e.inject("fault")
        assert ask(s, frame("MOVE 60 0")) == "OK MOVE"
        clock.t += 60
        status = ask(s, frame("STATUS?"))
        assert status.startswith("STATUS ERROR") and status.endswith(" 0 8")
        assert ask(s, frame("MOVE 0 0")).startswith("ERR 7 FAULT")
        assert ask(s, frame("CLEAR")) == "OK CLEAR"
        assert ask(s, frame("STATUS?")).endswith(" 0 0") and ask(s, frame("MOVE 0 0")).startswith("ERR 4")


# -- the host driver ------------------------------------------------------------------------

def test_open_identifies_and_homes():
    with JigEmulator(EmulatedAxes(position_deg=(30.0, -40.0), **FAST)) as e:
        jig = jig_for(e)
        with jig:
            assert jig.identity == "ACCELCAL-JIG2 EMU0001 1.0"
            assert jig.limits_deg.tolist() == [[-100, 100], [-190, 190]]
            st = jig.status()
            assert (st.state, st.a_deg, st.b_deg, st.homed) == ("IDLE", 0.0, 0.0, True)
        assert e.received[0] == "ID?" and "HOME" in e.received
        jig.close()  # safe twice


def test_open_sets_the_configured_speed(emu):
    with jig_for(emu, speed_deg_s=1500.0) as jig:
        assert (jig.speed_deg_s, jig.accel_deg_s2) == (1500.0, FAST["accel_deg_s2"])
    assert emu.speed_deg_s == 1500.0


@pytest.mark.parametrize("design", ["an4399-8", "six-face"])
def test_presents_every_pose_of_a_design(emu, design):
    with jig_for(emu) as jig:
        for pose in get_design(design):
            jig.present(pose)
            held = emu.pose()
            # the axes hold an orientation with the same expected output, within tolerance:
            # 0.02 deg moves a unit vector by at most 0.02 * pi / 180 * sqrt(2) per component
            np.testing.assert_allclose(held.reference_g, pose.reference_g, atol=5e-4)
            st = jig.status()
            assert st.state == "IDLE" and st.homed


def test_attached_board_is_at_the_pose_when_the_jig_reports_idle():
    board = SimulatedBoard.from_config(None, chip="mma8451", seed=7)  # ideal chip: noise and LSB only
    with JigEmulator(EmulatedAxes(position_deg=(40.0, 100.0), **FAST), board=board) as e, jig_for(e) as jig:
        assert board.pose.name == "jig A0.000 B0.000"  # homed on open: the board lies flat
        for pose in get_design("an4399-8"):
            jig.present(pose)
            np.testing.assert_allclose(board.true_direction, pose.reference_g, atol=5e-4)
            counts, _ = board.read(100)
            # mean of 100 samples: noise 2.9 counts / sqrt(100) = 7e-5 g, 1 LSB = 2.4e-4 g;
            # 2e-3 g is > 20 sigma away (false-failure rate < 1e-50, and the seed is fixed)
            np.testing.assert_allclose(counts.mean(axis=0) / board.counts_per_g, pose.reference_g, atol=2e-3)


def test_axis_mapping_and_equivalent_poses():
    lim = ((-100, 100), (-100, 100))
    with JigEmulator(EmulatedAxes(limits_deg=lim, axis_sign=(-1, 1), axis_offset_deg=(2.5, 0), **FAST)) as e, \
            jig_for(e, axis_sign=(-1, 1), axis_offset_deg=(2.5, 0)) as jig:
        np.testing.assert_allclose(jig.axes_for(PoseSpec("a", 85.0, 0.0)), [-82.5, 0.0])
        # roll 170 is outside B: pitch 180 - 85 with roll 170 + 180 - 360 reads the same
        pose = PoseSpec("b", 85.0, 170.0)
        np.testing.assert_allclose(jig.axes_for(pose), [-95.0 + 2.5, -10.0])
        jig.present(pose)
        np.testing.assert_allclose(e.pose().reference_g, pose.reference_g, atol=5e-4)
        # roll 180 needs B = 180 or A = -180 + 2.5: neither is inside the limits
        with pytest.raises(DeviceError, match=r"pose 'z-1g' .*outside the soft limits A -100..100, B -100..100"):
            jig.present(PoseSpec("z-1g", 0.0, 180.0))
        assert [c for c in e.received if c.startswith("MOVE")] == ["MOVE -92.500 -10.000"]
    with JigEmulator(EmulatedAxes(axis_sign=(-1, -1), axis_offset_deg=(3.0, -4.0), **FAST)) as e, \
            jig_for(e, axis_sign=(-1, -1), axis_offset_deg=(3.0, -4.0)) as jig:
        for pose in get_design("an4399-8"):
            jig.present(pose)
            np.testing.assert_allclose(e.pose().reference_g, pose.reference_g, atol=5e-4)


def test_roll_wraps_to_the_nearer_turn(emu):
    with jig_for(emu) as jig:
        jig.present(PoseSpec("a", 0.0, -170.0))
        jig.present(PoseSpec("b", 0.0, 175.0))  # -185 is 15 deg away, +175 is 345
        assert emu.position_deg() == pytest.approx((0.0, -185.0))


def test_not_homed_is_reported_by_the_controller(emu):
    with jig_for(emu, home_on_open=False) as jig, pytest.raises(DeviceError) as exc:
        jig.present(PoseSpec("p", 10.0, 0.0))
    assert str(exc.value) == f"jig on {emu.port}: 'MOVE 10.000 0.000' refused: ERR 4 NOT_HOMED send HOME first"


def test_stall_times_out_with_a_one_line_error(emu):
    with jig_for(emu) as jig:
        emu.inject("stall")
        t0 = time.monotonic()
        with pytest.raises(DeviceError) as exc:
            jig.present(PoseSpec("p", 90.0, 0.0))
        waited = time.monotonic() - t0
        limit = 1.5 * move_time_s(90.0, FAST["speed_deg_s"], FAST["accel_deg_s2"]) + 0.3
        assert limit <= waited < limit + 1.0
        msg = str(exc.value)
        assert msg.startswith(f"jig on {emu.port}: 'MOVE 90.000 0.000' did not reach A 90.000 B 0.000 within")
        assert "still MOVING at A 45.000" in msg and "\n" not in msg
        assert emu.received[-1] == "STOP" and jig.status().state == "IDLE"
        jig.present(PoseSpec("p", 90.0, 0.0))  # the next move works again
        assert emu.position_deg() == (90.0, 0.0)


def test_controller_stall_fault_is_reported_and_cleared_on_reopen(emu):
    jig = jig_for(emu)
    with jig:
        emu.inject("fault")
        with pytest.raises(DeviceError, match=r"'MOVE 90.000 0.000' failed: controller error 8 STALL at A 45.000"):
            jig.present(PoseSpec("p", 90.0, 0.0))
    with jig:  # open() clears the latched fault and homes again
        st = jig.status()
        assert (st.state, st.homed, st.error, st.a_deg) == ("IDLE", True, 0, 0.0)
    assert emu.received.count("CLEAR") == 1 and emu.received.count("HOME") == 2


def test_garbled_reply_is_retried(emu):
    with jig_for(emu) as jig:
        n = len(emu.received)
        emu.inject("garbage")
        jig.present(PoseSpec("p", 20.0, 0.0))  # garbage replaces the first STATUS? reply
        assert emu.received[n:n + 2] == ["STATUS?", "STATUS?"]
        emu.inject("noise")
        n = len(emu.received)
        jig.present(PoseSpec("q", -20.0, 0.0))  # noise before the reply: no resend needed
        assert emu.received[n:n + 2] == ["STATUS?", "MOVE -20.000 0.000"]
        assert emu.position_deg() == (-20.0, 0.0)
        emu.inject("error", code=3)  # the controller saw a corrupted command: resend
        jig.present(PoseSpec("r", 0.0, 10.0))
        assert emu.position_deg() == (0.0, 10.0)


def test_garbage_forever_gives_up_after_bounded_retries(emu):
    with jig_for(emu, retries=2) as jig:
        emu.inject("garbage", count=None)
        n = len(emu.received)
        with pytest.raises(DeviceError) as exc:
            jig.status()
    assert str(exc.value).startswith(f"jig on {emu.port}: 'STATUS?': garbled reply b'\\xfeST")
    assert str(exc.value).endswith("(3 attempts)") and len(emu.received) - n == 3


def test_no_answer(emu):
    with jig_for(emu, retries=1) as jig:
        emu.inject("silent", count=None)
        t0 = time.monotonic()
        with pytest.raises(DeviceError) as exc:
            jig.present(PoseSpec("p", 10.0, 0.0))
        assert time.monotonic() - t0 < 1.0
    assert str(exc.value) == f"jig on {emu.port}: 'STATUS?': no answer within 0.2 s (2 attempts)"


def test_one_lost_reply_is_recovered(emu):
    with jig_for(emu) as jig:
        emu.inject("silent")
        jig.present(PoseSpec("p", 10.0, 0.0))
        assert emu.position_deg() == (10.0, 0.0)


def test_controller_error_is_not_retried(emu):
    with jig_for(emu) as jig:
        n = len(emu.received)
        emu.inject("error", code=7)
        with pytest.raises(DeviceError) as exc:
            jig.status()
        assert len(emu.received) == n  # the injected error answers without executing
    assert str(exc.value) == f"jig on {emu.port}: 'STATUS?' refused: ERR 7 FAULT injected fault"


def test_disconnect(emu):
    with jig_for(emu) as jig:
        emu.inject("disconnect")
        with pytest.raises(DeviceError, match=rf"^jig on {emu.port}: 'STATUS\?': connection lost"):
            jig.present(PoseSpec("p", 10.0, 0.0))
        deadline = time.monotonic() + 2.0  # the host may notice before the thread has returned
        while emu.running and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not emu.running


def test_open_errors_are_one_line(tmp_path):
    with pytest.raises(DeviceError, match=r"^jig on .*nope: cannot open"):
        MotorizedJig(str(tmp_path / "nope")).open()
    with JigEmulator(EmulatedAxes(**FAST)) as e:
        e.inject("silent", count=None)
        jig = jig_for(e, retries=0)
        with pytest.raises(DeviceError, match=r"'ID\?': no answer"):
            jig.open()
        assert jig._ser is None  # a failed open releases the port
    with pytest.raises(DeviceError, match="not open"):
        MotorizedJig("/dev/null").status()


def test_controller_with_zero_speed_is_refused_at_open():
    # move_time_s() divides by speed and acceleration: a controller reporting 0 must not reach it
    with JigEmulator(EmulatedAxes(speed_deg_s=0.0, accel_deg_s2=0.0, homed=True)) as e:
        jig = jig_for(e, home_on_open=False)
        with pytest.raises(DeviceError, match=r"'SPEED\?': speed 0 deg/s, acceleration 0 deg/s\^2; both must be > 0"):
            jig.open()
        assert jig._ser is None


def test_non_finite_status_position_is_malformed():
    # a NaN position would pass the arrival check (NaN > tolerance is False)
    with JigEmulator(EmulatedAxes(position_deg=(float("nan"), 0.0), homed=True, **FAST)) as e:
        jig = jig_for(e, home_on_open=False)
        with pytest.raises(DeviceError, match=r"'STATUS\?': malformed reply 'STATUS IDLE nan 0.000 1 0'"):
            jig.open()  # open() reads STATUS? once
        assert jig._ser is None


def test_emulator_shuts_down_cleanly():
    before = set(threading.enumerate())
    fds = len(os.listdir("/proc/self/fd"))
    for _ in range(3):
        e = JigEmulator(EmulatedAxes(**FAST))
        e.start()
        with jig_for(e) as jig:
            jig.present(PoseSpec("p", 5.0, 5.0))
        e.stop()
        e.stop()  # safe twice
        assert not e.running
    assert set(threading.enumerate()) == before
    assert len(os.listdir("/proc/self/fd")) == fds


def test_run_forever_serves_behind_a_link_until_stopped(tmp_path):
    link = tmp_path / "jig0"
    stop, lines = threading.Event(), []
    t = threading.Thread(target=run_jig_emulator_forever,
                         kwargs={"link": str(link), "stop": stop, "announce": lines.append,
                                 "axes": EmulatedAxes(homed=True, **FAST)})
    t.start()
    try:
        for _ in range(200):
            if link.is_symlink():
                break
            time.sleep(0.01)
        with MotorizedJig(str(link), JigLink(timeout_s=0.2)) as jig:
            jig.present(PoseSpec("p", -30.0, 60.0))
            assert jig.status().a_deg == -30.0
    finally:
        stop.set()
        t.join(timeout=5)
    assert not t.is_alive() and not link.exists() and lines[0].startswith("jig emulator on /dev/pts/")


# -- configuration --------------------------------------------------------------------------

def test_from_config():
    jig = make_jig(validate_jig({"type": "motorized", "port": "/dev/ttyUSB0", "baud": 57600, "speed_deg_s": 40,
                                 "axis_sign": [1, -1], "axis_offset_deg": [0.5, -1], "home_on_open": False}), None)
    assert isinstance(jig, MotorizedJig)
    assert (jig.port, jig.baud, jig.home_on_open, jig._speed_cfg) == ("/dev/ttyUSB0", 57600, False, 40.0)
    assert jig.axis_sign.tolist() == [1, -1] and jig.axis_offset_deg.tolist() == [0.5, -1]


@pytest.mark.parametrize("cfg, message", [
    ({"port": "/dev/x", "sped": 3}, r"^jig\.sped: unknown key; allowed: type, port, baud"),
    ({}, r"^jig\.port: required"),
    ({"port": "/dev/x", "timeout_s": -1}, r"^jig\.timeout_s: -1 out of range"),
    ({"port": "/dev/x", "home_on_open": "yes"}, r"^jig\.home_on_open: 'yes'; allowed: true, false"),
    ({"port": "/dev/x", "axis_sign": [1, 2]}, r"^jig\.axis_sign\[1\]: 2; allowed: 1, -1"),
    ({"port": "/dev/x", "axis_offset_deg": 3},
     r"^jig\.axis_offset_deg: 3; allowed: a list \(zero offset of each axis \[pitch, roll\]"),
    ({"port": "/dev/x", "speed_deg_s": 0}, r"^jig\.speed_deg_s: 0 out of range"),
])
def test_bad_config_names_the_key(cfg, message):
    with pytest.raises(ConfigError, match=message):
        make_jig(validate_jig({"type": "motorized", **cfg}), None)

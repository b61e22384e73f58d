"""MPU6050Bridge through pyserial on a real pseudo-terminal, against the bridge emulator.

Noise: the emulated MPU6050 at 2 g has sigma ~55 counts per sample (400 ug/sqrt(Hz) at the
DLPF's equivalent noise bandwidth, pi/2 x 44 Hz), so a mean of n samples has SEM ~55/sqrt(n)
counts; the tolerances below are at least 6.5 SEM (false-failure rate < 1e-10 per assertion,
fixed seeds make runs repeatable).
"""
from __future__ import annotations

import os
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest

from accelcal_station.config.schema import validate_device
from accelcal_station.drivers import bridge_protocol as bp
from accelcal_station.drivers.bridge_link import _McuClock
from accelcal_station.drivers.factory import make_driver
from accelcal_station.drivers.mpu6050 import (
    ACCEL_CONFIG,
    CONFIG,
    PWR_MGMT_1,
    SMPLRT_DIV,
    MPU6050Bridge,
    smplrt_div_for,
    temperature_from_raw,
)
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.errors import AccelcalError, ConfigError, DeviceError

FAST = {"timeout_s": 0.25, "retries": 3, "boot_wait_s": 0.3}


@pytest.fixture
def emu():
    e = MPU6050BridgeEmulator(seed=7, factory_offsets=[1001, -2000, 3])
    e.start()
    yield e
    e.stop()


@pytest.fixture
def dev(emu):
    d = MPU6050Bridge(emu.port, **FAST)
    with d:
        yield d


def no_bridge_threads() -> bool:
    return not any(t.name.startswith("mpu6050-bridge") for t in threading.enumerate())


def one_line(e: Exception) -> str:
    s = str(e)
    assert "\n" not in s and s
    return s


# --- identity, wake, configuration ---------------------------------------------------------
def test_open_identifies_wakes_and_configures(emu, dev):
    ident = dev.identify()
    assert ident.chip == "mpu6050" and ident.chip_id == 0x68
    assert ident.interface == f"serial:{emu.port}" and emu.port.startswith("/dev/")
    assert ident.firmware.startswith("mpu6050-bridge 1.1")
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.read_register(PWR_MGMT_1)[0] == 0x01  # SLEEP cleared, PLL clock
    assert emu.regs[PWR_MGMT_1] & 0x40 == 0
    assert (dev.range_g, dev.odr_hz, dev.dlpf, dev.counts_per_g) == (2, 100.0, 3, 16384.0)
    assert (emu.regs[ACCEL_CONFIG], emu.regs[CONFIG], emu.regs[SMPLRT_DIV]) == (0x00, 3, 9)
    assert bp.CMD_IDENTIFY in emu.commands and bp.CMD_CONFIGURE in emu.commands


@pytest.mark.parametrize("range_g,cpg,afs", [(2, 16384, 0), (4, 8192, 1), (8, 4096, 2), (16, 2048, 3)])
def test_ranges_scale_one_g(emu, dev, range_g, cpg, afs):
    dev.configure(range_g=range_g)
    assert dev.counts_per_g == cpg and emu.regs[ACCEL_CONFIG] == afs << 3 and emu.board.range_g == range_g
    cap = dev.capture(400)
    # flat board, face up: z reads +1 g (MPU-6050 product specification); the ideal chip has no offset or gain error
    sem = 45.0 * cpg / 16384 / np.sqrt(400)
    assert abs(cap.mean_counts[2] - cpg) < 8 * sem + 2
    assert np.all(np.abs(cap.mean_counts[:2]) < 8 * sem + 2)


def test_rate_and_dlpf_set_registers_and_sample_spacing(emu, dev):
    dev.configure(odr_hz=200, dlpf=2)
    assert (emu.regs[SMPLRT_DIV], emu.regs[CONFIG]) == (4, 2) and dev.odr_hz == 200.0
    counts, t, dropped = dev.read_samples(50)
    assert counts.shape == (50, 3) and counts.dtype == np.int64 and dropped == 0
    assert np.allclose(np.diff(t), 1 / 200, atol=2e-6)
    dev.configure(dlpf=0)  # DLPF off: the gyro rate is 8 kHz, so 100 Hz needs SMPLRT_DIV 79
    dev.configure(odr_hz=100)
    assert emu.regs[SMPLRT_DIV] == 79 and emu.regs[CONFIG] == 0 and dev.odr_hz == 100.0
    assert smplrt_div_for(1000, 3) == 0 and smplrt_div_for(50, 1) == 19
    for bad in (300, 0, 2000, "fast"):
        with pytest.raises(ConfigError) as e:
            dev.configure(odr_hz=bad)
        assert "allowed" in one_line(e.value)
    with pytest.raises(ConfigError):
        dev.configure(range_g=3)
    with pytest.raises(ConfigError):
        dev.configure(dlpf=7)
    with pytest.raises(ConfigError):
        dev.configure(oversampling="high")


def test_capture_fields_and_temperature(emu, dev):
    assert temperature_from_raw(-3528) == pytest.approx(26.1535, abs=1e-4)
    with emu.lock:
        emu.board.set_temperature(41.0)
    assert dev.temperature_c() == pytest.approx(41.0, abs=1 / 340)
    cap = dev.capture(200, keep=True)
    assert cap.n == 200 and cap.dropped == 0 and cap.temp_c == pytest.approx(41.0, abs=1 / 340)
    assert np.all(cap.std_counts > 10) and np.all(cap.std_counts < 100)
    assert cap.t_end - cap.t_start == pytest.approx(199 / 100, abs=1e-5)
    assert np.all(np.diff(cap.timestamps) > 0) and cap.samples.shape == (200, 3)
    assert np.allclose(cap.mean_counts, cap.samples.mean(axis=0))
    cap2 = dev.capture(seconds=0.5)
    assert cap2.n == 50 and cap2.t_start > cap.t_end


def test_board_orientation_reaches_the_host(emu, dev):
    with emu.lock:
        emu.board.set_gravity_direction([1.0, 0.0, 0.0])
    cap = dev.capture(400)
    assert abs(cap.mean_counts[0] - 16384) < 30 and abs(cap.mean_counts[2]) < 30


# --- offsets (read-modify-write, bit 0 kept) --------------------------------------------------
def test_offsets_read_modify_write_keep_bit0(emu, dev):
    assert dev.accel_offsets().tolist() == [1001, -2000, 3]
    before = dev.capture(1000).mean_counts
    dev.set_accel_offsets([100, 201, -50])
    # bits 15:1 from the new values, bit 0 as the chip had it (1, 0, 1)
    assert dev.accel_offsets().tolist() == [101, 200, -49]
    assert np.frombuffer(bytes(emu.regs[6:12]), ">i2").tolist() == [101, 200, -49]
    after = dev.capture(1000).mean_counts
    # 2048 LSB per g of offset register, bit 0 ignored: (new - factory) / 2048 g
    want = (np.array([100, 200, -50]) - np.array([1000, -2000, 2])) / 2048 * 16384
    assert np.allclose(after - before, want, atol=12)  # 8 SEM of a difference of two 1000-means ~ 16
    for bad in ([1, 2], [40000, 0, 0], [0.5, 0, 0], ["a", 0, 0]):
        with pytest.raises(ConfigError):
            dev.set_accel_offsets(bad)


# --- NVM -------------------------------------------------------------------------------------
def test_nvm_pages_read_back(emu, dev):
    nvm = dev.nvm
    assert (nvm.size, nvm.page_size) == (1024, 32)
    assert nvm.read(0, 40) == b"\xff" * 40  # erased AVR EEPROM
    blob = bytes(range(256)) * 2
    nvm.write(20, blob[:100])  # starts mid-page, spans four pages
    assert nvm.read(20, 100) == blob[:100]
    assert nvm.read(0, 20) == b"\xff" * 20 and nvm.read(120, 8) == b"\xff" * 8  # neighbours kept
    assert emu.nvm.read(20, 100) == blob[:100]
    with pytest.raises(AccelcalError):
        nvm.read(1000, 100)


def test_nvm_write_survives_power_loss_by_reset_and_retry(emu, dev):
    emu.nvm.inject_power_loss(at_write=1)
    dev.nvm.write(64, b"calibration blob" * 2)
    assert dev.nvm.read(64, 32) == b"calibration blob" * 2
    assert dev.stats.resets == 1
    assert dev.read_register(PWR_MGMT_1)[0] == 0x01  # re-woken after the bridge rebooted


# --- faults ----------------------------------------------------------------------------------
def test_garbage_is_skipped(emu, dev):
    emu.inject_garbage(b"\x00\xff\xa5\x13\x37\xa5\x5a\x05garbage\xa5")
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.stats.parser.garbage_bytes >= 10
    assert dev.capture(100).n == 100


def test_corrupted_samples_are_rejected_and_counted_dropped(emu, dev):
    frames0 = dev.stats.frames
    # STREAM's ACK is 23 bytes, a SAMPLE 24: flip bits in bytes 14-16 of sample index 10
    emu.corrupt(3, after_bytes=23 + 24 * 10 + 14)
    cap = dev.capture(200, keep=True)
    assert dev.stats.parser.crc_errors >= 1
    assert (cap.n, cap.dropped) == (199, 1)
    assert np.round(np.diff(cap.timestamps) * 100).astype(int).tolist().index(2) == 9  # the hole is sample 10
    assert dev.stats.lost_frames == cap.dropped and dev.stats.frames > frames0


def test_corrupted_answer_is_retried(emu, dev):
    emu.corrupt(1, after_bytes=12)  # the next frame is the ACK
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.stats.parser.crc_errors == 1 and dev.stats.retries >= 1 and dev.stats.timeouts >= 1


def test_dropped_samples_from_sequence_gaps(emu, dev):
    emu.drop_frames(5, after_frames=20, types=(bp.RSP_SAMPLE,))
    cap = dev.capture(100, keep=True)
    assert (cap.n, cap.dropped) == (95, 5)
    assert dev.stats.lost_frames == 5 and dev.stats.dropped_samples == 5
    gaps = np.round(np.diff(cap.timestamps) * 100).astype(int)
    assert sorted(gaps.tolist())[-1] == 6 and np.sum(gaps != 1) == 1  # one hole of 5 samples


def test_dropped_last_samples_counted_from_stream_end(emu, dev):
    emu.drop_frames(3, after_frames=97, types=(bp.RSP_SAMPLE,))
    cap = dev.capture(100)
    assert (cap.n, cap.dropped) == (97, 3)


def test_dropped_acks_are_retried(emu, dev):
    emu.drop_frames(1, types=(bp.RSP_ACK,))
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.stats.retries == 1 and dev.stats.lost_frames == 1
    emu.drop_frames(1, types=(bp.RSP_ACK,))  # the STREAM's ACK: the stream is asked for again
    cap = dev.capture(100)
    assert (cap.n, cap.dropped) == (100, 0)
    assert emu.commands.count(bp.CMD_STREAM) >= 2


def test_short_stall_is_ridden_out_by_retries(emu, dev):
    emu.stall(0.4)
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.stats.timeouts >= 1


def test_stall_mid_stream_stops_and_resumes(emu, dev):
    emu.stall(0.4, after_samples=50)
    cap = dev.capture(200)
    assert (cap.n, cap.dropped) == (200, 0)
    assert dev.stats.timeouts >= 2  # the stream, then at least one STOP
    assert bp.CMD_STOP in emu.commands


def test_long_stall_is_a_clear_error_in_bounded_time(emu):
    with MPU6050Bridge(emu.port, timeout_s=0.1, retries=2, boot_wait_s=0.0) as d:
        emu.stall(30.0)
        t0 = time.monotonic()
        with pytest.raises(DeviceError) as e:
            d.read_register(0x75)
        assert time.monotonic() - t0 < 2.0
        msg = one_line(e.value)
        assert "READ_REG failed after 3 attempts" in msg and "no answer" in msg and emu.port in msg


def test_long_stall_mid_stream_is_a_clear_error(emu):
    with MPU6050Bridge(emu.port, timeout_s=0.1, retries=1, boot_wait_s=0.0) as d:
        emu.stall(30.0, after_samples=10)
        with pytest.raises(DeviceError) as e:
            d.capture(100)
        assert "STOP failed after 2 attempts" in one_line(e.value)


def test_reset_mid_stream_reconfigures_and_resumes(emu, dev):
    dev.configure(range_g=4, odr_hz=200)
    emu.reset(after_samples=60)
    cap = dev.capture(300, keep=True)
    assert (cap.n, cap.dropped) == (300, 0) and dev.stats.resets == 1
    assert np.all(np.diff(cap.timestamps) > 0)
    # the rebooted bridge reset the chip; the driver woke it and restored range and rate
    assert emu.regs[PWR_MGMT_1] == 0x01 and emu.regs[ACCEL_CONFIG] == 1 << 3 and emu.regs[SMPLRT_DIV] == 4
    assert abs(cap.mean_counts[2] - 8192) < 30  # no zero samples from a sleeping chip
    assert np.all(cap.samples[:, 2] > 7000)


def test_reset_between_commands_is_recovered(emu, dev):
    dev.configure(range_g=8)
    dev.set_accel_offsets([500, 500, 500])
    emu.reset()
    assert dev.read_register(ACCEL_CONFIG)[0] == 2 << 3  # re-initialised before answering
    assert dev.stats.resets == 1
    assert dev.accel_offsets().tolist() == [501, 500, 501]  # offsets set earlier are restored


def test_repeated_resets_are_a_clear_error(emu, dev):
    emu.reset(after_samples=5, times=10)
    with pytest.raises(DeviceError) as e:
        dev.capture(100)
    msg = one_line(e.value)
    assert "reset" in msg and "power supply" in msg


def test_reset_command(emu, dev):
    dev.configure(range_g=16)
    dev.reset()
    assert bp.CMD_RESET in emu.commands
    assert emu.regs[PWR_MGMT_1] == 0x01 and emu.regs[ACCEL_CONFIG] == 3 << 3
    assert dev.capture(50).n == 50


def test_mcu_timestamps_unwrap_and_bridge_resets():
    c = _McuClock()
    t = [c.seconds(ts) for ts in (2**32 - 20_000, 2**32 - 10_000, 5_000, 15_000)]  # micros() wraps
    assert np.allclose(np.diff(t), [0.01, 0.015, 0.01])
    t_boot = c.seconds(100_000, boot=True)  # the MCU clock restarted: time still goes forward
    assert t_boot >= t[-1] and c.seconds(110_000) == pytest.approx(t_boot + 0.01)


# --- errors at open ----------------------------------------------------------------------------
def test_no_such_port():
    with pytest.raises(DeviceError) as e:
        MPU6050Bridge("/dev/ttyUSB97", **FAST).open()
    assert "/dev/ttyUSB97 does not exist" in one_line(e.value)


def test_permission_denied_mentions_dialout():
    # /proc/sys files of mode 0444 refuse O_RDWR with EACCES even to root, like a
    # dialout-owned tty does to a user outside the group
    with pytest.raises(DeviceError) as e:
        MPU6050Bridge("/proc/sys/kernel/osrelease", **FAST).open()
    msg = one_line(e.value)
    assert "permission denied" in msg and "dialout" in msg


def test_port_in_use(emu, dev):
    with pytest.raises(DeviceError) as e:
        MPU6050Bridge(emu.port, **FAST).open()
    assert "in use" in one_line(e.value)


@pytest.mark.parametrize("who, name", [(0x70, "MPU-6500"), (0x7C, "MPU-6555")])
def test_wrong_chip_names_what_was_found(who, name):
    with MPU6050BridgeEmulator(seed=1, who_am_i=who) as e, pytest.raises(DeviceError) as err:
        MPU6050Bridge(e.port, **FAST).open()
    msg = one_line(err.value)
    # the value's own part named (issue 49: a compatible the config may accept is said to be one)
    assert f"WHO_AM_I (0x75) reads 0x{who:02x} (" in msg and name in msg and "expected 0x68" in msg


def test_no_chip_on_i2c():
    with MPU6050BridgeEmulator(seed=1, i2c_present=False) as e, pytest.raises(DeviceError) as err:
        MPU6050Bridge(e.port, timeout_s=0.1, retries=1, boot_wait_s=0.0).open()
    msg = one_line(err.value)
    assert "no I2C answer" in msg and "SDA/SCL" in msg


def test_silent_port_is_no_answer_in_bounded_time():
    master, slave = os.openpty()  # a terminal nobody answers on
    tty.setraw(slave)
    try:
        t0 = time.monotonic()
        with pytest.raises(DeviceError) as e:
            MPU6050Bridge(os.ttyname(slave), timeout_s=0.1, retries=2, boot_wait_s=0.2).open()
        assert time.monotonic() - t0 < 3.0
        msg = one_line(e.value)
        assert "IDENTIFY failed after 3 attempts (no answer" in msg and "firmware" in msg
    finally:
        os.close(master)
        os.close(slave)


# --- configuration and lifecycle -------------------------------------------------------------------
def test_from_config_checks_keys():
    ok = make_driver(validate_device({"driver": "mpu6050", "port": "/dev/ttyUSB0", "range_g": 8, "odr_hz": 50,
                                      "dlpf": 5}))
    assert isinstance(ok, MPU6050Bridge)
    assert ok.port == "/dev/ttyUSB0" and ok._want == (8, 50.0, 5)
    bad = [({}, "port"), ({"port": 3}, "port"), ({"port": "/dev/ttyUSB0", "odr_hz": 300}, "odr_hz"),
           ({"port": "/dev/ttyUSB0", "range_g": 3}, "range_g"), ({"port": "/dev/ttyUSB0", "bus": 1}, "bus"),
           ({"port": "/dev/ttyUSB0", "seed": 1}, "seed"), ({"port": "/dev/ttyUSB0", "dlpf": 9}, "dlpf")]
    for cfg, key in bad:
        with pytest.raises(ConfigError) as e:
            make_driver(validate_device({"driver": "mpu6050", **cfg}))
        assert f"device.{key}" in one_line(e.value)


def test_port_emulated_through_make_driver():
    with make_driver(validate_device({"driver": "mpu6050", "port": "emulated", "seed": 3, "timeout_s": 0.3})) as d:
        assert d.port.startswith("/dev/") and d.identify().chip_id == 0x68
        assert d.emulator.board.chip.name == "mpu6050"  # the station's simulated jig moves this board
        cap = d.capture(100)
        assert cap.n == 100 and abs(cap.mean_counts[2] - 16384) < 40
    assert no_bridge_threads()
    sim = str(Path(__file__).resolve().parents[1] / "configs" / "sim.yaml")
    with make_driver(validate_device({"driver": "mpu6050", "port": "emulated", "simulator": sim, "seed": 3})) as d:
        # configs/sim.yaml's board: z gain 1.021 and offset +41 mg (SEM 45/sqrt(400) counts, 0.14 mg)
        assert d.capture(400).mean_counts[2] / 16384 == pytest.approx(1.062, abs=0.005)


def test_failed_port_open_stops_the_emulator():
    from accelcal_station.drivers.emulated import EmulatedMPU6050Bridge

    emu = MPU6050BridgeEmulator(seed=2)
    d = EmulatedMPU6050Bridge(emu, baud=-5, **FAST)  # pyserial refuses the baud rate
    with pytest.raises(DeviceError, match="cannot open serial port"):
        d.open()
    assert no_bridge_threads() and emu._master == -1 and emu._slave == -1  # no thread or pty left behind


def test_emulator_stops_cleanly_and_closes_fds():
    e = MPU6050BridgeEmulator(seed=2)
    port = e.start()
    fds = (e._master, e._slave)
    with MPU6050Bridge(port, **FAST) as d:
        d.capture(10)
    e.stop()
    e.stop()  # twice is fine
    assert no_bridge_threads()
    for fd in fds:
        with pytest.raises(OSError):
            os.fstat(fd)

"""The host driver against both bridges: the Python emulator and the real firmware in simavr.

``simavr``: firmware/mpu6050_bridge built with avr-gcc (``make -C firmware``) and run on a
simulated ATmega328P by firmware/sim/mpu6050_sim.c, UART0 on a pseudo-terminal, an MPU6050
register model on TWI fed by the project's SimulatedBoard, the AVR's own EEPROM as NVM.
Without the AVR toolchain and simavr these cases skip with the reason; .ci/run sets
ACCELCAL_REQUIRE_SIMAVR=1, which turns that skip into a failure.

Noise: the simulated MPU6050 at 2 g has sigma ~45 counts per sample; a mean of n samples has
SEM ~45/sqrt(n); tolerances are >= 8 SEM (false-failure rate < 1e-14 per assertion; fixed seeds).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers import bridge_protocol as bp
from accelcal_station.drivers import mpu6050_simavr
from accelcal_station.drivers.bridge_link import BridgeLink, BridgeRefused
from accelcal_station.drivers.mpu6050 import (
    ACCEL_CONFIG,
    CONFIG,
    PWR_MGMT_1,
    SMPLRT_DIV,
    MPU6050Bridge,
)
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.mpu6050_simavr import SimavrBridge
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.errors import DeviceError, NVMError
from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator
from accelcal_station.nvm.writer import CalibrationWriter

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"

FACTORY = (1001, -2000, 3)
LINK = {"python": {"timeout_s": 0.25, "retries": 3, "boot_wait_s": 0.3},
        # simulated MCU time runs about as fast as wall time on a loaded CI core: roomier timeouts
        "simavr": {"timeout_s": 1.0, "retries": 2, "boot_wait_s": 3.0}}


def require_simavr() -> None:
    why = mpu6050_simavr.unavailable_reason()
    if why is None:
        return
    if os.environ.get("ACCELCAL_REQUIRE_SIMAVR"):
        pytest.fail(f"ACCELCAL_REQUIRE_SIMAVR is set but {why}")
    pytest.skip(why)


def make_bridge(kind: str, seed: int = 7):
    board = SimulatedBoard.from_config(None, chip="mpu6050", seed=seed)
    if kind == "simavr":
        require_simavr()
        return SimavrBridge(board, factory_offsets=FACTORY)
    return MPU6050BridgeEmulator(board, factory_offsets=FACTORY)


@pytest.fixture(params=["python", "simavr"])
def bridge(request):
    b = make_bridge(request.param)
    b.start()
    b.kind = request.param
    yield b
    b.stop()


@pytest.fixture
def dev(bridge):
    d = MPU6050Bridge(bridge.port, **LINK[bridge.kind])
    with d:
        yield d


def test_identify_and_wake(bridge, dev):
    ident = dev.identify()
    assert ident.chip == "mpu6050" and ident.chip_id == 0x68
    assert ident.firmware == f"mpu6050-bridge 1.1 (protocol {bp.PROTOCOL_VERSION})"
    assert dev.read_register(0x75)[0] == 0x68
    assert dev.read_register(PWR_MGMT_1)[0] == 0x01  # SLEEP cleared by the driver, PLL clock
    assert (dev.nvm.size, dev.nvm.page_size) == (1024, 32)


def test_configure_sets_registers(bridge, dev):
    dev.configure(range_g=4, odr_hz=200, dlpf=2)
    assert dev.read_register(ACCEL_CONFIG)[0] == 1 << 3
    assert (dev.read_register(CONFIG)[0], dev.read_register(SMPLRT_DIV)[0]) == (2, 4)
    assert bridge.board.range_g == 4  # the simulated sensor follows the chip's range


def test_stream_samples_sequence_and_timestamps(bridge, dev):
    dev.configure(range_g=2, odr_hz=200)
    cap = dev.capture(300, keep=True)
    assert (cap.n, cap.dropped) == (300, 0)
    assert dev.stats.lost_frames == 0 and dev.stats.parser.crc_errors == 0
    # MCU timestamps: one sample every 5 ms on average, each stamped when the bridge saw the chip's
    # DATA_RDY; a look at the chip is one 9-byte I2C burst at 400 kHz (~0.25 ms), the jitter's bound
    dt = np.diff(cap.timestamps)
    assert np.mean(dt) == pytest.approx(1 / 200, rel=1e-3)
    assert np.all(np.abs(dt - 1 / 200) < 4e-4), (dt.min(), dt.max())
    # flat board, z up: +1 g at 16384 counts per g; 8 SEM tolerance
    assert abs(cap.mean_counts[2] - 16384) < 8 * 45 / np.sqrt(300) + 2
    assert cap.temp_c == pytest.approx(bridge.board.temperature_c, abs=1 / 340)


def test_board_orientation_reaches_the_host(bridge, dev):
    dev.configure(odr_hz=200)
    with bridge.lock:
        bridge.board.set_gravity_direction([1.0, 0.0, 0.0])
    cap = dev.capture(300)
    assert abs(cap.mean_counts[0] - 16384) < 30 and abs(cap.mean_counts[2]) < 30


def test_register_write_read_offsets_shift_output(bridge, dev):
    dev.configure(odr_hz=200)
    assert dev.accel_offsets().tolist() == list(FACTORY)
    before = dev.capture(400).mean_counts
    dev.set_accel_offsets([100, 201, -50])
    assert dev.accel_offsets().tolist() == [101, 200, -49]  # bit 0 kept as the chip had it
    after = dev.capture(400).mean_counts
    want = (np.array([100, 200, -50]) - np.array([1000, -2000, 2])) / 2048 * 16384
    assert np.allclose(after - before, want, atol=8 * 45 * np.sqrt(2 / 400) + 2)


def test_nvm_pages_write_and_read(bridge, dev):
    nvm = dev.nvm
    assert nvm.read(0, 40) == b"\xff" * 40  # erased AVR EEPROM
    blob = bytes(range(256))[:100]
    nvm.write(20, blob)  # starts mid-page, spans four pages
    assert nvm.read(20, 100) == blob
    assert nvm.read(0, 20) == b"\xff" * 20 and nvm.read(120, 8) == b"\xff" * 8


def test_reset_mid_stream_reconfigures_and_resumes(bridge, dev):
    dev.configure(range_g=4, odr_hz=200)
    bridge.reset(after_samples=60)
    cap = dev.capture(200, keep=True)
    assert (cap.n, cap.dropped) == (200, 0) and dev.stats.resets == 1
    assert np.all(np.diff(cap.timestamps) > 0)
    # the rebooted bridge reset the chip (asleep, 2 g); the driver woke it and restored range and rate
    assert dev.read_register(PWR_MGMT_1)[0] == 0x01 and dev.read_register(ACCEL_CONFIG)[0] == 1 << 3
    assert np.all(cap.samples[:, 2] > 7000)  # no zeros from a sleeping chip, no 2 g-scale counts


def test_reset_command(bridge, dev):
    dev.configure(range_g=16)
    dev.reset()
    assert dev.read_register(ACCEL_CONFIG)[0] == 3 << 3
    assert dev.capture(50).n == 50


# --- the protocol itself, frame by frame ------------------------------------------------------
def frames_until(link, kind: int, within_s: float = 3.0) -> list:
    """Frames read until one of type ``kind`` (inclusive); fails if none comes."""
    got, deadline = [], time.monotonic() + within_s
    while (g := link.next_frame(deadline)) is not None:
        got.append(g[0])
        if g[0].type == kind:
            return got
    raise AssertionError(f"no {bp.FRAME_NAMES[kind]} within {within_s} s; got {[f.name for f in got]}")


@pytest.fixture
def link(bridge):
    lk = BridgeLink(bridge.port, timeout_s=LINK[bridge.kind]["timeout_s"], retries=0)
    lk.open()
    if bridge.kind == "simavr":
        frames_until(lk, bp.RSP_BOOT)  # the MCU boots after the port opened (100 ms of chip reset)
    yield lk
    lk.close()


@pytest.mark.parametrize("cmd,payload,err", [
    (0x55, b"", bp.ERR_UNKNOWN_CMD),
    (bp.CMD_CONFIGURE, b"\x00\x03", bp.ERR_BAD_LENGTH),
    (bp.CMD_CONFIGURE, bytes([4, 3, 9]), bp.ERR_BAD_ARG),  # AFS_SEL 4
    (bp.CMD_STREAM, bytes(4), bp.ERR_BAD_ARG),  # zero samples
    (bp.CMD_READ_REG, bytes([0x3B, 17]), bp.ERR_BAD_ARG),  # above REG_MAX_COUNT
    (bp.CMD_WRITE_REG, bytes([0x7F, 1, 2]), bp.ERR_BAD_ARG),  # past register 0x7F
    (bp.CMD_NVM_READ, bytes([32]), bp.ERR_BAD_ARG),  # page 32 of 32
    (bp.CMD_NVM_WRITE, bytes([0]) + bytes(31), bp.ERR_BAD_LENGTH),
])
def test_nak_paths(link, cmd, payload, err):
    with pytest.raises(BridgeRefused) as e:
        link.command(cmd, payload)
    assert bp.ERROR_TEXT[err] in str(e.value)


def test_bad_crc_is_dropped_and_the_next_frame_answered(link):
    bad = bytearray(bp.encode_frame(bp.CMD_IDENTIFY, 77))
    bad[-1] ^= 0x01
    link._ser.write(bytes(bad))
    assert len(link.command(bp.CMD_IDENTIFY)) == bp.IDENTIFY_DATA.size
    assert link.stats.naks == 0 and link.stats.lost_frames == 0  # no answer to the damaged frame


def test_a_command_ends_a_stream_with_stream_end_first(link):
    link.command(bp.CMD_WRITE_REG, bytes([PWR_MGMT_1, 0x01]))  # wake the chip
    assert bp.STREAM_DATA.unpack(link.command(bp.CMD_STREAM, bp.STREAM.pack(100000)))[0] == 100000
    got = frames_until(link, bp.RSP_SAMPLE)
    seq = link.send(bp.CMD_STOP)
    got = frames_until(link, bp.RSP_ACK)
    ends = [f for f in got if f.type == bp.RSP_STREAM_END]
    assert len(ends) == 1 and got[-1].payload == bp.ack(bp.CMD_STOP, seq)
    assert got.index(ends[0]) < len(got) - 1  # STREAM_END before the ACK
    samples = [bp.SAMPLE_INDEX.unpack_from(f.payload)[0] for f in got if f.type == bp.RSP_SAMPLE]
    # the count covers every chip sample up to the STOP: the last one sent, and any after it that
    # the link had no room for (1 kHz after wake-up against ~480 frames/s: a gap, never a repeat)
    assert bp.STREAM_END.unpack(ends[0].payload)[0] >= samples[-1] + 1
    assert all(np.diff(samples) > 0)
    assert link.stats.lost_frames == 0


def unplug(bridge) -> None:
    """The MPU6050 leaves the I2C bus (no ACK to address 0x68)."""
    if bridge.kind == "simavr":
        bridge.set_chip_present(False)
    else:
        with bridge.lock:
            bridge.i2c_present = False


def test_no_chip_on_i2c(bridge, link):
    unplug(bridge)
    time.sleep(0.05)  # the side channel is asynchronous to the serial link
    ident = bp.IDENTIFY_DATA.unpack(link.command(bp.CMD_IDENTIFY))
    assert ident[4] == 0x00  # WHO_AM_I: nothing answered
    with pytest.raises(DeviceError) as e:
        link.command(bp.CMD_READ_REG, bytes([0x75, 1]))
    assert bp.ERROR_TEXT[bp.ERR_I2C] in str(e.value) and "SDA/SCL" in str(e.value)
    link.command(bp.CMD_STREAM, bp.STREAM.pack(10))
    end = frames_until(link, bp.RSP_STREAM_END)[-1]
    assert bp.STREAM_END.unpack(end.payload)[0] == 0  # the first sample read failed: a short stream


def test_reset_command_boots_with_its_cause(link):
    link.command(bp.CMD_RESET)
    boot = frames_until(link, bp.RSP_BOOT)[-1]
    assert bp.BOOT.unpack(boot.payload) == (bp.PROTOCOL_VERSION, bp.BOOT_COMMAND, 1, 1)
    assert len(link.command(bp.CMD_IDENTIFY)) == bp.IDENTIFY_DATA.size


# --- only on the simulated chip ----------------------------------------------------------------
@pytest.fixture
def avr():
    b = make_bridge("simavr", seed=11)
    b.start()
    yield b
    b.stop()


def test_worn_eeprom_cell_is_nak_err_nvm(avr):
    with MPU6050Bridge(avr.port, **LINK["simavr"]) as dev:
        avr.wear_cell(64 + 5, 0x00)
        with pytest.raises(NVMError) as e:
            dev.nvm.write(64, b"\x55" * 32)
        assert "page 2" in str(e.value) and bp.ERROR_TEXT[bp.ERR_NVM] in str(e.value)
        assert dev.stats.naks == dev.link.retries + 1  # ERR_NVM is retried, then reported
        avr.wear_cell(None)
        dev.nvm.write(64, b"\x55" * 32)
        assert dev.nvm.read(64, 32) == b"\x55" * 32


def test_free_ram_at_deepest_stack(avr):
    with MPU6050Bridge(avr.port, **LINK["simavr"]) as dev:
        dev.configure(odr_hz=1000 / 3)  # the fastest rate the 115200-baud link carries
        dev.capture(20)
        dev.nvm.write(0, bytes(range(64)))
        dev.read_register(0x3B, 16)
        dev.write_register(0x06, bytes(6))
        dev.reset()
    s = avr.stats()
    # two measurements of the deepest stack agree: painted bytes never overwritten, lowest SP seen
    assert s["free_ram_min"] == s["min_sp_free"]
    # headroom: at least 256 bytes never touched; and the stack was used (not a blank reading)
    assert 256 <= s["free_ram_min"] < 2048 - s["static_ram"] - 64
    assert s["uart_lost"] == 0


# --- the station's commands against the firmware ------------------------------------------------
def test_probe_cli_on_the_port(bridge):
    r = CliRunner().invoke(cli, ["probe", "--config", str(CONFIGS / "mpu6050.yaml"), "--port", bridge.port, "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert out["chip"] == "mpu6050" and out["chip_id"] == 0x68, out
    assert out["interface"] == f"serial:{bridge.port}"


def test_whole_run_with_motorized_jig(bridge, tmp_path):
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5), board=bridge.board, board_lock=bridge.lock)
    jig.start()
    try:
        cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
        cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
        cfg["jig"].update(settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)  # fast axes: a quick test
        cfg["device"].update(LINK[bridge.kind], odr_hz=200)  # drop-free on the chip up to 333 Hz
        p = tmp_path / "mpu.yaml"
        p.write_text(yaml.safe_dump(cfg))
        r = CliRunner().invoke(cli, ["run", "--config", str(p), "--port", bridge.port, "--jig-port", jig.port,
                                     "--json"])
        assert r.exit_code == 0, r.output
        out = json.loads(r.stdout)
        assert out["verdict"] == "PASS" and out["chip"] == "mpu6050" and out["nvm_verified"]
        assert sum(c.startswith("MOVE") for c in jig.received) >= 8
    finally:
        jig.stop()
    # the calibration is in the bridge's NVM, read back through the protocol (the AVR's EEPROM for simavr)
    with MPU6050Bridge(bridge.port, **LINK[bridge.kind]) as dev:
        cal, _, _ = CalibrationWriter(dev.nvm).read_newest(out["serial"])
    np.testing.assert_allclose(cal.W, out["W"], rtol=0, atol=0)
    # the fit inverts the simulated sensor's own errors (truth) to well under 1 mg
    g = np.array([[0.6, -0.6, 0.52], [0.0, 0.0, 1.0]]) * cal.input_per_g
    truth = bridge.board.truth()
    np.testing.assert_allclose(cal.apply(g, units="counts"), truth.apply(g, units="counts"), atol=1e-3)


def test_emulate_firmware_prints_a_port_that_probe_opens():
    require_simavr()
    p = subprocess.Popen([sys.executable, "-m", "accelcal_station", "emulate", "mpu6050-bridge", "--firmware",
                          "--seed", "5", "--json"], stdout=subprocess.PIPE, text=True, cwd=REPO)
    try:
        port = json.loads(p.stdout.readline())["port"]
        r = subprocess.run([sys.executable, "-m", "accelcal_station", "probe", "--config", "configs/mpu6050.yaml",
                            "--port", port], capture_output=True, text=True, cwd=REPO, timeout=60)
        assert r.returncode == 0, r.stderr
        assert "mpu6050 (chip id 0x68)" in r.stdout and "mpu6050-bridge 1.1" in r.stdout, r.stdout
    finally:
        p.terminate()
        p.wait(timeout=10)

"""The chips' built-in self-test through the real driver paths (issue 40, driver part).

Figures written here from the data sheets, independently of the code:
- MMA8451Q data sheet Rev. 10.3, Table 4: self-test output change at +-4 g, 14-bit (2048 LSB/g),
  typical X +181, Y +255, Z +1680 LSB; NXP's screen: at least 50 LSB on every axis.
- MPU-6050 register map rev 4.2, 4.1: FT = 4096 * 0.34 * (0.92 / 0.34)^((A_TEST - 1) / 30) LSB at
  +-8 g, A_TEST 5 bits from SELF_TEST_X/Y/Z bits 7:5 (high) and SELF_TEST_A (low two); product
  specification rev 3.4, 6.1: (STR - FT) / FT within +-14 %.
The emulators draw each chip's response with a spread (MMA8451 10 %, MPU6050 4 %); tolerances
below are >= 4 of those spreads plus 8 SEM of the averages (false-failure rate < 1e-4; fixed seeds).
"""
from __future__ import annotations

import numpy as np
import pytest
from test_mpu6050_firmware import require_simavr

from accelcal_station.drivers.mma8451 import MMA8451
from accelcal_station.drivers.mma8451_emulator import MMA8451Emulator
from accelcal_station.drivers.mpu6050 import MPU6050Bridge, factory_trim_counts
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.mpu6050_simavr import SimavrBridge
from accelcal_station.drivers.simulated import SimulatedBoard

MMA_TYPICAL_G = np.array([181, 255, 1680]) / 2048
MMA_MIN_G = 50 / 2048


def ft_datasheet(code: int) -> float:
    return 0.0 if code == 0 else 4096 * 0.34 * (0.92 / 0.34) ** ((code - 1) / 30)


def mma(seed: int = 5, **faults) -> tuple[MMA8451, MMA8451Emulator]:
    emu = MMA8451Emulator(SimulatedBoard.from_config(None, chip="mma8451", seed=seed))
    emu.self_test_faults(**faults)
    return MMA8451(emu, clock=emu.clock, bus_label="emulated"), emu


@pytest.mark.parametrize("range_g", [2, 4, 8])
def test_mma8451_self_test_matches_the_data_sheet_at_every_range(range_g):
    dev, emu = mma()
    with dev:
        dev.configure(range_g=range_g)
        r = dev.self_test(128)
        assert emu.chip.regs[0x2B] & 0x80 == 0  # ST cleared afterwards
    assert r.ok and not r.no_effect and r.reason() is None
    got = np.array([a.change_g for a in r.axes])
    np.testing.assert_allclose(got, MMA_TYPICAL_G, rtol=0.4)  # 4 x the 10 % spread between chips
    assert all(a.low == pytest.approx(MMA_MIN_G) for a in r.axes)
    assert [a.axis for a in r.axes] == ["x", "y", "z"] and all(a.unit == "g" for a in r.axes)


@pytest.mark.parametrize("range_g", [2, 4, 8])
def test_mma8451_self_test_runs_at_8g_and_restores_the_run_range(range_g):
    """Issue 48: at +-2 g the ~1 g z response sits at the rail; the self-test runs on scale at +-8 g and the
    run's range comes back, read from XYZ_DATA_CFG (0x0E, FS bits 1:0: 0, 1, 2 for 2, 4, 8 g) through smbus2."""
    dev, emu = mma()
    with dev:
        dev.configure(range_g=range_g)
        r = dev.self_test(128)
        fs = emu.read_byte_data(0x1D, 0x0E) & 0x03
        assert dev.range_g == range_g and dev.counts_per_g == {2: 4096, 4: 2048, 8: 1024}[range_g]
    assert r.range_g == 8 and r.to_json()["range_g"] == 8
    assert fs == {2: 0, 4: 1, 8: 2}[range_g]


@pytest.mark.parametrize("range_g", [2, 4, 8])
def test_mma8451_too_large_response_fails_at_a_2g_run_range(range_g):
    # a 3.5 g z response: above NXP's screen of 6000 LSB at +-4 g (2.93 g); at +-2 g it read as the rail
    dev, emu = mma()
    emu.self_test_faults(scale=(1.0, 1.0, 3.5 / emu.self_test_g[2]))
    with dev:
        dev.configure(range_g=range_g)
        r = dev.self_test(128)
    assert not r.ok and [a.axis for a in r.axes if not a.ok] == ["z"]
    assert r.axes[2].change_g == pytest.approx(3.5, rel=0.01)  # on scale: the whole response is seen


def test_mma8451_weak_axis_fails_naming_it():
    dev, _ = mma(scale=(1.0, 1.0, 0.02))  # z responds 2 % of its force: ~16 mg, below 24.4 mg
    with dev:
        r = dev.self_test(128)
    assert not r.ok and not r.no_effect
    assert [a.axis for a in r.axes if not a.ok] == ["z"] and r.reason().startswith("self-test z:")


def test_mma8451_self_test_that_does_nothing_is_named():
    dev, _ = mma(dead=True)
    with dev:
        r = dev.self_test(128)
    assert r.no_effect and not r.ok and "self-test did nothing" in r.reason()


def test_factory_trim_from_the_self_test_registers():
    # codes 1, 31 and 16 on x, y, z: SELF_TEST_X/Y/Z bits 7:5 = code >> 2, SELF_TEST_A = low bits
    codes = (1, 31, 16)
    regs = bytes([(c >> 2) << 5 for c in codes]) + bytes([(1 & 3) << 4 | (31 & 3) << 2 | (16 & 3)])
    np.testing.assert_allclose(factory_trim_counts(regs), [ft_datasheet(c) for c in codes], rtol=1e-12)
    assert ft_datasheet(1) == pytest.approx(4096 * 0.34) and ft_datasheet(31) == pytest.approx(4096 * 0.92)
    assert factory_trim_counts(bytes(4)).tolist() == [0.0, 0.0, 0.0]  # no trim programmed


def bridge(kind: str, **kw):
    board = SimulatedBoard.from_config(None, chip="mpu6050", seed=4)
    if kind == "simavr":
        require_simavr()
        return SimavrBridge(board, **kw)
    return MPU6050BridgeEmulator(board, **kw)


@pytest.mark.parametrize("kind", ["python", "simavr"])
def test_mpu6050_self_test_through_the_bridge(kind):
    b = bridge(kind, self_test_codes=(12, 17, 22))
    port = b.start()
    try:
        with MPU6050Bridge(port, timeout_s=2.0, boot_wait_s=3.0) as dev:
            dev.configure(range_g=4)
            r = dev.self_test(64)
            assert dev.range_g == 4  # the range is the host's again afterwards
    finally:
        b.stop()
    assert r.ok, r.reason()
    str_counts = np.array([a.change_counts for a in r.axes])
    ft = np.array([ft_datasheet(c) for c in (12, 17, 22)])
    np.testing.assert_allclose(str_counts, ft, rtol=0.16)  # 4 x the 4 % spread
    assert all(a.low == -0.14 and a.high == 0.14 for a in r.axes)


@pytest.mark.parametrize("kind", ["python", "simavr"])
def test_mpu6050_weak_axis_and_dead_self_test(kind):
    for share, want in (((1.0, 0.5, 1.0), "y"), ((0.0, 0.0, 0.0), None)):
        b = bridge(kind, self_test_codes=(12, 17, 22), self_test_share=share)
        port = b.start()
        try:
            with MPU6050Bridge(port, timeout_s=2.0, boot_wait_s=3.0) as dev:
                r = dev.self_test(32)
        finally:
            b.stop()
        assert not r.ok
        if want:
            assert [a.axis for a in r.axes if not a.ok] == [want] and not r.no_effect
            assert r.axes[1].value == pytest.approx(-0.5, abs=0.05)
        else:
            assert r.no_effect and "did nothing" in r.reason()

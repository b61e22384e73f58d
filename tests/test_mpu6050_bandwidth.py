"""The MPU6050's per-sample noise at its DLPF bandwidth (issue 48's follow-up), simulated and emulated.

The figures are the data sheet's, written here independently of the code:
- MPU-6000/6050 Product Specification rev 3.4, 6.2: accelerometer noise power spectral density
  400 ug/sqrt(Hz);
- MPU-6000/6050 Register Map rev 4.2, register 26 CONFIG: accelerometer bandwidth per DLPF_CFG
  0..6: 260, 184, 94, 44, 21, 10, 5 Hz.
Per-sample sigma = density x sqrt(ENBW), the equivalent noise bandwidth of a one-pole low-pass
of -3 dB bandwidth f_c being (pi / 2) f_c (the integral of 1 / (1 + (f / f_c)^2) over f >= 0).
The filter runs before the sample-rate divider, so the output rate does not narrow it.

Statistics: the std of N AR(1) samples of lag-1 correlation a has relative sd about
sqrt((1 + a^2) / (1 - a^2) / (2 N)); the tolerances below are at least 5 of those sd (fixed seeds;
false-failure rate below 1e-6 per check).
"""
from __future__ import annotations

import numpy as np
import pytest

from accelcal_station.drivers.mpu6050 import MPU6050Bridge
from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
from accelcal_station.drivers.simulated import SimulatedBoard

DENSITY_G = 400e-6  # g/sqrt(Hz)
DLPF_BANDWIDTH_HZ = (260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0)
COUNTS_PER_G_2G = 16384.0  # AFS_SEL 0 sensitivity, product specification 6.2
FAST = {"timeout_s": 0.25, "retries": 3, "boot_wait_s": 0.3}


def sigma_counts(dlpf: int) -> float:
    return DENSITY_G * np.sqrt(np.pi / 2 * DLPF_BANDWIDTH_HZ[dlpf]) * COUNTS_PER_G_2G


def rel_sd(a: float, n: int) -> float:
    return float(np.sqrt((1 + a * a) / (1 - a * a) / (2 * n)))


def test_the_expected_figures_from_the_data_sheet():
    # 400 ug x sqrt(pi/2 x 44 Hz) = 3.33 mg; x 16384 = 54.5 counts at DLPF_CFG 3 (the shipped configs)
    assert sigma_counts(3) == pytest.approx(54.48, abs=0.01)
    assert sigma_counts(6) == pytest.approx(18.37, abs=0.01)  # 1.12 mg at 5 Hz
    assert sigma_counts(0) == pytest.approx(132.4, abs=0.1)   # 8.08 mg at 260 Hz


@pytest.mark.parametrize("dlpf", range(7))
def test_simulated_noise_follows_the_dlpf_bandwidth_at_100_hz(dlpf):
    """At 100 Hz the old sigma (density x sqrt(min(ODR / 2, f_c))) is sqrt(50 Hz) for DLPF_CFG 0-2:
    2.86x too small at DLPF_CFG 0, which the tolerance excludes."""
    b = SimulatedBoard.from_config({"chip": "mpu6050", "odr_hz": 100, "dlpf": dlpf, "seed": 40 + dlpf,
                                    "effects": {"noise": {"density_ug_per_rthz": 400.0}}})
    counts, _ = b.read(20000)
    a = float(np.exp(-2 * np.pi * DLPF_BANDWIDTH_HZ[dlpf] / 100.0))
    tol = max(5 * rel_sd(a, 20000), 0.03)
    np.testing.assert_allclose(counts.std(axis=0), sigma_counts(dlpf), rtol=tol)
    old = DENSITY_G * np.sqrt(min(50.0, DLPF_BANDWIDTH_HZ[dlpf])) * COUNTS_PER_G_2G
    assert abs(old / sigma_counts(dlpf) - 1) > 3 * tol  # the old bandwidth is told apart at every setting


@pytest.mark.parametrize("dlpf", [6, 1])
def test_emulated_bridge_noise_follows_the_dlpf_bandwidth(dlpf):
    """Through pyserial on a pseudo-terminal against the bridge emulator (its default board: the
    data-sheet density)."""
    emu = MPU6050BridgeEmulator(seed=3)
    emu.start()
    try:
        with MPU6050Bridge(emu.port, **FAST) as dev:
            dev.configure(odr_hz=100, dlpf=dlpf)
            counts, _, dropped = dev.read_samples(6000)
    finally:
        emu.stop()
    assert dropped == 0
    a = float(np.exp(-2 * np.pi * DLPF_BANDWIDTH_HZ[dlpf] / 100.0))
    np.testing.assert_allclose(counts.std(axis=0), sigma_counts(dlpf), rtol=max(5 * rel_sd(a, 6000), 0.05))

"""Correlated samples (issue 48): the MPU6050's DLPF in the simulator, and standard errors from the
effective sample count n_eff = n / tau_int (accelcal_station/models/effective_samples.py).

Expected figures come from the data sheet and from closed forms, not from the code: a one-pole low-pass
of bandwidth f_c sampled at f_s has lag-k autocorrelation exp(-2 pi f_c k / f_s), and an AR(1) process
of lag-1 correlation a has tau_int = (1 + a) / (1 - a).
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.signal import lfilter
from scipy.stats import chi2

from accelcal_station.config.sections import default_config_path
from accelcal_station.drivers.base import Capture
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.models.effective_samples import autocorrelation, effective_n, tau_int
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

# MPU-6000/6050 register map rev 4.2, register 26 CONFIG: accelerometer bandwidth per DLPF_CFG (Hz)
DLPF_BANDWIDTH_HZ = (260.0, 184.0, 94.0, 44.0, 21.0, 10.0, 5.0)
MPU_DENSITY_UG = 400.0  # MPU-6050 product specification 6.2: noise power spectral density


def lag1(bandwidth_hz: float, odr_hz: float) -> float:
    return float(np.exp(-2 * np.pi * bandwidth_hz / odr_hz))


def test_dlpf6_at_100hz_gives_lag1_autocorrelation_of_a_5hz_one_pole_filter():
    b = SimulatedBoard.from_config({"chip": "mpu6050", "odr_hz": 100, "dlpf": 6, "seed": 5})
    counts, _ = b.read(20000)
    rho1 = autocorrelation(counts, 1)[1]
    # exp(-2 pi 5 / 100) = 0.730; the estimate's sd is sqrt((1 - a^2) / n) = 0.005: 0.03 is 6 sd
    assert lag1(5.0, 100.0) == pytest.approx(0.7304, abs=1e-4)
    np.testing.assert_allclose(rho1, lag1(5.0, 100.0), atol=0.03)


@pytest.mark.parametrize("dlpf", range(7))
def test_every_dlpf_setting_sets_its_correlation_and_keeps_the_data_sheet_noise(dlpf):
    odr = 1000.0  # 8 kHz / 8 with DLPF_CFG 0, 1 kHz / 1 otherwise
    b = SimulatedBoard.from_config({"chip": "mpu6050", "odr_hz": odr, "dlpf": dlpf, "seed": 11,
                                    "effects": {"noise": {}}})
    counts, _ = b.read(40000)
    a = lag1(DLPF_BANDWIDTH_HZ[dlpf], odr)
    np.testing.assert_allclose(autocorrelation(counts, 1)[1], a, atol=0.03)  # sd <= 0.005
    # a one-pole filter's equivalent noise bandwidth is (pi / 2) f_c (tests/test_mpu6050_bandwidth.py)
    sigma = MPU_DENSITY_UG * 1e-6 * np.sqrt(np.pi / 2 * DLPF_BANDWIDTH_HZ[dlpf]) * 16384
    # the std of 40000 AR(1) samples: relative sd sqrt((1 + a^2) / (1 - a^2) / 80000) <= 2.2 %; 10 % is 4.5 sd
    np.testing.assert_allclose(counts.std(axis=0), sigma, rtol=0.10)


@pytest.mark.parametrize("a", [0.0, 0.5, 0.73, 0.9])
def test_tau_int_of_an_ar1_process(a):
    rng = np.random.default_rng(3)
    taus = []
    for _ in range(40):
        e = rng.standard_normal((5000, 3))
        y = lfilter([np.sqrt(1 - a * a)], [1.0, -a], e, axis=0)  # y_k = a y_(k-1) + sqrt(1 - a^2) e_k
        taus.append(tau_int(y))
    # (1 + a) / (1 - a); the mean of 120 estimates has sd < 3 % of it (Sokal's var ~ 2 (2M + 1) / n tau^2)
    np.testing.assert_allclose(np.mean(taus), (1 + a) / (1 - a), rtol=0.08)


def test_capture_sem_matches_the_scatter_of_capture_means():
    b = SimulatedBoard.from_config({"chip": "mpu6050", "odr_hz": 100, "dlpf": 6, "seed": 21})
    means, sems, naive = [], [], []
    for _ in range(200):
        counts, t = b.read(300)
        b.read(60)  # a gap longer than the correlation time: the next capture is independent
        c = Capture.from_samples(counts, t)
        means.append(c.mean_counts)
        sems.append(c.sem_counts)
        naive.append(c.std_counts / np.sqrt(c.n))
    scatter = np.std(means, axis=0, ddof=1)
    # 200 means: the scatter's relative sd is 5 %, so [0.8, 1.25] is > 4 sd each side; the
    # independent-sample formula is sqrt(tau) = sqrt(1.73 / 0.27) = 2.5x too small
    ratio = scatter / np.sqrt(np.mean(np.square(sems), axis=0))
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    assert np.all(scatter / np.sqrt(np.mean(np.square(naive), axis=0)) > 2.0)


def test_white_samples_keep_n():
    x = np.random.default_rng(1).standard_normal((2000, 3))
    np.testing.assert_allclose(effective_n(x), 2000, rtol=0.25)
    assert np.all(effective_n(np.ones((100, 3))) == 100)  # no variance: n, not a division by zero


def station_config(tmp_path, seed: int, dlpf: int, target_sem_mg: float) -> str:
    c = yaml.safe_load(default_config_path().read_text())
    c["store"] = {"path": str(tmp_path / "runs.sqlite")}
    c["device"].update(chip="mpu6050", odr_hz=100, dlpf=dlpf, seed=seed)
    c["device"]["simulator"]["effects"]["noise"] = {"density_ug_per_rthz": MPU_DENSITY_UG}
    c["capture"]["target_sem_mg"] = target_sem_mg
    c["nvm"] = {"write": False}
    p = tmp_path / f"station-{seed}.yaml"
    p.write_text(yaml.safe_dump(c))
    return str(p)


def mpu_target_sem_mg() -> float:
    """The shipped MPU6050 station config's per-pose target."""
    doc = yaml.safe_load((default_config_path().parent / "mpu6050.yaml").read_text())
    return float(doc["capture"]["target_sem_mg"])


def test_repeated_runs_scatter_matches_the_reported_offset_stderr(tmp_path):
    """One simulated MPU6050 board (DLPF_CFG 6, 100 Hz, 400 ug/sqrt(Hz)) calibrated 12 times with fresh noise.

    The ratio is pooled over the three axes: sqrt(mean(sd_a^2 / se_a^2)); with 12 runs x 3 axes, 33 x
    ratio^2 is about chi^2 with 33 dof, so P(ratio < 0.6) + P(ratio > 1.6) is below 1e-3 (computed
    below): the check's false-failure rate.  The independent-sample formula would report sqrt(tau) =
    2.5x smaller errors and fail it."""
    V, S, tau = [], [], []
    for seed in range(1, 13):
        st = make_flow(StationConfig.load(station_config(tmp_path, seed, 6, mpu_target_sem_mg())), echo=lambda s: None)
        (rep,) = st.run()
        assert rep.fit is not None and rep.fit.stderr is not None, rep.reasons
        assert all(p["reached_target"] for p in rep.poses)  # the shipped target is reached at DLPF_CFG 6
        V.append(rep.fit.V)
        S.append(rep.fit.stderr["V"])
        tau += [p["n"] / np.array(p["n_eff"]) for p in rep.poses]
    sd, se = np.std(V, axis=0, ddof=1), np.sqrt(np.mean(np.square(S), axis=0))
    ratio = float(np.sqrt(np.mean(sd**2 / se**2)))
    false_failure = chi2.cdf(33 * 0.6**2, 33) + chi2.sf(33 * 1.6**2, 33)
    assert false_failure < 1e-3
    assert 0.6 <= ratio <= 1.6, (sd, se)
    # the poses' measured tau_int is near the filter's (1 + a) / (1 - a) = 6.4 (short captures read it low)
    a = lag1(5.0, 100.0)
    assert 0.5 * (1 + a) / (1 - a) < np.mean(tau) < 1.3 * (1 + a) / (1 - a)
    assert ratio * np.sqrt(np.mean(tau)) > 1.6  # what std / sqrt(n) would have reported


def test_the_shipped_mpu6050_target_is_reached_at_the_data_sheet_noise(tmp_path):
    # DLPF_CFG 3 (the shipped configs): 400 ug/sqrt(Hz) * sqrt(pi/2 * 44 Hz) = 3.33 mg a sample, tau 1.13:
    # (3.33 / 0.15)^2 * 1.13 = 558 samples, 5.6 s a pose, inside capture.max_s (20 s)
    st = make_flow(StationConfig.load(station_config(tmp_path, 3, 3, mpu_target_sem_mg())), echo=lambda s: None)
    (rep,) = st.run()
    assert rep.verdict == "PASS", rep.reasons
    assert all(p["reached_target"] for p in rep.poses)
    assert max(p["n"] for p in rep.poses) < 1000

"""The simulated board, driver, EEPROM and jig: every effect's signature, the noise floor,
and recovery of the simulator's ground truth by the calibration models."""
from __future__ import annotations

import time

import numpy as np
import pytest

from accelcal_station.config.schema import validate_device
from accelcal_station.drivers.factory import make_driver
from accelcal_station.drivers.simulated import SimulatedBoard, SimulatedDriver
from accelcal_station.errors import ConfigError, DeviceError
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.designs import get_design, predict_stderr
from accelcal_station.fixtures.simulated_jig import SimulatedJig, rotation_path
from accelcal_station.models.fitting import fit_batch
from accelcal_station.sim.sensor_model import rotation_matrix

FLAT = PoseSpec("z+1g", 0.0, 0.0)
X_UP = PoseSpec("x+1g", -90.0, 0.0)  # reference (+1, 0, 0) g
X_DOWN = PoseSpec("x-1g", 90.0, 0.0)
Y_UP = PoseSpec("y+1g", 0.0, 90.0)


def board(effects: dict, chip: str = "mma8451", seed: int = 0, **cfg) -> SimulatedBoard:
    return SimulatedBoard.from_config({"effects": effects, **cfg}, chip=chip, seed=seed)


def reading_g(b: SimulatedBoard, pose: PoseSpec | None = None, n: int = 1) -> np.ndarray:
    if pose is not None:
        b.set_pose(pose)
    counts, _ = b.read(n)
    return np.asarray(counts, dtype=float).mean(axis=0) / b.counts_per_g


# -- the contract -------------------------------------------------------------------------

def test_default_board_contract():
    b = SimulatedBoard.from_config(None, seed=5)
    assert (b.chip.name, b.range_g, b.odr_hz, b.counts_per_g) == ("mma8451", 2, 100.0, 4096.0)
    assert b.identity.chip_id == 0x1A and b.identity.serial == "SIM-00000005"
    b.set_pose(X_UP)
    counts, t = b.read(250)
    assert counts.dtype == np.int64 and counts.shape == (250, 3)
    np.testing.assert_allclose(np.diff(t), 0.01)
    assert b.clock.now() == pytest.approx(t[-1]) and t[-1] == pytest.approx(2.5)
    np.testing.assert_allclose(counts.mean(axis=0) / 4096.0, [1, 0, 0], atol=1e-3)
    np.testing.assert_array_equal(b.truth().W, np.eye(3))
    assert b.eeprom.size == 4096 and b.eeprom.page_size == 32


def test_configure_changes_counts_per_g_and_refuses_bad_settings():
    b = SimulatedBoard.from_config(None, chip="mpu6050", seed=1)
    b.configure(8, 200, 2)
    assert (b.counts_per_g, b.odr_hz, b.dlpf) == (4096.0, 200.0, 2)
    b.set_pose(FLAT)
    np.testing.assert_allclose(reading_g(b, n=400), [0, 0, 1], atol=2e-3)
    with pytest.raises(ConfigError, match=r"range_g: 3; allowed for mpu6050: 2, 4, 8, 16"):
        b.configure(3, 200)


def test_whole_calibration_runs_in_milliseconds_of_wall_time():
    b = SimulatedBoard.from_config(None, seed=2)
    start = time.perf_counter()
    for pose in get_design("an4399-8"):
        b.set_pose(pose)
        b.read(1000)
    wall = time.perf_counter() - start
    assert b.clock.now() == pytest.approx(80.0)  # 8000 samples at 100 Hz of virtual time
    assert wall < 0.2


def test_realtime_mode_sleeps_wall_time():
    b = SimulatedBoard.from_config({"realtime": True, "odr_hz": 50}, seed=1)
    start = time.perf_counter()
    b.read(5)
    assert time.perf_counter() - start >= 0.09  # 5 samples at 50 Hz


def test_seed_reproduces_and_streams_are_independent():
    a, b, c = (board({"noise": {}}, seed=s) for s in (7, 7, 8))
    ra, rb, rc = (x.read(100)[0] for x in (a, b, c))
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(ra, rc)
    # switching drift and pose scatter on does not change the noise draws
    d = board({"noise": {}, "drift": {}, "pose_error": {"scatter_deg": 1.0}}, seed=7)
    d.set_pose(FLAT)
    d.set_gravity_direction([0, 0, 1])
    np.testing.assert_array_equal(d.read(100)[0], ra)


def test_board_config_errors_name_the_key(tmp_path):
    with pytest.raises(ConfigError, match=r"^dev\.rnage_g: unknown key"):
        SimulatedBoard.from_config({"rnage_g": 2}, path="dev")
    with pytest.raises(ConfigError, match=r"^dev\.effects\.offset\.offset_mg\[0\]: 'a' is not a number"):
        SimulatedBoard.from_config({"effects": {"offset": {"offset_mg": ["a", 0, 0]}}}, path="dev")
    with pytest.raises(ConfigError, match=r"^dev\.eeprom\.size_bytes: 1000 must be a multiple of page_bytes"):
        SimulatedBoard.from_config({"eeprom": {"size_bytes": 1000}}, path="dev")
    f = tmp_path / "sensor.yaml"
    f.write_text("effects:\n  gain: {gain: [1, 1, 9]}\n")
    with pytest.raises(ConfigError, match=rf"^dev\.simulator\({f}\)\.effects\.gain\.gain\[2\]: 9 out of range"):
        SimulatedBoard.from_config({"simulator": str(f)}, path="dev")
    with pytest.raises(ConfigError, match=r"^dev\.chip: 'adxl345'; allowed: mma8451, mpu6050"):
        SimulatedBoard.from_config({"chip": "adxl345"}, path="dev")


def test_serial_from_config_and_temperature_of_the_die():
    b = SimulatedBoard.from_config({"serial": "B-17", "ambient_c": 30, "self_heating_c": 2.5}, chip="mpu6050")
    assert b.identity.serial == "B-17" and b.temperature_c == 32.5
    b.set_temperature(-5.0)
    assert b.temperature_c == -2.5


# -- the thirteen effects -------------------------------------------------------------------

def test_offset_adds_its_mg():
    b = board({"offset": {"offset_mg": [12.0, -34.0, 56.0]}})
    np.testing.assert_allclose(reading_g(b, FLAT), [0.012, -0.034, 1.056], atol=1e-12)


def test_gain_scales_each_axis():
    b = board({"gain": {"gain": [1.03, 0.97, 1.01]}})
    np.testing.assert_allclose(reading_g(b, X_UP), [1.03, 0, 0], atol=1e-12)
    np.testing.assert_allclose(reading_g(b, Y_UP), [0, 0.97, 0], atol=1e-12)


def test_cross_axis_couples_and_rotates():
    C = [[0, 0.02, 0], [0, 0, 0], [0, -0.01, 0]]
    b = board({"cross_axis": {"coupling": C}})
    np.testing.assert_allclose(reading_g(b, Y_UP), [0.02, 1.0, -0.01], atol=1e-12)
    b = board({"cross_axis": {"rotation_deg": [0, 0, 2.0]}})  # chip turned 2 deg about z
    np.testing.assert_allclose(reading_g(b, X_UP), [np.cos(np.radians(2)), -np.sin(np.radians(2)), 0], atol=1e-12)


def test_cubic_is_odd_and_follows_its_coefficient():
    b = board({"cubic": {"cubic_per_g2": [0.01, 0, 0]}})
    up, down = reading_g(b, X_UP)[0], reading_g(b, X_DOWN)[0]
    assert up == pytest.approx(-down, abs=1e-14)
    assert up - 0.01 * up**3 == pytest.approx(1.0, abs=1e-14)  # f = G - c G^3
    assert up - 1.0 == pytest.approx(0.0103, abs=5e-4)  # about +c at 1 g


def test_physics_forward_is_the_sensors_response_and_the_lot_chain_agrees(tmp_path):
    """simulator.physics: forward gives G = o + u + c u^3 (u = K f); the default stays implicit
    (f = G - c G^3); the lot chain (sim/lot_physics.py, vectorised) gives the one board's reading."""
    from accelcal_station.sim.lot_physics import board_parameters, enabled_effects, response_g

    eff = {"offset": {"offset_mg": [20.0, -10.0, 40.0]}, "gain": {"gain": [1.02, 1.0, 0.99]},
           "cubic": {"cubic_per_g2": [0.015, 0.0, 0.01]}}
    fwd = SimulatedBoard.from_config({"simulator": {"effects": eff, "physics": "forward"}}, seed=0)
    imp = SimulatedBoard.from_config({"simulator": {"effects": eff}}, seed=0)
    assert fwd.model.forward and not imp.model.forward
    u = 1.02
    assert reading_g(fwd, X_UP)[0] == pytest.approx(0.020 + u + 0.015 * u**3, abs=1e-12)
    G = reading_g(imp, X_UP)[0]
    f_x = (G - 0.020) / 1.02 - 0.015 * G**3  # the implicit chain, unchanged
    assert f_x == pytest.approx(1.0, abs=1e-12)
    f = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, -0.8]])
    for model in (fwd.model, imp.model):
        prm = board_parameters(model, None, None, 1)
        lot = response_g(prm, enabled_effects(model, None), f[None], 25.0, model.forward)[0]
        np.testing.assert_allclose(lot, model.response_g(f), atol=1e-13)
    with pytest.raises(ConfigError, match=r"^dev\.simulator\.physics: 'inverse'; allowed: implicit, forward$"):
        SimulatedBoard.from_config({"simulator": {"physics": "inverse"}}, path="dev")
    (tmp_path / "s.yaml").write_text("effects: {cubic: {cubic_per_g2: [0.01, 0, 0]}}\nphysics: forward\n")
    assert SimulatedBoard.from_config({"simulator": str(tmp_path / "s.yaml")}).model.forward


def test_quadratic_is_even():
    b = board({"quadratic": {"quadratic_per_g": [0.008, 0, 0]}})
    up, down = reading_g(b, X_UP)[0], reading_g(b, X_DOWN)[0]
    assert (up + down) / 2 == pytest.approx(0.008, rel=0.05)  # both faces shifted by about +q
    assert up - 0.008 * up**2 == pytest.approx(1.0, abs=1e-14)


def test_temperature_moves_offset_and_gain_by_the_coefficients():
    b = board({"offset": {"offset_mg": [10, 0, 0]}, "gain": {"gain": [1.01, 1, 1]},
               "temperature": {"t_ref_c": 25, "offset_mg_per_c": [0.5, 0, 0], "offset_mg_per_c2": [0.01, 0, 0],
                               "gain_ppm_per_c": [300, 0, 0], "gain_ppm_per_c2": [-2, 0, 0]}})
    for temp in (25.0, 65.0, -15.0):
        b.set_temperature(temp)
        up, down = reading_g(b, X_UP)[0], reading_g(b, X_DOWN)[0]
        dt = temp - 25.0
        assert (up + down) / 2 == pytest.approx(1e-3 * (10 + 0.5 * dt + 0.01 * dt**2), abs=1e-12)
        assert (up - down) / 2 == pytest.approx(1.01 * (1 + 1e-6 * (300 * dt - 2 * dt**2)), abs=1e-12)


def test_pose_error_moves_the_true_gravity_direction():
    b = board({"pose_error": {"jig_rotation_deg": [0, 3.0, 0]}})
    b.set_pose(FLAT)
    expected = rotation_matrix([0, 3.0, 0]) @ [0, 0, 1]
    np.testing.assert_allclose(b.true_direction, expected, atol=1e-15)
    np.testing.assert_allclose(reading_g(b), expected, atol=1e-12)
    assert np.degrees(np.arccos(b.true_direction @ FLAT.reference_g)) == pytest.approx(3.0)
    # scatter: fresh per presentation; rms angle of an isotropic per-axis sigma is sigma * sqrt(2)
    b = board({"pose_error": {"scatter_deg": 0.5}}, seed=3)
    ang = []
    for _ in range(2000):
        b.set_pose(FLAT)
        ang.append(np.degrees(np.arccos(np.clip(b.true_direction @ [0, 0, 1], -1, 1))))
    # 2000 draws: the rms estimate has a relative sd of ~1.6 %; 8 % is 5 sd (false failure < 1e-6)
    assert np.sqrt(np.mean(np.square(ang))) == pytest.approx(0.5 * np.sqrt(2), rel=0.08)


def test_gravity_scales_the_true_force():
    b = board({"gravity": {"local_mps2": 9.7803}})
    g = reading_g(b, PoseSpec("tilt", 30, 40))
    assert np.linalg.norm(g) == pytest.approx(9.7803 / 9.80665, abs=1e-12)


# Noise floor: block means of n samples; 800 blocks give the std a relative sd of 2.5 %,
# so the 12 % tolerance is 4.8 sd (false failure about 2e-6 per check, 3e-5 for all 18).
# MPU6050 DLPF (issue 48): one-pole, rho_k = a^k = exp(-2 pi f_c k / ODR), block-mean variance sigma^2 / n
# (1 + 2 sum (1 - k/n) a^k); single samples, a = 0.76: std of 800 has relative sd 5.3 %, 25 % is 4.7 sd.
# The MPU6050's ENBW is the one-pole DLPF's (pi / 2) f_c, f_c = 44 Hz at DLPF_CFG 3; a from f_c.
@pytest.mark.parametrize("chip, odr, dlpf, enbw, f_c", [("mma8451", 100, None, 50.0, None),
                                                        ("mma8451", 800, None, 400.0, None),
                                                        ("mpu6050", 1000, 3, np.pi / 2 * 44.0, 44.0)])
def test_noise_floor_matches_density_and_bandwidth(chip, odr, dlpf, enbw, f_c):
    b = board({"noise": {}}, chip=chip, seed=11, odr_hz=odr, dlpf=dlpf)
    density = b.chip.noise_ug_per_rthz
    sigma_counts = density * 1e-6 * np.sqrt(enbw) * b.counts_per_g
    np.testing.assert_allclose(b.noise_sigma_counts, sigma_counts)
    a = np.exp(-2 * np.pi * f_c / odr) if f_c is not None else 0.0
    for n in (1, 16, 256):
        counts, _ = b.read(800 * n)
        means = np.asarray(counts).reshape(800, n, 3).mean(axis=1)
        factor = 1 + 2 * np.sum((1 - np.arange(1, n) / n) * a ** np.arange(1, n))
        np.testing.assert_allclose(means.std(axis=0, ddof=1), sigma_counts * np.sqrt(factor / n),
                                   rtol=0.25 if (a and n == 1) else 0.12)


def test_quantization_gives_integer_counts_in_lsb_steps():
    b = board({"noise": {}, "quantization": {"lsb_counts": 4}}, seed=1)
    counts, _ = b.read(500)
    assert counts.dtype == np.int64 and np.all(counts % 4 == 0) and len(np.unique(counts[:, 2])) > 1
    raw, _ = board({"noise": {}}, seed=1).read(500)
    assert raw.dtype == np.float64 and np.all(raw != np.round(raw))


def test_saturation_clips_at_full_scale():
    effects = {"offset": {"offset_mg": [0, -1500, 1500]}, "quantization": {}}
    b = board({**effects, "saturation": {}})
    b.set_pose(FLAT)  # z would read 2.5 g, beyond the 2 g range
    np.testing.assert_array_equal(b.read(3)[0], [[0, -6144, 8191]] * 3)
    b.set_pose(PoseSpec("z-1g", 0, 180))
    np.testing.assert_array_equal(b.read(1)[0][0, 1:], [-6144, 2048])
    b.set_pose(Y_UP.__class__("y-1g", 0, -90))  # y: -1 g - 1.5 g = -2.5 g
    assert b.read(1)[0][0, 1] == -8192
    b = board({**effects, "saturation": {"full_scale_fraction": 0.5}})
    b.set_pose(FLAT)
    assert b.read(1)[0][0, 2] == 4095
    unclipped = board(effects)
    unclipped.set_pose(FLAT)
    assert unclipped.read(1)[0][0, 2] == 10240


def test_drift_warm_up_follows_its_time_constant():
    b = board({"drift": {"warmup_mg": [0, 0, 20.0], "warmup_tau_s": 30.0}})
    _, t0 = b.read(1)
    z0 = reading_g(b)[2]
    b.clock.sleep(60.0)
    counts, t = b.read(1)
    z1 = counts[0, 2] / 4096.0
    assert z0 - 1.0 == pytest.approx(0.020 * (1 - np.exp(-(t0[0] + 0.01) / 30.0)), abs=1e-12)
    assert z1 - 1.0 == pytest.approx(0.020 * (1 - np.exp(-t[0] / 30.0)), abs=1e-12)
    assert z1 > z0


def test_drift_random_walk_grows_as_sqrt_time():
    rw = 50.0  # ug/sqrt(s)
    ends = []
    for seed in range(400):
        b = board({"drift": {"random_walk_ug_per_rts": [rw, rw, rw]}}, seed=seed)
        c1, _ = b.read(1)  # t = 0.01 s
        b.clock.sleep(24.99)
        c2, _ = b.read(1)  # t = 25.01 s
        b.clock.sleep(75.0)
        c3, _ = b.read(1)  # t = 100.01 s
        ends.append([c1[0], c2[0], c3[0]])
    drift_ug = (np.array(ends) / 4096.0 - [0, 0, 1]) * 1e6  # (seeds, times, axes)
    sd = drift_ug.std(axis=0).mean(axis=1)
    # 400 boards x 3 axes: the sd estimates are within ~3 % (1 sd); 15 % is 5 sd
    np.testing.assert_allclose(sd[1:], rw * np.sqrt([25.01, 100.01]), rtol=0.15)
    assert sd[2] / sd[1] == pytest.approx(2.0, rel=0.15)  # grows with time as sqrt(t)


def test_settling_decays_with_its_time_constant():
    b = board({"settling": {"fraction": 0.05, "tau_s": 0.3}})
    b.set_pose(FLAT)
    b.clock.sleep(10.0)
    b.set_pose(X_UP)  # step of the true force: (+1, 0, -1) g
    t_step = b.clock.now()
    counts, t = b.read(100)
    g = counts / 4096.0
    tr = g - [1, 0, 0]
    np.testing.assert_allclose(tr[:, 0], 0.05 * np.exp(-(t - t_step) / 0.3), atol=1e-12)
    np.testing.assert_allclose(tr[:, 2], -0.05 * np.exp(-(t - t_step) / 0.3), atol=1e-12)
    tau = -1.0 / np.polyfit(t - t_step, np.log(tr[:, 0]), 1)[0]
    assert tau == pytest.approx(0.3, rel=1e-9)


def test_settling_follows_motion_as_a_first_order_response():
    b = board({"settling": {"fraction": -0.1, "tau_s": 0.2}})
    b.set_pose(FLAT)
    b.clock.sleep(5.0)
    path = rotation_path([0, 0, 1], [1, 0, 0], 100)
    counts, t = b.read_motion(path)
    # the last move step is tiny, so at the end of a smooth move the lag is small but present
    lag = counts[-1] / 4096.0 - [1, 0, 0]
    assert 0 < -lag[0] < 0.1 and np.all(np.isfinite(counts))
    after, t2 = b.read(200)
    assert np.abs(after[-1] / 4096.0 - [1, 0, 0]).max() < np.abs(lag).max() * np.exp(-1.9 / 0.2) * 1.01


# -- driver -----------------------------------------------------------------------------------

def test_make_driver_builds_the_simulated_driver():
    dev = make_driver(validate_device({"driver": "simulated", "chip": "mpu6050", "seed": 3, "range_g": 4, "odr_hz": 200,
                       "dlpf": 2, "ambient_c": 31.0}))
    assert isinstance(dev, SimulatedDriver)
    with pytest.raises(DeviceError, match="not open"):
        dev.read_samples(3)
    with dev:
        ident = dev.identify()
        assert (ident.chip, ident.chip_id, ident.interface) == ("mpu6050", 0x68, "simulated")
        assert (dev.range_g, dev.odr_hz, dev.counts_per_g) == (4, 200.0, 8192.0)
        dev.configure(range_g=2, dlpf=4)
        assert dev.counts_per_g == 16384.0 and dev.board.dlpf == 4 and dev.odr_hz == 200.0
        cap = dev.capture(seconds=1.0)
        assert cap.n == 200 and cap.temp_c == 31.0 and cap.dropped == 0
        np.testing.assert_allclose(cap.mean_counts / 16384.0, [0, 0, 1], atol=3e-3)
        assert dev.nvm is dev.board.eeprom
        with pytest.raises(ConfigError, match="unknown option 'oversampling'"):
            dev.configure(oversampling=2)
    with make_driver(validate_device({"driver": "simulated"})) as mma:
        assert mma.temperature_c() is None  # the MMA8451 has no temperature sensor


def test_driver_config_errors_carry_the_section_path():
    with pytest.raises(ConfigError, match=r"^device\.odr_hz: 7; allowed for mma8451"):
        make_driver(validate_device({"driver": "simulated", "odr_hz": 7}))


# -- EEPROM -----------------------------------------------------------------------------------

def test_jig_presents_poses_with_pose_error_and_move_time():
    b = board({"pose_error": {"jig_rotation_deg": [1.0, 0, 0], "scatter_deg": 0.2}}, seed=4)
    jig = SimulatedJig(b, move_time_s=1.5)
    with jig:
        jig.present(Y_UP)
    assert b.clock.now() == pytest.approx(1.5) and b.pose is Y_UP
    np.testing.assert_allclose(b.true_direction, b.true_rotation @ Y_UP.reference_g)
    err = np.degrees(np.arccos(b.true_direction @ Y_UP.reference_g))
    assert 0.3 < err < 2.5  # the 1 deg jig rotation plus a little scatter


def test_jig_records_smooth_motion_between_poses():
    b = board({"noise": {}, "quantization": {}}, seed=1)
    jig = SimulatedJig(b, move_time_s=2.0, record_motion=True)
    jig.present(X_UP)
    jig.present(PoseSpec("x-1g", 90, 0))  # a half turn
    (m1, t1), (m2, t2) = jig.motion
    assert len(m2) == 200 and t2[0] > t1[-1]
    norms = np.linalg.norm(m2 / 4096.0, axis=1)
    np.testing.assert_allclose(norms, 1.0, atol=0.01)  # a rotation, no linear acceleration
    assert np.abs(np.diff(m2[:, 0])).max() < 0.05 * 4096  # smooth: no jumps
    np.testing.assert_allclose(m2[-1] / 4096.0, [-1, 0, 0], atol=0.01)
    path = rotation_path([0, 0, 1], [0, 0, -1], 50)
    np.testing.assert_allclose(np.linalg.norm(path, axis=1), 1.0)
    np.testing.assert_allclose(path[-1], [0, 0, -1])


# -- ground truth recovered by the models ------------------------------------------------------

def random_board(rng, model: str, seed: int) -> SimulatedBoard:
    """A board with realistic errors drawn from rng, using only effects inside ``model``'s class."""
    gain = 1 + rng.uniform(-0.03, 0.03, 3)
    effects = {"offset": {"offset_mg": rng.uniform(-60, 60, 3).tolist()}, "gain": {"gain": gain.tolist()},
               "noise": {}, "quantization": {}}
    if model in ("12", "15"):
        C = rng.uniform(-0.01, 0.01, (3, 3))
        np.fill_diagonal(C, 0)
        effects["cross_axis"] = {"coupling": C.tolist(), "rotation_deg": rng.uniform(-1, 1, 3).tolist()}
    if model == "9":  # model 9's W is symmetric: diag(gain) (I + C) must be, and no rotation
        S = rng.uniform(-0.01, 0.01, (3, 3))
        S = (S + S.T) / 2
        np.fill_diagonal(S, 0)
        effects["cross_axis"] = {"coupling": (S / gain[:, None]).tolist()}
    if model == "15":
        effects["cubic"] = {"cubic_per_g2": rng.uniform(-0.006, 0.006, 3).tolist()}
    return board(effects, seed=seed)


N_SEEDS = 20
N_SAMPLES = 1000


# 20 boards per model and 6 + 9 + 12 + 15 = 42 parameters (model 9's W symmetric: 6 of 9
# distinct) make 840 z-scores; P(|z| > 4) = 6.33e-5 each, so a correct simulator fails this
# test with probability 1 - (1 - 6.33e-5)^840 = 5.2 % over random seed sets (the seeds here
# are fixed).  The spread check (sd of the z-scores within 0.75..1.25, so the predicted errors
# are not inflated) adds < 0.1 %.
@pytest.mark.parametrize("model, design", [("6", "six-face"), ("9", "nine-position"), ("12", "an4399-8"),
                                           ("15", "an4399-8")])
def test_fits_recover_the_truth_within_predicted_standard_errors(model, design):
    rng = np.random.default_rng(int(model) * 1000 + 17)
    poses = get_design(design)
    readings, truths = [], []
    for s in range(N_SEEDS):
        b = random_board(rng, model, seed=100 + s)
        means = []
        for pose in poses:
            b.set_pose(pose)
            means.append(b.read(N_SAMPLES)[0].mean(axis=0))
        readings.append(means)
        truths.append(b.truth())
        sigma = np.sqrt(b.noise_sigma_counts[0] ** 2 + 1 / 12)  # white noise plus 1-LSB rounding
    refs = np.array([p.reference_g for p in poses])
    fit = fit_batch(np.array(readings), refs, model, units="counts", counts_per_g=4096.0)
    assert fit.ok.all()
    se = predict_stderr(design, model, sigma / np.sqrt(N_SAMPLES) / 4096.0)
    z = {"W": (fit.W - [t.W for t in truths]) / np.where(se["W"] > 0, se["W"], np.inf),
         "V": (fit.V - [t.V for t in truths]) / se["V"]}
    if model == "6":
        z["W"] = np.diagonal(z["W"], axis1=1, axis2=2)
        np.testing.assert_allclose(fit.W - np.diagonal(fit.W, axis1=1, axis2=2)[..., None] * np.eye(3), 0)
    elif model == "9":
        z["W"] = z["W"][:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    if model == "15":
        z["Gamma"] = (fit.Gamma - [t.Gamma for t in truths]) / se["Gamma"]
    allz = np.concatenate([v.reshape(N_SEEDS, -1) for v in z.values()], axis=1)
    assert allz.shape[1] == int(model)
    worst = np.unravel_index(np.argmax(np.abs(allz)), allz.shape)
    assert np.abs(allz).max() < 4, f"board {worst[0]}, parameter {worst[1]}: z = {allz[worst]:.2f}"
    assert 0.75 < allz.std() < 1.25

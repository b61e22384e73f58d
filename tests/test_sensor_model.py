"""The effects catalog, its YAML schema, the chip defaults and the stateless forward model."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from accelcal_station.errors import ConfigError
from accelcal_station.sim.sensor_model import (
    CHIPS,
    EFFECT_NAMES,
    EFFECTS,
    SensorModel,
    get_chip,
    parse_effects,
    rotation_matrix,
)

MMA = CHIPS["mma8451"]
MPU = CHIPS["mpu6050"]

FULL = {  # every effect that the truth inverts, plus temperature
    "offset": {"offset_mg": [25.0, -40.0, 60.0]},
    "gain": {"gain": [1.02, 0.98, 1.01]},
    "cross_axis": {"coupling": [[0, 0.01, -0.02], [0.015, 0, 0.005], [-0.01, 0.02, 0]],
                   "rotation_deg": [0.5, -1.0, 2.0]},
    "cubic": {"cubic_per_g2": [0.004, -0.003, 0.006]},
    "temperature": {"t_ref_c": 20.0, "offset_mg_per_c": [0.2, -0.1, 0.3], "offset_mg_per_c2": [0.01, 0, -0.005],
                    "gain_ppm_per_c": [100, -200, 50], "gain_ppm_per_c2": [2, 1, -3]},
}


def test_catalog_names_follow_design_md_in_order():
    text = (Path(__file__).resolve().parents[1] / "docs" / "DESIGN.md").read_text()
    assert tuple(re.findall(r"^\| `(\w+)` \|", text, re.M)) == EFFECT_NAMES
    assert len(EFFECT_NAMES) == 13


def test_every_parameter_has_unit_doc_and_valid_default():
    for name, eff in EFFECTS.items():
        assert eff.doc and eff.params, name
        for p in eff.params:
            assert p.unit and p.doc, f"{name}.{p.name}"
        # an effect given with no parameters takes its defaults and validates
        parsed = parse_effects({name: {}}, MMA)
        assert set(parsed[name]) == {p.name for p in eff.params}


def test_chip_datasheet_defaults():
    assert [MMA.counts_per_g(r) for r in MMA.ranges_g] == [4096, 2048, 1024]
    assert [MPU.counts_per_g(r) for r in MPU.ranges_g] == [16384, 8192, 4096, 2048]
    assert MMA.code_limits == (-8192, 8191) and MPU.code_limits == (-32768, 32767)
    assert max(MMA.odr_hz) == 800 and not MMA.has_temperature and MPU.has_temperature
    assert MMA.noise_ug_per_rthz == 99.0
    assert MMA.enbw_hz(100.0) == 50.0
    # the DLPF's one-pole equivalent noise bandwidth (pi/2) f_c, whatever the ODR (issue 48's follow-up)
    assert MPU.enbw_hz(1000.0, 3) == pytest.approx(69.115, abs=1e-3)
    assert MPU.enbw_hz(50.0, 0) == pytest.approx(408.41, abs=1e-2)
    # noise defaults to the chip's density
    assert np.all(parse_effects({"noise": None}, MPU)["noise"]["density_ug_per_rthz"] == 400.0)


@pytest.mark.parametrize("chip, rng, odr, dlpf, key", [
    ("mma8451", 16, 100, None, "range_g"),
    ("mma8451", 2, 123, None, "odr_hz"),
    ("mma8451", 2, 100, 3, "dlpf"),
    ("mpu6050", 2, 300, 3, "odr_hz"),
    ("mpu6050", 2, 100, 7, "dlpf"),
])
def test_chip_configuration_refused_with_key(chip, rng, odr, dlpf, key):
    with pytest.raises(ConfigError, match=rf"^dev\.{key}: .*allowed"):
        get_chip(chip).check(rng, odr, dlpf, "dev")


def test_mpu6050_rates_are_divider_steps():
    assert MPU.check(16, 1000 / 7, 1, "dev") == (16, 1000 / 7, 1)
    assert MPU.check(2, 800, 0, "dev")[1] == 800.0  # DLPF off: 8 kHz / (1 + 9)
    with pytest.raises(ConfigError, match=r"odr_hz: 800; allowed for mpu6050 with dlpf 3: 1000 / \(1 \+ divider\)"):
        MPU.check(2, 800, 3, "dev")
    with pytest.raises(ConfigError, match=r"at most 1000"):
        MPU.check(2, 2000, 0, "dev")
    assert MMA.check(8, 1.5625, None, "dev")[1] == 1.5625


@pytest.mark.parametrize("effects, message", [
    ({"ofset": {}}, r"^e\.ofset: unknown key; allowed: offset, gain"),
    ({"offset": {"offset": [1, 2, 3]}}, r"^e\.offset\.offset: unknown key; allowed: enabled, offset_mg"),
    ({"offset": {"offset_mg": [1, 2, 3000]}}, r"^e\.offset\.offset_mg\[2\]: 3000 out of range"),
    ({"gain": {"gain": [1, "x", 1]}}, r"^e\.gain\.gain\[1\]: 'x' is not a number"),
    ({"gain": {"gain": [1, 1]}}, r"^e\.gain\.gain: \[1, 1\]; allowed"),
    ({"cross_axis": {"coupling": [[0.1, 0, 0], [0, 0, 0], [0, 0, 0]]}}, r"^e\.cross_axis\.coupling: diagonal"),
    ({"cross_axis": {"coupling": [[0, 0.5, 0], [0, 0, 0], [0, 0, 0]]}}, r"^e\.cross_axis\.coupling\[0\]\[1\]: 0.5 out"),
    ({"cross_axis": {"coupling": [0, 0, 0]}}, r"^e\.cross_axis\.coupling\[0\]: 0; allowed: a list .*3x3"),
    ({"noise": {"density_ug_per_rthz": -1}}, r"^e\.noise\.density_ug_per_rthz: -1 out of range; allowed: 0 to 100000"),
    ({"quantization": {"lsb_counts": 2.5}}, r"^e\.quantization\.lsb_counts: 2.5; allowed: a whole number 1 to 4096"),
    ({"settling": {"tau_s": 0}}, r"^e\.settling\.tau_s: 0 out of range"),
    ({"gravity": {"local_mps2": 12}}, r"^e\.gravity\.local_mps2: 12 out of range; allowed: 9.7 to 9.9"),
    ({"drift": {"enabled": "yes"}}, r"^e\.drift\.enabled: 'yes'; allowed: true, false"),
    ({"offset": 3}, r"^e\.offset: 3; allowed: a mapping"),
    ([1], r"^e: \[1\]; allowed: a mapping"),
])
def test_bad_effects_rejected_with_key_path(effects, message):
    with pytest.raises(ConfigError, match=message):
        parse_effects(effects, MMA, "e")


def test_effects_switch_on_and_off():
    m = SensorModel.from_config({"offset": {"offset_mg": [1, 2, 3], "enabled": False}, "gain": True,
                                 "noise": False, "drift": None}, MMA)
    assert m.enabled == ("gain", "drift")
    assert SensorModel.from_config(None, MMA).enabled == ("noise", "quantization", "saturation")


def test_to_config_round_trips_and_edits_by_name():
    m = SensorModel.from_config(FULL, MMA)
    again = SensorModel.from_config(m.to_config(), MMA)
    assert again.enabled == m.enabled == ("offset", "gain", "cross_axis", "cubic", "temperature")
    np.testing.assert_array_equal(again.linear_matrix(33.0), m.linear_matrix(33.0))
    m2 = m.with_effect("offset", offset_mg=[0, 0, 5]).without("cubic")
    assert m2.enabled == ("offset", "gain", "cross_axis", "temperature")
    np.testing.assert_allclose(m2.offset_g(20.0), [0, 0, 0.005])


def test_rotation_matrix_is_rodrigues():
    R = rotation_matrix([0, 0, 90])
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    Rs = rotation_matrix(np.random.default_rng(0).normal(0, 30, (50, 3)))
    np.testing.assert_allclose(Rs @ np.swapaxes(Rs, 1, 2), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(Rs), 1.0)


def test_linear_matrix_composition():
    m = SensorModel.from_config(FULL, MMA)
    C = np.array(FULL["cross_axis"]["coupling"])
    R = rotation_matrix(FULL["cross_axis"]["rotation_deg"])
    np.testing.assert_allclose(m.linear_matrix(20.0), np.diag(FULL["gain"]["gain"]) @ (np.eye(3) + C) @ R.T)


@pytest.mark.parametrize("temp", [-10.0, 20.0, 55.0])
def test_truth_inverts_the_forward_model_exactly(temp):
    m = SensorModel.from_config(FULL, MMA)
    f = np.random.default_rng(1).normal(size=(200, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    G = m.response_g(f, temp)
    # the implicit equation of stage 3 holds
    q, c = m.nonlinearity()
    np.testing.assert_allclose(np.linalg.solve(m.linear_matrix(temp), (G - m.offset_g(temp)).T).T - c * G**3, f,
                               atol=1e-14)
    cal = m.truth(temp, 4096.0)
    assert cal.model == "15" and cal.input_units == "counts" and cal.input_per_g == 4096.0
    np.testing.assert_allclose(cal.apply(G * 4096.0, "counts"), f, atol=1e-13)
    np.testing.assert_allclose(cal.Gamma, -np.array(FULL["cubic"]["cubic_per_g2"]))


def test_truth_is_not_claimed_for_quadratic():
    m = SensorModel.from_config({**FULL, "quadratic": {"quadratic_per_g": [0.005, 0, 0]}}, MMA)
    f = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    err = m.truth(20.0, 1.0).apply(m.response_g(f, 20.0), "counts") - f
    # the even term is left in: both faces are off by +q G^2 (about +5 mg) on x
    np.testing.assert_allclose(err[:, 0], 0.005 * m.response_g(f, 20.0)[:, 0] ** 2, rtol=1e-9)


def test_temperature_coefficients():
    m = SensorModel.from_config(FULL, MMA)
    dt = 35.0 - 20.0
    t = FULL["temperature"]
    np.testing.assert_allclose(m.offset_g(35.0) * 1e3, np.array(FULL["offset"]["offset_mg"])
                               + np.array(t["offset_mg_per_c"]) * dt + np.array(t["offset_mg_per_c2"]) * dt**2)
    ppm = np.array(t["gain_ppm_per_c"]) * dt + np.array(t["gain_ppm_per_c2"]) * dt**2
    np.testing.assert_allclose(m.gain(35.0), np.array(FULL["gain"]["gain"]) * (1 + 1e-6 * ppm))


def test_nonlinearity_that_folds_in_range_is_refused():
    m = SensorModel.from_config({"cubic": {"cubic_per_g2": [0.0, 0.01, 0.0]}}, MPU)
    m.check_range(2)
    with pytest.raises(ConfigError, match=r"cubic\.cubic_per_g2: too large for the 8 g range"):
        m.check_range(8)


def test_to_counts_saturates_then_quantizes():
    m = SensorModel.from_config({"saturation": {"full_scale_fraction": 0.5}, "quantization": {"lsb_counts": 4}}, MMA)
    out = m.to_counts(np.array([[3.0, -3.0, 0.2501]]), 4096.0)
    assert out.dtype == np.int64
    np.testing.assert_array_equal(out, [[4092, -4096, 1024]])  # clipped to 4095, the top multiple of 4 is 4092
    raw = SensorModel.from_config({}, MMA).to_counts(np.array([[3.0, 0.1, 0.0]]), 4096.0)
    assert raw.dtype == np.float64 and raw[0, 0] == 12288.0

"""The calibration core against the seed documents' worked examples and its own contracts."""
from __future__ import annotations

import json

import numpy as np
import pytest

from accelcal_station.calibration import Calibration, TemperatureTable, quadratic_coefficients
from accelcal_station.conventions import an4399_reference
from accelcal_station.errors import DataError, TemperatureRangeError, UnderdeterminedError, UnitsError
from accelcal_station.models.fitting import fit, fit_batch, fit_temperature
from accelcal_station.models.linear import six_param_six_face, six_param_two_pose
from accelcal_station.session import PoseRecord, Session

TOL = 2e-5  # the vector file's tolerance for printed decimals


def _example(an4399, name):
    e = an4399[name]
    ang = np.array(e["poses_deg"], dtype=float)
    return np.array(e["counts"], dtype=float), an4399_reference(ang[:, 0], ang[:, 1]), e["expected"]


def test_example_1_two_pose(an4399):
    e = an4399["example_1"]
    w, v = six_param_two_pose(np.array(e["counts"]["pose0"]) / 4096, np.array(e["counts"]["pose1"]) / 4096)
    np.testing.assert_allclose(w, e["expected"]["W_diag"], atol=5e-5)
    np.testing.assert_allclose(v, e["expected"]["V"], atol=5e-6)
    # apply the rounded coefficients, as the note does
    cal = Calibration("6", np.diag(e["expected"]["W_diag"]), e["expected"]["V"], input_units="counts",
                      input_per_g=4096)
    x = cal.apply([e["apply_check"]["x_counts"], 0, 0], units="counts")[0]
    assert abs(x - e["apply_check"]["x_calibrated_g"]) < 2e-6


def test_example_1_least_squares_matches_closed_form(an4399):
    e = an4399["example_1"]
    g = np.array([e["counts"]["pose0"], e["counts"]["pose1"]])
    ref = np.array([[1, 1, 1], [-1, -1, -1]]) / np.sqrt(3)
    r = fit(g, ref, "6", units="counts", counts_per_g=4096)
    np.testing.assert_allclose(np.diag(r.W), e["expected"]["W_diag"], atol=5e-5)
    np.testing.assert_allclose(r.V, e["expected"]["V"], atol=5e-6)
    assert r.crossval_rms_g is None  # two poses, two coefficients a channel: nothing left to cross-validate


def test_example_2_six_face(an4399):
    g = an4399["example_2"]["g_on_axis"]
    w, v = six_param_six_face([g[a][0] for a in "xyz"], [g[a][1] for a in "xyz"])
    np.testing.assert_allclose(w, an4399["example_2"]["expected"]["W_diag"], atol=5e-5)
    np.testing.assert_allclose(v, an4399["example_2"]["expected"]["V"], atol=5e-6)


@pytest.mark.parametrize("name,model", [("example_3", "12"), ("example_4", "12")])
def test_examples_3_4_twelve_parameter(an4399, name, model):
    counts, ref, exp = _example(an4399, name)
    r = fit(counts, ref, model, units="counts", counts_per_g=4096)
    np.testing.assert_allclose(r.W, exp["W"], atol=TOL)
    np.testing.assert_allclose(r.V, exp["V"], atol=TOL)
    if "P" in exp:
        np.testing.assert_allclose(r.P, exp["P"], atol=1e-12)
    else:
        np.testing.assert_allclose(r.P * 1e6, exp["P_times_1e6"], atol=0.005)


def test_example_5_fifteen_parameter(an4399):
    counts, ref, exp = _example(an4399, "example_5")
    r = fit(counts, ref, "15", units="counts", counts_per_g=4096)
    for i, a in enumerate("xyz"):
        row = exp[a]
        np.testing.assert_allclose(r.W[i], row[:3], atol=TOL)
        assert abs(r.V[i] - row[3]) < TOL
        assert abs(r.Gamma[i] - row[4]) < TOL
    # the note prints 196.62 where exact arithmetic gives 196.628 (its Gamma_zz is likewise
    # rounded): one unit of the last printed decimal
    np.testing.assert_allclose(r.P * 1e6, exp["P_times_1e6"], atol=0.01)


def test_example_6_quadratic_temperature(an4399):
    e = an4399["example_6"]
    a, b, c = quadratic_coefficients(e["temperatures_c"], e["W_xx"])
    assert abs(a - e["expected"]["alpha"]) < 1e-6
    assert abs(b - e["expected"]["beta"]) < 1e-8
    assert abs(c - e["expected"]["gamma"]) < 1e-10
    K = len(e["temperatures_c"])
    W = np.tile(np.eye(3), (K, 1, 1))
    W[:, 0, 0] = e["W_xx"]
    table = TemperatureTable(e["temperatures_c"], W, np.zeros((K, 3)), np.zeros((K, 3)), "quadratic")
    Wt, _, _ = table.interpolate(32.0)
    assert abs(Wt[0, 0] - e["expected"]["at_32c"]) < 1e-6


def test_temperature_refuses_silent_extrapolation():
    table = TemperatureTable([0, 40], np.tile(np.eye(3), (2, 1, 1)), [[0, 0, 0], [0.01, 0, 0]],
                             np.zeros((2, 3)), "linear")
    _, V, _ = table.interpolate(20.0)
    assert V[0] == pytest.approx(0.005)
    with pytest.raises(TemperatureRangeError, match="outside the calibrated range 0 to 40"):
        table.interpolate(50.0)
    _, V, _ = table.interpolate(50.0, extrapolate=True)
    assert V[0] == pytest.approx(0.0125)


def test_fit_temperature_recovers_linear_drift():
    rng = np.random.default_rng(1)
    ref = an4399_reference(*np.array([[39, -158], [-66, 164], [18, 66], [-1, -44], [6, -55], [-20, 33]]).T)
    poses = []
    for t in (-10.0, 25.0, 60.0):
        offset = np.array([0.01, -0.02, 0.005]) + 1e-4 * (t - 25) * np.array([1, 2, -1])
        g = ref * (1 + 1e-4 * (t - 25)) + offset + rng.normal(0, 1e-5, ref.shape)
        poses += [PoseRecord(f"p{i}@{t}", g[i] * 4096, reference_g=ref[i], temp_c=t) for i in range(len(ref))]
    s = Session(poses, units="counts", counts_per_g=4096)
    cal, fits = fit_temperature(s, "12", "quadratic")
    assert [t for t, _ in fits] == [-10.0, 25.0, 60.0]
    # the calibration applied at an intermediate temperature gives the references back
    t = 42.5
    g = ref * (1 + 1e-4 * (t - 25)) + np.array([0.01, -0.02, 0.005]) + 1e-4 * (t - 25) * np.array([1, 2, -1])
    out = cal.apply(g * 4096, units="counts", temp_c=t)
    assert np.max(np.abs(out - ref)) < 2e-4
    with pytest.raises(TemperatureRangeError):
        cal.apply(g * 4096, units="counts", temp_c=80.0)
    with pytest.raises(UnitsError, match="temperature"):
        cal.apply(g * 4096, units="counts")



def test_fit_temperature_model_9_on_counts_keeps_one_scale():
    # model 9 on counts without counts_per_g estimates a scale per temperature group; the
    # table must still give unit norms at every calibration temperature (it gave 1.5 % off at 50 C)
    ref = an4399_reference(*np.array([[0, 0], [0, 90], [0, 180], [0, -90], [90, 0], [-90, 0],
                                      [-45, 90], [0, 45], [-45, 0], [30, 120]]).T)

    def counts(t):
        gain = np.array([1.02, 0.98, 1.01]) * (1 + np.array([1e-3, -2e-3, 5e-4]) * t)
        return 4096 * (ref * gain + np.array([0.03, -0.02, 0.05]) + 1e-3 * t * np.array([0.5, -0.3, 0.2]))

    poses = [PoseRecord(f"p{i}@{t}", c, temp_c=t) for t in (0.0, 50.0) for i, c in enumerate(counts(t))]
    cal, _ = fit_temperature(Session(poses, units="counts"), "9")
    for t in (0.0, 50.0):
        out = cal.apply(counts(t), units="counts", temp_c=t)
        np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-9)


def test_mps2_calibration_applies_with_its_own_gravity():
    ref = an4399_reference([-90, 90, 0, 0, 0, 0], [0, 0, 90, -90, 0, 180])
    cal = fit(ref * 9.79, ref, "6", units="mps2", gravity_mps2=9.79).calibration
    np.testing.assert_allclose(cal.apply(ref * 9.79, units="mps2"), ref, atol=1e-12)
    # an explicit gravity still wins
    np.testing.assert_allclose(cal.apply(ref * 9.80665, units="mps2", gravity_mps2=9.80665), ref, atol=1e-12)


def test_calibraxis_norm_model_within_10_mg(calibraxis):
    for key in ("set_1_counts", "set_2_counts"):
        x = np.array(calibraxis[key])
        for data, units, extra in ((x, "counts", {}), (x + 32768, "counts", {}),
                                   (x / 4096 * 9.79, "mps2", {"gravity_mps2": 9.79})):
            r = fit(data, model="9", units=units, **extra)
            assert r.success
            assert np.max(np.abs(r.norm_error_g)) < 0.01, (key, units)
            assert r.crossval_rms_g is not None and r.crossval_rms_g < 0.05
            # the AN4399 form reproduces the norm model
            out = r.calibration.apply(data, units=units, **extra)
            np.testing.assert_allclose(np.linalg.norm(out, axis=1) - 1, r.norm_error_g, atol=1e-12)


def test_norm_model_recovers_a_known_sensor():
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(24, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    M = np.array([[1.02, 0.01, -0.005], [0.01, 0.97, 0.003], [-0.005, 0.003, 1.01]])
    B = np.array([0.05, -0.03, 0.02])
    raw = np.linalg.solve(M, dirs.T).T + B  # A = M (raw - B) = dirs
    r = fit(raw * 16384 + 32768, model="9", units="counts", counts_per_g=16384)
    cal = r.calibration.apply(raw * 16384 + 32768, units="counts")
    np.testing.assert_allclose(cal, dirs, atol=1e-9)


def test_batch_identical_to_one_at_a_time(an4399):
    counts, ref, _ = _example(an4399, "example_5")
    rng = np.random.default_rng(3)
    stack = counts[None] + rng.normal(0, 2.0, (50,) + counts.shape)
    for model in ("6", "12", "15"):
        b = fit_batch(stack, ref, model, units="counts", counts_per_g=4096)
        for d in (0, 17, 49):
            one = fit(stack[d], ref, model, units="counts", counts_per_g=4096)
            # the stacked closed forms sum over a block of boards: equal to rounding (1e-12)
            np.testing.assert_allclose(b.W[d], one.W, rtol=0, atol=1e-12)
            np.testing.assert_allclose(b.V[d], one.V, rtol=0, atol=1e-12)
            assert b.result(d).crossval_rms_g == pytest.approx(one.crossval_rms_g, rel=1e-9)
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    raw = dirs[None] * rng.uniform(0.95, 1.05, (20, 1, 3)) + rng.normal(0, 0.02, (20, 1, 3))
    b = fit_batch(raw, None, "9")
    for d in (0, 19):
        one = fit(raw[d], model="9")
        np.testing.assert_allclose(b.W[d], one.W, rtol=0, atol=1e-12)


def test_batch_flags_unfittable_boards_without_dropping_them(an4399):
    counts, ref, _ = _example(an4399, "example_4")
    stack = np.stack([counts, counts])
    stack[1, :, 2] = 100.0  # board 1: z channel stuck
    b = fit_batch(stack, ref, "12", units="counts", counts_per_g=4096)
    assert b.ok.tolist() == [True, False]
    assert "channel z has no spread" in b.messages[1]


@pytest.mark.parametrize("readings,ref,model,match", [
    (np.eye(3), np.eye(3), "12", "needs at least 4 poses"),
    (np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0.0]]), np.eye(4, 3), "12", "channel z has no spread"),
])
def test_underdetermined_pose_sets_say_what_is_missing(readings, ref, model, match):
    with pytest.raises(UnderdeterminedError, match=match):
        fit(readings, ref, model)


def test_an_undetermined_cubic_is_held_and_named():
    """Six exact faces: model 15's cubic cannot be told from the gain, model 12's terms can (models/held.py)."""
    faces = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    r = fit(faces, faces, "15")
    assert [h.term for h in r.held] == ["Gamma_xx", "Gamma_yy", "Gamma_zz"] and "cubic" in r.held[0].reason
    np.testing.assert_array_equal(r.Gamma, 0.0)


def test_planar_poses_are_refused():
    a = np.deg2rad(np.arange(0, 360, 45))
    flat = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) + [0, 0, 0.3]
    c, s = np.cos(0.6), np.sin(0.6)
    planar = flat @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T  # a tilted plane: every channel spreads
    with pytest.raises(UnderdeterminedError, match="plane"):
        fit(planar, planar, "12")
    with pytest.raises(UnderdeterminedError,
                       match="6 distinct orientations; the 9-parameter norm model needs at least 9"):
        fit(planar[:6], model="9")


def test_units_are_checked():
    x = an4399_reference([0, 90, 0, -30], [0, 0, 90, 60]) * 4096
    ref = an4399_reference([0, 90, 0, -30], [0, 0, 90, 60])
    with pytest.raises(UnitsError, match="counts given as g"):
        fit(x, ref, "12", units="g")
    with pytest.raises(UnitsError, match="counts-per-g"):
        fit(x, ref, "12", units="counts")
    with pytest.raises(UnitsError, match="unknown units"):
        fit(x, ref, "12", units="furlongs")
    with pytest.raises(DataError, match="NaN"):
        fit(np.where(x == x.max(), np.nan, x), ref, "12", units="counts", counts_per_g=4096)


def test_calibration_json_round_trip_and_unit_checks(tmp_path, an4399):
    counts, ref, _ = _example(an4399, "example_5")
    cal = fit(counts, ref, "15", units="counts", counts_per_g=4096).calibration
    p = tmp_path / "cal.json"
    cal.save(p)
    back = Calibration.load(p)
    assert json.loads(p.read_text())["version"] == 1
    np.testing.assert_array_equal(back.W, cal.W)
    np.testing.assert_array_equal(back.apply(counts, units="counts"), cal.apply(counts, units="counts"))
    np.testing.assert_allclose(back.apply(counts / 4096, units="g"), cal.apply(counts, units="counts"))
    with pytest.raises(UnitsError, match="4096 counts/g; data given at 8192"):
        back.apply(counts, units="counts", counts_per_g=8192)
    bad = json.loads(p.read_text())
    bad["version"] = 99
    p.write_text(json.dumps(bad))
    with pytest.raises(DataError, match="version 99"):
        Calibration.load(p)


def test_standard_errors_match_monte_carlo(an4399):
    # 400 noisy copies of the octahedron design: the fit's own standard errors agree with the
    # scatter of its estimates within 15 % (chi-square spread of 400 samples is ~7 %: fails < 1e-4).
    _, ref, _ = _example(an4399, "example_4")
    rng = np.random.default_rng(11)
    sigma = 1e-3
    stack = ref[None] + rng.normal(0, sigma, (400,) + ref.shape)
    b = fit_batch(stack, ref, "12", noise=np.full(ref.shape, sigma))
    emp = b.V.std(axis=0)
    pred = b.stderr_V.mean(axis=0)
    np.testing.assert_allclose(emp, pred, rtol=0.15)


@pytest.mark.parametrize("model", ["6", "9", "12", "15"])
def test_fit_batch_does_not_depend_on_its_threads(model):
    """fit_batch cuts a large stack into blocks of boards fitted on threads (models 6, 9, 15;
    fit_stacked's own blocks for 12): every figure of every board must be the same, to the bit,
    on 1, 2 or 3 threads, with boards that are refused, that hold a term or that have an absurd
    reading (named as such) spread over the blocks."""
    from accelcal_station.fixtures.designs import get_design, references
    from accelcal_station.models.fitting import FRONT_BLOCK, fit_batch, front_blocks

    rng = np.random.default_rng(int(model))
    ref = np.asarray(references(get_design({"6": "six-face", "9": "nine-position"}.get(model, "optimal-12"))))
    D = 2 * FRONT_BLOCK.get(model, 8192) + 1001
    assert len(front_blocks(D, model)) == (1 if model == "12" else 3)
    W = np.eye(3) + 0.01 * rng.standard_normal((D, 3, 3))
    x = np.einsum("dij,dpj->dpi", np.linalg.inv(W), ref - 0.02 * rng.standard_normal((D, 1, 3)))
    x += 1e-3 * rng.standard_normal(x.shape)
    odd = rng.choice(D, 40, replace=False)
    x[odd[:10], :, 2] *= 0.01  # a flattened axis: refused, or a term held
    x[odd[10:20], 1] = x[odd[10:20], 0]  # a revisit: cross-validated by orientation
    x[odd[20:25], 2] = 1e300  # an absurd reading
    noise = np.full(x.shape, 1e-3)
    runs = [fit_batch(x, None if model == "9" else ref, model, noise=noise, workers=w) for w in (1, 2, 3)]
    assert not runs[0].ok[odd[20:25]].any() and runs[0].ok.sum() > D - 60
    if model != "9":  # model 9 judges its output, not raw readings (any offset)
        assert all("a reading of gravity is 0.3 to 3 g" in runs[0].messages[d] for d in odd[20:25])
    for other in runs[1:]:
        for name in ("W", "V", "Gamma", "residuals_g", "residual_rms_g", "crossval_rms_g", "condition_number",
                     "stderr_W", "crossval_by_orientation_rms_g", "readings_g", "ok", "poses_apart"):
            assert np.array_equal(getattr(other, name), getattr(runs[0], name), equal_nan=name != "ok"), name
        assert other.messages == runs[0].messages and other.held == runs[0].held


def test_absurd_coefficients_clears_a_sane_stack_as_board_by_board():
    """absurd_coefficients clears a whole stack by a few reductions when every W - I entry is
    within 0.8 / 3 and every offset within its limit; that must be what board-by-board judging
    says: stacks up to that edge (laid out as the stacked fitters lay out W, boards last, and
    plainly) are judged both ways (a board past every limit appended forces board by board)."""
    from accelcal_station.models.sanity import OFFSET_MAX_G, _all_sane, absurd_coefficients

    rng = np.random.default_rng(5)
    for scale in (0.01, 0.2, 0.8 / 3, 0.3, 0.6):
        W = np.eye(3) + rng.uniform(-scale, scale, (2000, 3, 3))
        V = rng.uniform(-OFFSET_MAX_G, OFFSET_MAX_G, (2000, 3)) * min(1.0, scale * 4)
        for Wl in (W, np.ascontiguousarray(W.transpose(2, 1, 0)).transpose(2, 1, 0)):
            fast = absurd_coefficients(Wl, V).mask
            one_by_one = absurd_coefficients(np.concatenate([Wl, [np.full((3, 3), np.nan)]]),
                                             np.concatenate([V, [[5.0, 0, 0]]])).mask
            assert one_by_one[-1] and np.array_equal(fast, one_by_one[:-1]), scale
            if _all_sane(Wl, V):
                assert scale <= 0.8 / 3 and not fast.any()
    assert not _all_sane(np.eye(3)[None] * 1.3, np.zeros((1, 3)))
    assert not _all_sane(np.eye(3)[None], np.ones((1, 3)) * 2)


def test_model_12_fit_beside_its_front_gives_the_same_bits():
    """With two threads, fit_batch starts model 12's fit beside its front (the fit does not depend
    on the plan: model 12 holds no term); every figure must be what one thread gives, refused and
    revisiting boards included, and the fit must have run on its own thread (seen by thread name)."""
    import threading

    from accelcal_station.fixtures.designs import get_design, references
    from accelcal_station.models.fitting import OVERLAP_BOARDS

    rng = np.random.default_rng(12)
    ref = np.asarray(references(get_design("an4399-8")))
    D = OVERLAP_BOARDS + 777
    W = np.eye(3) + 0.01 * rng.standard_normal((D, 3, 3))
    x = np.einsum("dij,dpj->dpi", np.linalg.inv(W), ref - 0.02 * rng.standard_normal((D, 1, 3)))
    x += 1e-3 * rng.standard_normal(x.shape)
    x[:20, :, 2] *= 0.01  # refused: a flattened axis
    x[20:40, 1] = x[20:40, 0]  # a revisit
    one = fit_batch(x, ref, "12", workers=1)
    names: set[str] = set()

    def seen(*_: object) -> None:
        names.add(threading.current_thread().name)

    before = threading.gettrace()
    threading.settrace(seen)  # called in every thread started from here on
    try:
        two = fit_batch(x, ref, "12", workers=2)
    finally:
        threading.settrace(before)  # type: ignore[arg-type]
    assert any(n.startswith("accelcal-fit12") for n in names), names
    assert not one.ok[:20].any() and one.ok[40:].all()
    for name in ("W", "V", "residuals_g", "residual_rms_g", "crossval_rms_g", "condition_number", "stderr_W",
                 "crossval_by_orientation_rms_g", "ok", "poses_apart"):
        assert np.array_equal(getattr(two, name), getattr(one, name), equal_nan=name != "ok"), name
    assert two.messages == one.messages and two.held == one.held

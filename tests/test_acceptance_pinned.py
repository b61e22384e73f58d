"""Issue 53: the acceptance rules' own parts pinned to values written here: each measure of a fit
whose W, V, Gamma are chosen by hand (so every figure is known without the program), the
distinct-pose rule at its bounds (a model's unknowns per axis plus one: AN4399 6 -> 2 + 1,
12 -> 4 + 1, 15 -> 5 + 1), the limits a config gives and the safe default, and typed reasons
as they are stored and read back."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from accelcal_station.acceptance.reasons import Reason, codes, wrap
from accelcal_station.acceptance.rules import (
    DEFAULT_LIMITS,
    MEASURES,
    FitFigures,
    Limits,
    SelfTestLimits,
    judge_all,
    limit_reasons,
    measure,
    measure_all,
)
from accelcal_station.config.schema import AcceptanceSection


def figures(W, V, Gamma=(0.0, 0.0, 0.0), rms=1e-4, rmax=3e-4, cv=2e-4, se_v=5e-5, se_w=1e-5, poses=8,
            model="12") -> FitFigures:
    one = lambda v: np.array([v], dtype=float)  # noqa: E731
    return FitFigures(model, np.array([W], dtype=float), np.array([V], dtype=float), np.array([Gamma], dtype=float),
                      one(rms), one(rmax), one(cv), one(se_v), one(se_w), np.array([poses]), [["Gamma held"]])


W = [[1.02, 0.004, -0.007], [0.003, 0.96875, 0.001], [-0.002, 0.0, 1.01]]  # binary fractions: exact figures
V = [0.018, -0.046875, 0.030]


def test_each_measure_is_the_hand_value():
    m = {k: float(v[0]) for k, v in measure_all(figures(W, V, (0.0, -0.002, 0.001))).items()}
    assert m == pytest.approx({
        "residual_rms_mg": 0.1, "residual_max_mg": 0.3, "crossval_rms_mg": 0.2,
        "gain_error_max": 0.03125,  # |0.96875 - 1|
        "cross_axis_max": 0.007,  # |W_xz|
        "offset_max_mg": 46.875,  # |V_y|
        "cubic_max": 0.002, "stderr_offset_max_mg": 0.05, "stderr_gain_max": 1e-5,
    }, rel=1e-12)


def test_limits_hold_at_the_limit_and_fail_above_it():
    f = figures(W, V)
    assert judge_all(f, Limits({"offset_max_mg": 46.875, "gain_error_max": 0.03125}))[0].passed  # <= holds
    (v,) = judge_all(f, Limits({"offset_max_mg": 46.87, "gain_error_max": 0.0312}))
    assert not v.passed and v.label == "FAIL"
    assert v.reasons == ["offset_max_mg 46.88 > limit 46.87 (largest |V_i|, mg)",
                         "gain_error_max 0.03125 > limit 0.0312 (largest |W_ii - 1| (W maps reading in g to g), "
                         "fraction)"]
    assert codes(v.reasons) == ["offset_max_mg", "gain_error_max"]
    assert v.held == ["Gamma held"] and v.measured["distinct_poses"] == 8.0
    assert judge_all(f, Limits({}))[0].label == "PASS"


def test_an_unmeasurable_figure_fails():
    (v,) = judge_all(figures(W, V, se_v=np.nan), Limits({"stderr_offset_max_mg": 1.0}))
    assert not v.passed and v.reasons == ["stderr_offset_max_mg: not measurable for this fit (limit 1)"]
    assert "stderr_offset_max_mg" not in v.measured


@pytest.mark.parametrize("model,need", [("6", 3), ("12", 5), ("15", 6), ("9", 10)])
def test_distinct_poses_rule_at_its_bounds(model, need):
    m = measure_all(figures(W, V, model=model))
    assert limit_reasons(m, np.array([need]), model, Limits({}), planned_poses=need) == [[]]
    (few,) = limit_reasons(m, np.array([need - 1]), model, Limits({}), planned_poses=need)
    assert codes(few) == ["distinct_poses"]
    assert few[0].startswith(f"distinct_poses {need - 1} < {need} needed by model {model} ")
    (skipped,) = limit_reasons(m, np.array([need]), model, Limits({}), planned_poses=need + 1)
    assert skipped == [f"distinct_poses {need} < {need + 1} planned (a pose was skipped or repeated)"]


def test_limits_from_a_config_and_the_safe_default():
    lim = Limits.from_config({"residual_rms_mg": 1, "self_test": False, "offset_trim_tolerance": 0.5})
    assert lim.values == {"residual_rms_mg": 1.0, "crossval_rms_mg": 10.0} == {"residual_rms_mg": 1.0,
                                                                               **DEFAULT_LIMITS}
    assert lim.defaulted == ["crossval_rms_mg"] and lim.offset_trim_tolerance == 0.5
    assert lim.self_test == SelfTestLimits(False) and not lim.self_test.overridden
    assert lim.defaults_line() == "acceptance: crossval_rms_mg not set, using the safe default 10"
    given = Limits.from_section(AcceptanceSection(crossval_rms_mg=2.0, self_test_tolerance=0.2))
    assert given.defaulted == [] and given.defaults_line() == "" and given.values == {"crossval_rms_mg": 2.0}
    assert given.self_test.overridden and given.self_test.tolerance == 0.2 and given.self_test.run
    low = Limits.from_section(AcceptanceSection(self_test_low_g=[0.1, 0.1, 0.5]))
    assert low.self_test.low_g == (0.1, 0.1, 0.5) and low.self_test.high_g is None and low.self_test.overridden
    assert Limits.from_section(None).values == DEFAULT_LIMITS


def test_reasons_read_stored_and_read_back():
    r = Reason("nvm", "read-back differs")
    assert (str(r), r.code) == ("nvm: read-back differs", "nvm")
    lim = Reason("residual_rms_mg", "1.2 > limit 1", sep=" ")
    assert str(lim) == "residual_rms_mg 1.2 > limit 1"
    assert r.to_dict() == {"code": "nvm", "message": "nvm: read-back differs"}
    back = Reason.from_dict(r.to_dict())
    assert back == r and back.code == "nvm" and isinstance(back, Reason)
    assert Reason.from_dict({"message": "x"}).code == "" and Reason.from_dict("plain").code == ""
    assert Reason.from_dict(r) is r
    assert Reason.from_dict({"code": None, "message": "m"}) == "m"
    pickled = pickle.loads(pickle.dumps(lim))
    assert pickled == lim and pickled.code == "residual_rms_mg"
    w = wrap(lim, "at 70 C: ")
    assert (str(w), w.code) == ("at 70 C: residual_rms_mg 1.2 > limit 1", "residual_rms_mg")
    assert wrap("text", "p: ").code == "" and codes([r, "bare"]) == ["nvm", ""]


def test_figures_of_several_boards_are_each_boards_own():
    """judge_all over B = 2 boards: each board's figures and verdict are its own."""
    a, b = figures(W, V), figures(np.eye(3) + 0.002 * (1 - np.eye(3)), [0.001, 0.0, -0.002], rms=2e-4)
    both = FitFigures("12", *(np.concatenate([x, y]) for x, y in zip(
        (a.W, a.V, a.Gamma, a.residual_rms_g, a.residual_max_g, a.crossval_rms_g, a.stderr_V_max_g, a.stderr_W_max,
         a.distinct_poses),
        (b.W, b.V, b.Gamma, b.residual_rms_g, b.residual_max_g, b.crossval_rms_g, b.stderr_V_max_g, b.stderr_W_max,
         b.distinct_poses), strict=True)))
    m = measure_all(both)
    assert m["cross_axis_max"].tolist() == pytest.approx([0.007, 0.002], rel=1e-12)
    assert m["offset_max_mg"].tolist() == pytest.approx([46.875, 2.0], rel=1e-12)
    assert m["residual_rms_mg"].tolist() == pytest.approx([0.1, 0.2], rel=1e-12)
    va, vb = judge_all(both, Limits({"cross_axis_max": 0.005}))
    assert not va.passed and vb.passed and va.held == [] and vb.measured["cross_axis_max"] == pytest.approx(0.002)


def test_measure_of_one_fit_is_the_hand_value():
    from accelcal_station.models.fitting import fit

    refs = np.array([[s1, s2, s3] for s1 in (1, -1) for s2 in (1, -1) for s3 in (1, -1)]) / np.sqrt(3.0)
    x = refs @ np.array(W).T + V  # an exact board: no residual, no noise given
    m = measure(fit(x, refs, "12", units="g"))
    assert m["residual_rms_mg"] == pytest.approx(0.0, abs=1e-9)
    # W maps readings to g: the inverse of the board's own matrix, offset -W^-1 V
    Wi = np.linalg.inv(W)
    assert m["offset_max_mg"] == pytest.approx(np.max(np.abs(Wi @ V)) * 1e3, rel=1e-9)
    assert m["gain_error_max"] == pytest.approx(np.max(np.abs(np.diag(Wi) - 1)), rel=1e-9)
    # no noise given: the residuals' RSS / (P - k) estimates it, and an exact board has none
    assert m["stderr_offset_max_mg"] == pytest.approx(0.0, abs=1e-9) and set(m) == set(MEASURES)

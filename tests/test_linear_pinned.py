"""Issue 53: the AN4399 linear fits (models/linear.py) and the by-orientation folds
(models/crossval.py) pinned to values computed here: ``np.linalg.lstsq`` per channel, the standard
error from RSS / (P - k) when no noise is given (AN4399 Eqn 46 and the usual least-squares
covariance), the closed forms' refusals at their stated thresholds, and a board with more
distinct orientations than the fold limit."""
from __future__ import annotations

import numpy as np
import pytest

from accelcal_station.errors import UnderdeterminedError
from accelcal_station.models.crossval import MAX_FOLDS
from accelcal_station.models.fitting import fit
from accelcal_station.models.linear import fit_linear_batch, six_param_six_face, six_param_two_pose

CUBE = np.array([[s1, s2, s3] for s1 in (1, -1) for s2 in (1, -1) for s3 in (1, -1)]) / np.sqrt(3.0)


def board(refs: np.ndarray, seed: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    K = np.diag([1.012, 0.987, 1.021]) + 0.004 * rng.standard_normal((3, 3)) * (1 - np.eye(3))
    return refs @ K.T + [0.018, -0.027, 0.041] + 3e-4 * rng.standard_normal(refs.shape)


@pytest.mark.parametrize("model", ["6", "15"])
def test_stderr_from_the_residuals_when_no_noise_is_given(model):
    refs = np.vstack([CUBE, np.eye(3), -np.eye(3), CUBE[:4] * [[1, 1, 0.2]] / np.linalg.norm([1, 1, 0.2])])
    x = board(refs)
    b = fit_linear_batch(x[None], refs, model)
    P = len(x)
    for c in range(3):
        cols = [x[:, c]] if model == "6" else [x[:, 0], x[:, 1], x[:, 2]]
        if model == "15":
            cols.append(np.ones(P))
            cols.append(x[:, c] ** 3)
        else:
            cols.append(np.ones(P))
        X = np.column_stack(cols)
        beta, rss, *_ = np.linalg.lstsq(X, refs[:, c], rcond=None)
        k = X.shape[1]
        se = np.sqrt(np.diag(rss[0] / (P - k) * np.linalg.inv(X.T @ X)))
        iv = 1 if model == "6" else 3
        assert b.V[0, c] == pytest.approx(beta[iv], rel=1e-9, abs=1e-12)
        assert b.stderr_V[0, c] == pytest.approx(se[iv], rel=1e-6)
        assert b.stderr_W[0, c, c] == pytest.approx(se[0 if model == "6" else c], rel=1e-6)
        if model == "15":
            assert b.Gamma[0, c] == pytest.approx(beta[4], rel=1e-7, abs=1e-12)
        r = refs[:, c] - X @ beta
        assert b.P[0, c] == pytest.approx(np.sum(r**2), rel=1e-6)
        np.testing.assert_allclose(b.residuals_g[0, :, c], r, atol=1e-12)
    calibrated = refs - b.residuals_g[0]
    np.testing.assert_allclose(b.norm_error_g[0], np.linalg.norm(calibrated, axis=1) - np.linalg.norm(refs, axis=1),
                               atol=1e-12)
    assert b.ok[0] and b.stderr_ok[0] and b.condition_number[0] > 1


def test_closed_forms_refuse_at_their_threshold():
    # AN4399 Eqns 6-17: channels that read the same (within 1e-6 g) on both poses are not opposite
    up, down = np.array([0.6, 0.55, 0.58]), np.array([-0.56, -0.6, -0.57])
    w, v = six_param_two_pose(up, down)
    np.testing.assert_allclose(w, 2 / np.sqrt(3) / (up - down))
    np.testing.assert_allclose(v, 1 / np.sqrt(3) - w * up)
    with pytest.raises(UnderdeterminedError, match="must be opposite"):
        six_param_two_pose(up, [-0.56, -0.6, 0.58 - 7e-7])  # x, y opposite; z reads the same within 7e-7 g
    w, v = six_param_six_face([1.02, 0.99, 1.01], [-0.98, -1.01, -0.97])
    np.testing.assert_allclose(w, [1.0, 1.0, 2 / 1.98])
    np.testing.assert_allclose(v, [-0.02, 0.01, -w[2] * 0.02])
    with pytest.raises(UnderdeterminedError, match="faces must be opposite"):
        six_param_six_face([1.0, 1.0, 1.0], [-1.0, 1.0 + 7e-7, -1.0])


def fibonacci(n: int) -> np.ndarray:
    """n directions spread over the sphere (golden-angle spiral), ~sqrt(4 pi / n) rad apart."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    rho = np.sqrt(1 - z**2)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def test_more_orientations_than_the_fold_limit_are_not_cross_validated_by_orientation():
    refs = fibonacci(MAX_FOLDS + 1)
    refs = np.vstack([refs, refs[:1]])  # one orientation revisited
    f = fit(board(refs), refs, "12", units="g")
    assert f.distinct_orientations == MAX_FOLDS + 1 == 257
    assert f.crossval_by_orientation_rms_g is None or np.isnan(f.crossval_by_orientation_rms_g)
    assert f.crossval_rms_g is not None and f.crossval_rms_g > 0
    few = fibonacci(40)
    few = np.vstack([few, few[:1]])
    g = fit(board(few), few, "12", units="g")
    assert g.distinct_orientations == 40 and g.crossval_by_orientation_rms_g > 0


def test_what_an_underdetermined_design_lacks_is_named():
    from accelcal_station.models.linear import diagnose_underdetermined

    u, v = np.array([1, -1, 0]) / np.sqrt(2), np.array([1, 1, -2]) / np.sqrt(6)
    t = np.radians(np.arange(0, 360, 60))
    plane = np.outer(np.cos(t), u) + np.outer(np.sin(t), v)  # every pose in the plane x + y + z = 0
    msg = diagnose_underdetermined(plane, "12")
    assert msg.startswith("the 6 poses lie in a plane (normal ") and "model 12 needs poses out of that plane" in msg
    normal = np.array([float(x) for x in msg.split("(normal ")[1].split(")")[0].split(",")])
    np.testing.assert_allclose(np.abs(normal), [0.58, 0.58, 0.58])
    faces = np.vstack([np.eye(3), -np.eye(3)])
    assert diagnose_underdetermined(faces, "15").startswith("the 6 poses are 3 opposite pairs: the cubic terms")
    assert diagnose_underdetermined(faces, "12") == "the poses do not determine model 12 (the design is " \
        "numerically singular)"
    # seven poses, one unpaired (x and y at 0.7 g), channel z only near 0 and +-1 g: its cubic is lost in its gain
    seven = np.vstack([faces, [[np.sqrt(0.5), np.sqrt(0.5), 0]]])
    assert diagnose_underdetermined(seven, "15").startswith("the cubic term of channel z cannot be told from its gain")
    assert diagnose_underdetermined(faces[:4], "15") == "model 15 needs at least 5 poses; got 4"
    assert diagnose_underdetermined(np.array([[1, 0, 0], [0.98, 0.1, 0.1], [1, 0.2, 0.0]]), "6").startswith(
        "channel x has no spread across the 3 poses (all within 0.020 g)")


def test_the_diagnosis_thresholds_at_their_stated_values():
    """A plane is named when the smallest centred singular value is below 1e-3 of the largest; a channel's
    levels are compared at 0.1 g; two directions are a pair when |d_p + d_q| < 0.1."""
    from accelcal_station.models.linear import diagnose_underdetermined

    u, v = np.array([1, -1, 0]) / np.sqrt(2), np.array([1, 1, -2]) / np.sqrt(6)
    n = np.ones(3) / np.sqrt(3)
    t = np.radians(np.arange(0, 360, 60))
    sign = np.where(np.arange(6) % 2, 1.0, -1.0)[:, None]
    # singular values sqrt(3), sqrt(3) in the plane and eps sqrt(6) across it: the ratio is eps sqrt(2)
    for eps, plane in ((0.3e-3, True), (0.6e-3, True), (0.8e-3, False)):  # 4.2e-4, 8.5e-4, 1.13e-3
        poses = np.outer(np.cos(t), u) + np.outer(np.sin(t), v) + eps * sign * n
        assert ("lie in a plane" in diagnose_underdetermined(poses, "12")) is plane, eps
    faces = np.vstack([np.eye(3), -np.eye(3)])
    # z at 0.96 g rounds to 1.0 g at 0.1 g: channel z is still only near 0 and +-1 g
    near = np.vstack([faces, [[0.2, 0.2, 0.96]]])
    assert diagnose_underdetermined(near, "15").startswith("the cubic term of channel z cannot be told")
    # -z replaced by a direction 30 deg from it: |d_p + d_q| = 0.52 > 0.1, not a pair
    # pairs are judged by direction, whatever the reading's length (a face read at half a g is still -z)
    short = faces.copy()
    short[5] *= 0.5
    assert diagnose_underdetermined(short, "15").startswith("the 6 poses are 3 opposite pairs")
    tilted = faces.copy()
    tilted[5] = [0.5, 0.0, -np.sqrt(0.75)]
    assert diagnose_underdetermined(tilted, "15").startswith("the cubic term of channel y cannot be told")

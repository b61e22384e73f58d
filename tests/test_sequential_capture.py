"""Sequential capture against the parameters' targets (models/allocation.py, station/sequential_capture.py)
and verification at the fit poses (station/verification.py); docs/capture.md.

The expected counts are derived by hand in each test's docstring (closed-form covariances of small
designs) or computed here independently (the OLS estimator through numpy's pseudo-inverse), never
copied from the program's output."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from accelcal_station.config.schema import VerifySection
from accelcal_station.config.sections import default_config_path
from accelcal_station.drivers.base import Capture
from accelcal_station.drivers.factory import make_driver
from accelcal_station.errors import ConfigError
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.simulated_jig import SimulatedJig
from accelcal_station.models.allocation import DesignRows, allocate, design_rows, target_variances
from accelcal_station.station.flow import make_flow
from accelcal_station.station.sequential_capture import ParameterTargets, SequentialPlan
from accelcal_station.station.settings import StationConfig
from accelcal_station.station.verification import verify_mode

SIGMA_G = 99e-6 * np.sqrt(50.0)  # the default MMA8451's per-sample noise: 99 ug/sqrt(Hz) over ODR/2 = 50 Hz


def _one_channel(x: list[float]) -> DesignRows:
    """A single model-6 channel with readings x (rows (x_i, 1)): gain at 0, offset at 1."""
    xs = np.asarray(x, dtype=float)
    A = np.stack([xs, np.ones_like(xs)], axis=1)[None]
    mix = np.zeros((1, len(xs), 3))
    mix[..., 0] = 1.0
    return DesignRows("6", A, mix, ((0, 1),), ((0, 0),))


def _pinv_gains(A: np.ndarray) -> np.ndarray:
    """g_ij = d theta_j / d y_i of the OLS estimator, (m, p), through numpy's pseudo-inverse."""
    return np.linalg.pinv(A).T


def test_neyman_allocation_on_a_hand_derived_channel() -> None:
    """Readings x = (1, 1, -1): A^T A = [[3, 1], [1, 3]], (A^T A)^-1 = [[3, -1], [-1, 3]] / 8, so the
    offset's weights g_i = (1/4, 1/4, 1/2).  With var(V) = q sum g_i^2 / n_i <= T the fewest samples are
    n_i = |g_i| sum|g| q / T = (q/4T, q/4T, q/2T) (Cauchy-Schwarz); equal counts would need 3q/8T each."""
    rows = _one_channel([1.0, 1.0, -1.0])
    q, T = 4e-6, 1e-8  # per-sample variance (g^2), target variance (g^2): q / T = 400
    tv = np.array([[np.inf, T]])
    a = allocate(rows, np.zeros((1, 3)), np.full((1, 3), q), np.ones(3, bool), tv, 1, 10**6)
    np.testing.assert_allclose(a.n, [100, 100, 200], atol=1)
    assert a.n.sum() < 3 * 150  # equal counts: 3 q / (8 T) = 150 each
    assert a.feasible and a.worst_ratio <= 1.0 + 1e-9
    np.testing.assert_allclose(a.u[0, 1], np.sqrt(T), rtol=0.01)


def test_six_face_model_12_closed_form() -> None:
    """Six faces, model 12: per channel rows (+-e_k, 1), A^T A = diag(2, 2, 2, 6), so var(V_k) = q / (6 n)
    and var(W_kk) = q / (2 n) with n on each face (only the +-k faces carry W_kk).  Offsets alone:
    n = q / (6 T_V); the gain target binding: n = q / (2 T_W) on every face."""
    refs = np.array([p.reference_g for p in get_design("six-face")])
    rows = design_rows("12", refs)
    q = SIGMA_G**2
    off_u = 0.02e-3
    a = allocate(rows, np.zeros((3, 6)), np.full((3, 6), q), np.ones(6, bool),
                 target_variances(rows, off_u, None), 1, 10**6)
    n_off = q / (6 * off_u**2)  # 204.2
    np.testing.assert_allclose(a.n, np.ceil(n_off), atol=1)
    gain_u = 1e-5
    a = allocate(rows, np.zeros((3, 6)), np.full((3, 6), q), np.ones(6, bool),
                 target_variances(rows, off_u, gain_u), 1, 10**6)
    n_gain = q / (2 * gain_u**2)  # 2450: the gain binds
    np.testing.assert_allclose(a.n, np.ceil(n_gain), atol=1)
    np.testing.assert_allclose(a.u[:, 0:3].max(), gain_u, rtol=1e-3)  # W_xx, W_yy, W_zz at the target
    np.testing.assert_allclose(a.u[:, 3], np.sqrt(q / (6 * np.ceil(n_gain))), rtol=1e-3)  # offsets below theirs


def test_the_default_design_needs_equal_counts_near_the_cube_closed_form() -> None:
    """an4399-8 (cube vertices to the printed whole degrees), model 12: A^T A ~ diag(8/3, 8/3, 8/3, 8), so
    var(V) = q / (8 n): n = q / (8 T) = 0.700^2 / (8 x 0.018^2) = 189 samples a pose, all alike."""
    refs = np.array([p.reference_g for p in get_design("an4399-8")])
    rows = design_rows("12", refs)
    a = allocate(rows, np.zeros((3, 8)), np.full((3, 8), SIGMA_G**2), np.ones(8, bool),
                 target_variances(rows, 0.018e-3, 1e-4), 1, 10**6)
    np.testing.assert_allclose(a.n, SIGMA_G**2 / (8 * 0.018e-3**2), rtol=0.03)
    assert a.n.max() - a.n.min() <= 0.03 * a.n.mean()


def test_high_leverage_poses_get_more_samples() -> None:
    """nine-position (six faces and three 45 deg tilts), model 12, the x offset alone: the Neyman counts
    are proportional to |g_i| of the OLS estimator (computed here by pinv), so the poses that move V_x
    more get more, and the total is below equal counts' (max of sum_i w_i / S over n)."""
    refs = np.array([p.reference_g for p in get_design("nine-position")])
    rows = design_rows("12", refs)
    q, T = SIGMA_G**2, 0.02e-3**2
    tv = np.full((3, 4), np.inf)
    tv[0, 3] = T
    a = allocate(rows, np.zeros((3, 9)), np.full((3, 9), q), np.ones(9, bool), tv, 1, 10**7)
    g = np.abs(_pinv_gains(rows.A[0])[:, 3])
    np.testing.assert_allclose(a.n / a.n.sum(), g / g.sum(), atol=2 / a.n.sum())
    assert np.ptp(g) > 0.05 * g.max()  # the design is unbalanced for V_x: the counts differ
    equal = q * np.sum(g**2) / T  # every pose's count with equal counts
    assert a.n.sum() < 9 * equal


def _white_pose(rng: np.random.Generator, n: int, sigma_counts: float) -> np.ndarray:
    return np.round(rng.normal(0.0, sigma_counts, (n, 3)) + 4096.0)


def _run_plan(plan: SequentialPlan, rng: np.random.Generator, sigma_counts: float, block: int = 10
              ) -> list[Capture]:
    """Each pose as gated_capture takes it: ask at min_samples, again each time the count is reached."""
    caps = []
    for i in range(plan.rows.poses):
        want = plan.min_samples
        s = _white_pose(rng, want, sigma_counts)
        while True:
            want = max(plan.min_samples, plan.needed(i, s))
            if len(s) >= want:
                break
            while len(s) < want:
                s = np.vstack([s, _white_pose(rng, block, sigma_counts)])
        cap = Capture.from_samples(s, np.arange(len(s)) / 100.0)
        plan.record(i, cap)
        caps.append(cap)
    return caps


def test_the_plan_stops_when_the_measured_noise_meets_the_targets() -> None:
    """White noise of 2.9 counts (the default chip): after the last pose the offsets' standard uncertainty
    from the poses' own measured standard errors (the sandwich, through pinv) is at the target, not far
    below it (no waste) nor above it beyond the last pose's re-estimate (3 %)."""
    refs = np.array([p.reference_g for p in get_design("an4399-8")])
    plan = SequentialPlan.for_design("12", refs, ParameterTargets(0.018, 1e-4), 4096.0, 32, 2000)
    caps = _run_plan(plan, np.random.default_rng(51), SIGMA_G * 4096.0)
    sem_g = np.array([c.sem_counts for c in caps]) / 4096.0
    g = _pinv_gains(np.concatenate([refs, np.ones((8, 1))], axis=1))[:, 3]
    u_offset_mg = np.sqrt((sem_g**2).T @ g**2) * 1e3  # per axis
    assert np.all(u_offset_mg <= 0.018 * 1.03), u_offset_mg
    assert np.max(u_offset_mg) >= 0.018 * 0.9, u_offset_mg
    assert all(c.n >= 32 for c in caps)


def test_poses_captured_beyond_their_need_leave_the_rest_little() -> None:
    """Seven poses of 2,000 samples each: var(V) = q / 64 (7 / 2000 + 1 / n) <= T needs n >= 26 at the last
    pose (q = 0.70^2 mg^2, T = 0.018^2 mg^2), not the equal share's 189; the ask that would end it uses the
    pose's own tau_int from its 32 samples (what the fit will report), which a short capture reads high."""
    refs = np.array([p.reference_g for p in get_design("an4399-8")])
    plan = SequentialPlan.for_design("12", refs, ParameterTargets(0.018, None), 4096.0, 32, 2000)
    rng = np.random.default_rng(7)
    for i in range(7):
        s = _white_pose(rng, 2000, SIGMA_G * 4096.0)
        plan.record(i, Capture.from_samples(s, np.arange(len(s)) / 100.0))
    n = plan.needed(7, _white_pose(rng, 32, SIGMA_G * 4096.0))
    assert 26 <= n < 189 / 2
    assert plan.last is not None and plan.last.worst_ratio <= 1.0


def _config(tmp_path: Path, **sections: dict[str, object]) -> StationConfig:
    c = yaml.safe_load(default_config_path().read_text())
    c["store"] = {"path": str(tmp_path / "runs.sqlite")}
    for k, v in sections.items():
        c.setdefault(k, {}).update(v)
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(c))
    return StationConfig.load(p)


def test_one_board_repeated_scatter_matches_the_reported_offset_stderr(tmp_path: Path) -> None:
    """The default board (configs/sim.yaml: its offsets, gains and cross-axis fixed in the file) calibrated
    12 times with fresh noise (device seeds 1-12) under sequential capture.  Pooled over the three axes,
    33 x ratio^2 is about chi^2 with 33 dof, so P(ratio < 0.6) + P(ratio > 1.6) (computed below) is the
    check's false-failure rate, < 1e-3.  Every board reports offset standard error <= 0.02 mg."""
    cfg = _config(tmp_path, nvm={"write": False})
    V, S = [], []
    for seed in range(1, 13):
        driver = make_driver(cfg.device.model_copy(update={"seed": seed}))
        (rep,) = make_flow(cfg, echo=lambda s: None, driver=driver).run()
        assert rep.verdict == "PASS" and rep.fit is not None and rep.fit.stderr is not None, rep.reasons
        assert rep.measured["stderr_offset_max_mg"] <= 0.02
        assert rep.verify_error_max_mg is not None and rep.verify_error_max_mg <= 0.25
        V.append(rep.fit.V)
        S.append(rep.fit.stderr["V"])
    sd, se = np.std(V, axis=0, ddof=1), np.sqrt(np.mean(np.square(S), axis=0))
    ratio = float(np.sqrt(np.mean(sd**2 / se**2)))
    assert chi2.cdf(33 * 0.6**2, 33) + chi2.sf(33 * 1.6**2, 33) < 1e-3
    assert 0.6 <= ratio <= 1.6, (sd, se)


@pytest.mark.parametrize("mode, moves", [("fit-poses", 8), ("independent", 9)])
def test_verification_at_the_last_fit_pose_needs_no_move(tmp_path: Path, mode: str, moves: int) -> None:
    """fit-poses: the one verification capture is taken where the last fit pose left the board (8 jig
    moves for 8 poses, in the jig's shortest-path order); independent: the design's first pose presented
    again (9).  Both verify on fresh
    samples (averaged beyond the fit's) and the NVM round trip."""
    cfg = _config(tmp_path, verify={"mode": mode, "poses": 1})
    driver = make_driver(cfg.device.model_copy(update={"seed": 3}))
    jig = SimulatedJig(driver.board, 2.0, record_motion=True)
    lines: list[str] = []
    (rep,) = make_flow(cfg, echo=lines.append, driver=driver, jig=jig).run()
    assert rep.verdict == "PASS", rep.reasons
    assert rep.verify_mode == mode
    assert len(jig.motion) == moves
    verified = [s for s in lines if s.startswith("verify ")]
    last = rep.poses[-1]["pose"]  # the last pose the jig presented (its shortest path: fixtures/pose_path.py)
    assert verified == ([f"verify {last} (where the jig stands)"] if mode == "fit-poses" else ["verify p1"])
    assert rep.timing["samples_averaged"] > sum(p["n"] for p in rep.poses)  # fresh samples, after the fit
    assert rep.nvm_verified


def test_three_fit_pose_verifications_walk_back_along_the_path(tmp_path: Path) -> None:
    cfg = _config(tmp_path, verify={"mode": "fit-poses", "poses": 3}, nvm={"write": False})
    lines: list[str] = []
    (rep,) = make_flow(cfg, echo=lines.append, driver=make_driver(cfg.device.model_copy(update={"seed": 4}))).run()
    # back along the path the jig took: the last three poses presented, newest first
    assert [s.split()[1] for s in lines if s.startswith("verify ")] == [p["pose"] for p in rep.poses][::-1][:3]
    assert rep.verdict == "PASS", rep.reasons


def test_verify_design_with_fit_poses_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="verify.mode"):
        _config(tmp_path, verify={"mode": "fit-poses", "design": "six-face"})
    assert verify_mode(_config(tmp_path, verify={"mode": "independent", "design": "six-face"}).schema.verify) \
        == "independent"
    assert verify_mode(VerifySection(design="six-face")) == "independent"  # verify.design alone: its own poses
    assert verify_mode(None) == "fit-poses"  # the default


def test_precedence_of_the_per_pose_target(tmp_path: Path) -> None:
    """target_sem_mg alone: the old per-pose rule (no parameter targets); with a target: both (a floor)."""
    default = _config(tmp_path).capture
    assert (default.target_offset_u_mg, default.target_gain_u, default.target_sem_mg) == (0.018, 1e-4, None)
    alone = _config(tmp_path, capture={"target_sem_mg": 0.1}).capture
    assert (alone.target_offset_u_mg, alone.target_gain_u, alone.target_sem_mg) == (None, None, 0.1)
    both = _config(tmp_path, capture={"target_sem_mg": 0.1, "target_offset_u_mg": 0.03}).capture
    assert (both.target_offset_u_mg, both.target_gain_u, both.target_sem_mg) == (0.03, 1e-4, 0.1)


def test_the_fit_reports_the_sandwich_with_unequal_pose_errors() -> None:
    """Poses of unequal standard error (as sequential capture gives them): the fitted offset's reported
    standard error is sqrt(sum_i v_i g_i^2) with g the OLS estimator's weights (pinv, computed here), not
    mean(v) (X^T X)^-1; with equal errors both agree.  A Monte Carlo of 4,000 noisy copies (fixed seed)
    scatters as reported within 5 % (the standard deviation's own relative spread is 1 / sqrt(2 x 3999) =
    1.1 %, so a false failure needs a 4.4-sigma draw: ~1e-5)."""
    from accelcal_station.models.linear import fit_linear_batch

    refs = np.array([p.reference_g for p in get_design("nine-position")])
    se = np.where(np.arange(9)[:, None] < 6, 0.05e-3, 0.2e-3) * np.ones((9, 3))  # faces 4x finer than tilts
    res = fit_linear_batch(refs[None], refs, "12", se[None])
    g = _pinv_gains(np.concatenate([refs, np.ones((9, 1))], axis=1))[:, 3]
    np.testing.assert_allclose(res.stderr_V[0], np.sqrt((se**2).T @ g**2), rtol=1e-9)
    rng = np.random.default_rng(2024)
    noisy = refs[None] + rng.normal(0.0, 1.0, (4000, 9, 3)) * se
    V = fit_linear_batch(noisy, refs, "12").V
    np.testing.assert_allclose(V.std(axis=0, ddof=1), res.stderr_V[0], rtol=0.05)
    equal = np.full((9, 3), 0.1e-3)
    same = fit_linear_batch(refs[None], refs, "12", equal[None])
    np.testing.assert_allclose(same.stderr_V[0], 0.1e-3 * np.sqrt(np.sum(g**2)), rtol=1e-9)


def test_no_plan_where_the_fit_holds_terms_or_the_design_cannot_fit() -> None:
    from accelcal_station.station.capture import CaptureSettings
    from accelcal_station.station.sequential_capture import plan_for

    faces = [p.reference_g for p in get_design("six-face")]
    assert plan_for("9", CaptureSettings(), faces, 4096.0, 100.0) is None  # 6 poses, 9 parameters
    plan = plan_for("15", CaptureSettings(), faces, 4096.0, 100.0)  # the cubic held: model 12's terms
    assert plan is not None and plan.rows.model == "12"
    assert plan_for("12", CaptureSettings(target_offset_u_mg=None, target_gain_u=None), faces, 4096.0, 100.0) is None

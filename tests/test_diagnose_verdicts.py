"""Verdicts that keep their word (diagnosis/verdict.py): "explained" only with the held-out gap within
EXPLAINED_GAP_MAX (1.5) of the floor, else "partly explained" with the gap left; a stochastic effect
(pose error) "accounts for the spread; a deterministic fix cannot lower it", never "explained" with an
unchanged residual; an effect confounded with acquisition order is in ``confounded``, not ``selected``
(tests/test_diagnose_order.py has the z-ordered relaxation).

Data from the project's forward simulator (configs/sim.yaml plus the effect named), fixed seeds.
"""
from __future__ import annotations

from pathlib import Path

import pytest
from diagnose_sphere import config as _config

from accelcal_station.api import diagnose
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.diagnosis.verdict import EXPLAINED_GAP_MAX
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board


def _raw_log(cfg: str, seed: int, path: Path) -> Path:
    run = run_poses(simulated_board(cfg, seed), get_design("optimal-12"), "drift", samples=400, raw=True, move_s=2.0)
    (t, c), _ = run.raw_table()
    path.write_text("t,x,y,z\n" + "\n".join(f"{a:.5f},{int(x)},{int(y)},{int(z)}"
                                            for a, (x, y, z) in zip(t, c, strict=True)) + "\n")
    return path


def _check_words(js: dict) -> None:
    """The invariant every diagnosis keeps."""
    if js["verdict"] == "explained":
        assert js["gap_after"] <= EXPLAINED_GAP_MAX, js
    # an effect confounded alone is never selected; a selected one may have terms in doubt (alone: false)
    assert not {e for e, c in js["confounded"].items() if c["alone"]} & set(js["selected"])


@pytest.fixture(scope="module")
def drift(tmp_path_factory):
    d = tmp_path_factory.mktemp("verdicts")
    cfg = _config(d, {"drift": {"random_walk_ug_per_rts": [50.0] * 3, "warmup_mg": [20.0] * 3,
                                "warmup_tau_s": 40.0}}, "drift.yaml")
    return [diagnose([_raw_log(cfg, s, d / f"drift{s}.csv")], raw=True).to_json() for s in (1, 2, 3)]


def test_drift_that_shrinks_the_gap_but_leaves_it_above_the_floor_is_partly_explained(drift):
    # a fix that lowers one view but not the headline gap is not selected (seed 1 here: the time view
    # 3.2 -> 1.1 x the floor, the static view 57 -> 61): it explains nothing overall
    named = [js for js in drift if "drift" in js["selected"]]
    assert len(named) >= 2
    for js in drift:
        _check_words(js)
        if js not in named:
            assert js["verdict"] in ("unexplained", "partly explained") and js["gap_after"] <= js["gap_before"]
    for js in named:
        assert js["gap_after"] < js["gap_before"]
        assert js["gap_after"] > EXPLAINED_GAP_MAX  # the case: 19.75 -> 17.76 is not explained
        assert js["verdict"] == "partly explained"
        assert f"above the {EXPLAINED_GAP_MAX:g} 'explained' needs" in js["verdict_text"]


def test_a_pose_error_accounts_for_the_spread_and_is_never_explained_with_the_residual_unchanged(tmp_path):
    cfg = _config(tmp_path, {"pose_error": {"scatter_deg": 0.3}}, "pose.yaml")
    for seed in (1, 2):
        run = run_poses(simulated_board(cfg, seed), get_design("optimal-24"), "pose", samples=200)
        write_pose_table(run.session, tmp_path / f"pose{seed}.csv")
        js = diagnose([tmp_path / f"pose{seed}.csv"]).to_json()
        _check_words(js)
        assert "pose_error" in js["selected"] and js["steps"] == []  # named by its signature, no fix
        assert js["rms_mg_after"] == js["rms_mg_before"]  # the 5.42 -> 5.42 mg
        assert js["verdict"] != "explained"
        assert js["verdict"] == "accounted for"
        assert "pose_error accounts for the spread; a deterministic fix cannot lower it" in js["verdict_text"]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_board_that_is_only_noisier_is_accounted_for_with_its_noise_ratio(tmp_path, seed):
    # the simulator's noise density tripled (99 -> 297 ug/sqrt(Hz)): the only difference from configs/sim.yaml
    cfg = _config(tmp_path, {"noise": {"density_ug_per_rthz": [297.0] * 3}}, "noisy.yaml")
    run = run_poses(simulated_board(cfg, seed), get_design("optimal-24"), "noisy", samples=200)
    write_pose_table(run.session, tmp_path / "noisy.csv")
    js = diagnose([tmp_path / "noisy.csv"]).to_json()
    _check_words(js)
    assert js["selected"] == ["noise"] and js["steps"] == []
    assert all(abs(r - 3.0) < 0.3 for r in js["stochastic"]["noise"]["ratio"])
    assert js["verdict"] == "accounted for"
    assert "noise accounts for the spread; a deterministic fix cannot lower it (within-pose sigma" in js["verdict_text"]

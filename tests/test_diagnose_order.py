"""The diagnosis sees acquisition order and temperature (diagnosis/order.py, shape.py, where.py).

Relaxation: the project's forward simulator (configs/sim.yaml plus a drift warm-up of -3 mg on z
with a time constant of 24 s = six poses of 4 s) runs optimal-24 sorted by descending z, then the
same boards with the same poses in shuffled order.  Temperature: pose means made here by forward
physics (gain, a full cross-axis matrix whose x-from-y coupling changes by 0.4 % per 45 C from 25 C,
offset, white noise of the simulator's per-sample sigma over n = 200); the diagnosis has no
temperature-dependent cross-axis term, so the leftover must be described, not fitted.
Fixed seeds: deterministic.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from accelcal_station.api import diagnose
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.diagnosis.report import summary_lines
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board
from accelcal_station.session import PoseRecord, Session

REPO = Path(__file__).resolve().parents[1]
POLY = {"quadratic", "cubic"}
SEEDS = (1, 2)  # boards 1 and 2 name the quadratic when ordered by z (measured; 3 of 8 boards in the issue)


@pytest.fixture(scope="module")
def relaxation(tmp_path_factory):
    d = tmp_path_factory.mktemp("order")
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["simulator"]["effects"]["drift"] = {"warmup_mg": [0.0, 0.0, -3.0], "warmup_tau_s": 24.0}
    (d / "board.yaml").write_text(yaml.safe_dump(cfg))
    by_z = sorted(get_design("optimal-24"), key=lambda p: -p.reference_g[2])
    shuffled = [by_z[i] for i in np.random.default_rng(0).permutation(len(by_z))]
    out: dict[str, list[Path]] = {"ordered": [], "shuffled": []}
    for kind, poses in (("ordered", by_z), ("shuffled", shuffled)):
        for seed in SEEDS:
            run = run_poses(simulated_board(str(d / "board.yaml"), seed), poses, kind, samples=200, move_s=2.0)
            out[kind].append(d / f"{kind}{seed}.csv")
            write_pose_table(run.session, out[kind][-1])
    return out


def test_z_ordered_relaxation_puts_the_polynomial_in_confounded_not_selected(relaxation):
    named = 0
    for f in relaxation["ordered"]:
        dg = diagnose([f])
        js = dg.to_json()
        assert js["verdict"] != "explained"
        assert not POLY & set(js["selected"])  # confounded with acquisition order: never selected
        for e in POLY & set(js["confounded"]):
            named += 1
            assert js["confounded"][e]["r2"] > 0.8 and js["confounded_with"] == js["confounded"]
            assert "confounded with acquisition order" in js["verdict_text"]
            assert any("confounded with acquisition order" in line for line in summary_lines(dg))
        assert "trends with acquisition order on z" in js["verdict_text"]
        blocks = js["where"]["by_order"]
        z = [b["mean_residual_mg"][2] for b in blocks]
        assert len(blocks) == 8 and max(z) - min(z) > 0.5  # the z residual moves along the run (measured ~1 mg)
    assert named >= 1  # the confound is met, not avoided: the selection took a polynomial, set aside


def test_the_same_boards_in_shuffled_order_name_nothing(relaxation):
    for f in relaxation["shuffled"]:
        js = diagnose([f]).to_json()
        assert js["selected"] == [] and js["confounded_with"] == {}  # tables carry no times: drift untestable


def _temperature_tables(d: Path, seed: int = 0) -> list[Path]:
    rng = np.random.default_rng(seed)
    cpg, sigma, n = 4096.0, 0.0007, 200
    off, gain = np.array([0.018, -0.027, 0.041]), np.array([1.012, 0.987, 1.021])
    files = []
    for t in (-20.0, 25.0, 70.0):
        c = np.array([[0, 0.006, -0.004], [0.008, 0, 0.005], [-0.007, 0.003, 0]])
        c[0, 1] += 0.004 * (t - 25.0) / 45.0
        k = np.diag(gain) @ (np.eye(3) + c)
        recs = [PoseRecord(p.name, np.round((k @ p.reference_g + off + rng.normal(0, sigma / np.sqrt(n), 3)) * cpg, 2),
                           np.full(3, sigma * cpg), n, p.reference_g, p.pitch_deg, p.roll_deg, t)
                for p in get_design("optimal-18")]
        files.append(d / f"t{t:g}.csv")
        write_pose_table(Session(recs, "counts", cpg, None, "mma8451"), files[-1])
    return files


def test_a_temperature_dependent_cross_axis_leftover_is_named_by_axis_and_temperature(tmp_path):
    js = diagnose(_temperature_tables(tmp_path)).to_json()
    assert js["verdict"] in ("unexplained", "partly explained")
    assert "temperature-dependent on x: grows with |T - 25 C|" in js["verdict_text"]
    assert "scattered" not in js["verdict_text"]

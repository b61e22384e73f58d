"""Panel calibration on simulated boards: many boards per jig pose, one panel_id, per-board verdicts."""
from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.schema import validate_device
from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.errors import ConfigError
from accelcal_station.fixtures.designs import get_design, references
from accelcal_station.sim.sensor_model import rotation_matrix
from accelcal_station.station.flow import make_flow
from accelcal_station.station.jig_pose import MIN_BOARDS, estimate_jig_poses
from accelcal_station.station.panel_config import panel_sections
from accelcal_station.station.settings import StationConfig

CONFIGS = __import__("pathlib").Path(__file__).resolve().parents[1] / "configs"


def panel_config(tmp_path, boards, **device) -> str:
    cfg = yaml.safe_load((CONFIGS / "panel-sim.yaml").read_text())
    cfg["device"]["boards"] = boards
    cfg["device"].update(device)
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def test_sixteen_board_panel_json_store_and_nvm(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, ["run", "--config", str(CONFIGS / "panel-sim.yaml"), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    boards = out["boards"]
    assert len(boards) == 16 and {b["verdict"] for b in boards} == {"PASS"}
    assert all(b["nvm"]["ok"] and b["nvm_verified"] for b in boards)
    assert len({b["serial"] for b in boards}) == 16
    # each board its own offsets (spread): the fitted V differ from board to board
    V = np.array([b["V"] for b in boards])
    assert np.min(np.std(V, axis=0)) > 5e-3
    db = sqlite3.connect(tmp_path / "accelcal-runs.sqlite")
    rows = db.execute("SELECT panel_id, count(*), sum(verdict = 'PASS'), sum(nvm_status = 'written'), "
                      "count(DISTINCT device_serial) FROM runs GROUP BY panel_id").fetchall()
    assert rows == [(out["panel_id"], 16, 16, 16, 16)]
    assert db.execute("SELECT count(*) FROM poses").fetchone()[0] == 16 * 8


def test_bad_boards_fail_with_their_own_reason_while_the_others_pass(tmp_path):
    boards = [{}, {"simulator": {"effects": {"offset": {"offset_mg": [170.0, 0.0, 0.0]}, "noise": {},
                                               "quantization": {}}}},
              {}, {"seated_deg": [180.0, 0.0, 0.0]}]  # seated upside down in its slot
    path = panel_config(tmp_path, boards)
    r = CliRunner().invoke(cli, ["run", "--config", path])
    assert r.exit_code == 1, r.output
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("board ")]
    assert len(lines) == 4
    assert "PASS" in lines[0] and "PASS" in lines[2]
    assert "FAIL" in lines[1] and "offset_max_mg" in lines[1]
    assert "FAIL" in lines[3] and "from the planned pose" in lines[3] and "pose p1" in lines[3]
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    verdicts = db.execute("SELECT verdict, count(DISTINCT panel_id) FROM runs GROUP BY verdict").fetchall()
    assert sorted(verdicts) == [("FAIL", 1), ("PASS", 1)]


def test_panel_of_one_is_the_single_board_flow(tmp_path):
    cfg = StationConfig.load(panel_config(tmp_path, 1))
    st = make_flow(cfg, echo=lambda s: None)
    (rep,) = st.run()
    assert rep.verdict == "PASS" and rep.nvm_verified
    assert not st.panel.estimate.estimated and "too small" in st.panel.estimate.note


@pytest.mark.parametrize("boards, key", [(0, "device.boards"), ("many", "device.boards"),
                                         ([3], "device.boards[0]"), (65, "device.boards")])
def test_panel_config_errors_name_the_key(boards, key):
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        panel_sections(validate_device({"driver": "simulated", "boards": boards}))


def test_spread_needs_boards():
    with pytest.raises(ConfigError, match="device.spread: only used with device.boards"):
        panel_sections(validate_device({"driver": "simulated", "spread": {"offset_mg": 1}}))


def test_panel_boards_are_typed_copies_with_their_own_keys_over_the_panels():
    """Each board's section is the validated device's model with its own given keys over the panel's:
    seed * 1000 + i and PANEL-0i unless the board says, a board's own ambient_c kept, the spread drawn
    into each board's own effects (10 mg: three boards never draw the same offsets), the panel's section
    itself left as it was."""
    device = validate_device({"driver": "simulated", "seed": 5, "serial": "P", "ambient_c": 20.0,
                              "simulator": {"effects": {"offset": {"offset_mg": [1.0, 2.0, 3.0]}, "noise": {}}},
                              "boards": [{}, {"serial": "X", "ambient_c": 30.0}, {"seed": 77}],
                              "spread": {"offset_mg": 10.0}})
    before = device.model_dump()
    secs = panel_sections(device)
    assert [p for _, p in secs] == ["device.boards[0]", "device.boards[1]", "device.boards[2]"]
    assert all(type(s) is type(device) and s.boards is None and s.spread is None for s, _ in secs)
    assert [(s.seed, s.serial, s.ambient_c) for s, _ in secs] == [(5000, "P-01", 20.0), (5001, "X", 30.0),
                                                                  (77, "P-03", 20.0)]
    offsets = [s.simulator.effects["offset"]["offset_mg"] for s, _ in secs]
    assert len({tuple(o) for o in offsets}) == 3 and all(o != [1.0, 2.0, 3.0] for o in offsets)
    assert all("noise" in s.simulator.effects for s, _ in secs)  # the other effects kept
    assert device.model_dump() == before
    # built into boards as they are: the board's serial and ambient temperature
    board = SimulatedBoard.from_section(secs[1][0])
    assert (board.serial, board.ambient_c) == ("X", 30.0)


def _scattered_panel(n: int, scatter_deg: float, seed: int = 3):
    """n in-class model-12 boards read at an4399-8 poses, all through the same per-pose jig error."""
    rng = np.random.default_rng(seed)
    design = get_design("an4399-8")
    ref = references(design)
    R = rotation_matrix(rng.normal(0.0, scatter_deg, (len(design), 3)))
    true = (R @ ref[..., None])[..., 0]
    gf = []
    for i in range(n):
        eff = {"offset": {"offset_mg": rng.normal(0, 20, 3).tolist()},
               "gain": {"gain": (1 + rng.normal(0, 0.01, 3)).tolist()},
               "cross_axis": {"coupling": (rng.normal(0, 0.005, (3, 3)) * (1 - np.eye(3))).tolist()},
               "noise": {}, "quantization": {}}
        b = SimulatedBoard.from_config({"chip": "mma8451", "effects": eff}, seed=seed * 100 + i)
        rows = []
        for d in true:
            b.set_gravity_direction(d)
            rows.append(b.read(2000)[0].mean(axis=0) / b.counts_per_g)
        gf.append(rows)
    return np.array(gf), ref, R


def test_joint_estimation_removes_the_jigs_scatter_from_the_residuals():
    # fixed seed; 0.2 deg scatter is 3.5 mg per pose, the noise of a 2000-sample mean 0.016 mg
    gf, ref, _ = _scattered_panel(8, 0.2)
    from accelcal_station.models.linear import fit_linear_batch

    before = fit_linear_batch(gf, ref, "12").residual_rms_g
    est = estimate_jig_poses(gf, ref, "12")
    after = fit_linear_batch(gf, est.references_g, "12").residual_rms_g
    assert est.estimated and 0.05 < est.rms_deg < 0.4
    assert np.all(before > 5e-4) and np.all(after < 1e-4)


def test_joint_estimation_says_when_the_panel_is_too_small():
    gf, ref, _ = _scattered_panel(MIN_BOARDS - 1, 0.2)
    est = estimate_jig_poses(gf, ref, "12")
    assert not est.estimated and "too small" in est.note and f"at least {MIN_BOARDS}" in est.note
    np.testing.assert_array_equal(est.references_g[0], ref)
    assert "no pose references" in estimate_jig_poses(gf, ref, "9").note


def test_a_misplaced_panel_is_named_as_the_panel(tmp_path):
    seated = {"seated_deg": [0.0, 180.0, 0.0]}
    cfg = StationConfig.load(panel_config(tmp_path, [dict(seated) for _ in range(3)]))
    lines: list[str] = []
    reps = make_flow(cfg, echo=lines.append).run()
    assert [r.verdict for r in reps] == ["FAIL"] * 3
    assert any("the panel is not in the planned pose" in ln for ln in lines)
    assert all(len(r.reasons) == 1 and r.reasons[0].startswith("pose p1:") for r in reps)


def test_a_board_that_is_not_still_is_named_and_the_others_pass(tmp_path):
    from accelcal_station.drivers.factory import make_driver
    from accelcal_station.station.panel_config import panel_sections

    cfg = StationConfig.load(panel_config(tmp_path, 3))
    drivers = [make_driver(sec, path) for sec, path in panel_sections(cfg.device)]
    for k in range(100):  # shaken through the first pose: 3 deg jolts every 0.5 s for 50 s
        drivers[1].board.disturb(after_s=1.0 + 0.5 * k, duration_s=0.4, amplitude_deg=3.0)
    lines: list[str] = []
    reps = make_flow(cfg, echo=lines.append, drivers=drivers).run()
    assert [r.verdict for r in reps] == ["PASS", "FAIL", "PASS"]
    assert reps[1].reasons[0].startswith("device: p1:") and "not still" in reps[1].reasons[0]
    assert any(ln.strip().startswith("board 2 (PNL-02)") for ln in lines)

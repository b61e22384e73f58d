"""The thermal plan over a panel (thermal_panel.py): a small simulated MPU6050 panel in the
emulated chamber, every board its own table, verdict, burn and store run sharing a panel_id;
a bad board fails alone; a chamber fault ends every board's run, recorded, nothing burned.
(The 16-board panel runs in benchmarks/bench_thermal_time.py.)"""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _config(tmp_path, boards=3, name="tp.yaml", faults=None):
    cfg = yaml.safe_load((CONFIGS / "thermal-panel-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["boards"] = boards
    if faults:
        cfg["chamber"]["emulator"]["faults"] = faults
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def _run(path):
    r = CliRunner().invoke(cli, ["run", "--config", str(path), "--json"])
    return r, json.loads(r.stdout)


def _stored(tmp_path):
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    return db.execute("SELECT panel_id, device_serial, verdict, reasons, nvm_status FROM runs ORDER BY id").fetchall()


def test_three_board_panel_each_burns_its_own_table_verified_at_45c(tmp_path):
    r, out = _run(_config(tmp_path))
    assert r.exit_code == 0, r.output
    boards = out["boards"]
    assert len(boards) == 3 and {b["verdict"] for b in boards} == {"PASS"}
    for b in boards:
        th = b["thermal"]
        assert b["nvm_verified"] and b["nvm"]["ok"] and th["panel"]["panel_id"] == out["panel_id"]
        assert len(th["table"]["temps_c"]) == 3 and th["temp_source"] == "die"
        (v,) = th["verify"]
        assert v["set_point_c"] == 45 and v["within_limit"] and not v["without_table_within_limit"]
        # every pose of the design at every set point (3 calibration x 8, 4 at 45 C) on every board
        assert len(b["poses"]) == 3 * 8 + 4
        assert {p["set_point_c"] for p in b["poses"]} == {-20, 25, 45, 70}
    # each board its own offsets (spread 20 mg): the fitted offsets differ from board to board
    V = np.array([b["V"] for b in boards])
    assert np.min(np.std(V, axis=0)) > 5e-3
    rows = _stored(tmp_path)
    assert {r[0] for r in rows} == {out["panel_id"]} and len({r[1] for r in rows}) == 3
    assert [(r[2], r[4]) for r in rows] == [("PASS", "written")] * 3
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    assert db.execute("SELECT count(*) FROM poses").fetchone()[0] == 3 * 3 * 8  # the calibration poses


def test_panel_time_split_sums_and_the_per_board_figure_divides_the_shared_soak(tmp_path):
    _, one = _run(_config(tmp_path, boards=1, name="one.yaml"))
    (tmp_path / "runs.sqlite").unlink()
    _, three = _run(_config(tmp_path, boards=3))
    t1, t3 = one["timing"], three["timing"]
    for t in (t1, t3):
        assert t["soak_s"] + t["sampling_floor_s"] + t["rest_s"] == pytest.approx(t["panel_time_s"])
        assert t["soak_s"] > 0.8 * t["panel_time_s"]  # soak dominates
        for k in ("soak_s", "sampling_floor_s", "rest_s", "board_time_s"):
            assert t["per_board"][k] == pytest.approx(t[k] / t["boards"])
    # the three boards share one soak: the panel soaks as long as one board (same chamber, same rule) ...
    assert t3["soak_s"] == pytest.approx(t1["soak_s"], rel=0.05)
    # ... so per board it costs about a third
    assert t3["per_board"]["board_time_s"] < 0.4 * t1["per_board"]["board_time_s"]
    # each board reports the soak it sat through and its own sampling floor
    assert all(b["timing"]["soak_s"] == t3["soak_s"] for b in three["boards"])


def test_a_bad_board_fails_with_its_own_reason_and_the_others_burn(tmp_path):
    p = _config(tmp_path, boards=[{}, {"seated_deg": [180.0, 0.0, 0.0]}, {}])  # seated upside down
    r, out = _run(p)
    assert r.exit_code == 1
    verdicts = [b["verdict"] for b in out["boards"]]
    assert verdicts == ["PASS", "FAIL", "PASS"]
    assert "from the planned pose" in out["boards"][1]["reasons"][0] and out["boards"][1]["nvm"] is None
    assert all(out["boards"][i]["nvm_verified"] for i in (0, 2))
    rows = _stored(tmp_path)
    assert [(r[2], r[4]) for r in rows] == [("PASS", "written"), ("FAIL", "none"), ("PASS", "written")]


@pytest.mark.parametrize("faults, kind", [
    ({"min_air_c": -5}, "set point -20 C not reached"),
    ({"alarm_at_s": 1000, "alarm_code": 3}, "alarm 3 (refrigeration fault) during the soak at -20 C"),
])
def test_a_chamber_fault_ends_every_boards_run_and_burns_nothing(tmp_path, faults, kind):
    r, out = _run(_config(tmp_path, faults=faults))
    assert r.exit_code == 1, r.output
    for b in out["boards"]:
        assert b["verdict"] == "FAIL" and kind in b["reasons"][0] and b["nvm"] is None
    rows = _stored(tmp_path)
    assert len(rows) == 3 and all(r[2] == "FAIL" and kind in r[3] and r[4] == "none" for r in rows)


def test_door_opened_mid_capture_fails_every_board_and_burns_nothing(tmp_path):
    _, clean = _run(_config(tmp_path, name="clean.yaml"))
    visit = next(v for v in clean["boards"][0]["thermal"]["visits"] if v["set_point_c"] == 25)
    mid = (visit["t_soaked_s"] + visit["t_end_s"]) / 2  # the same seeds run the same timeline up to here
    (tmp_path / "runs.sqlite").unlink()
    r, out = _run(_config(tmp_path, faults={"door_open_at_s": mid, "door_open_s": 20}))
    assert r.exit_code == 1
    for b in out["boards"]:
        assert "door opened during the capture" in b["reasons"][0] and "at 25 C" in b["reasons"][0]
        assert b["nvm"] is None and not b["nvm_verified"]
    rows = _stored(tmp_path)
    assert all(r[2] == "FAIL" and "door opened" in r[3] and r[4] == "none" for r in rows)


def test_a_chamber_that_stops_answering_records_every_board_interrupted_with_its_poses(tmp_path):
    _, clean = _run(_config(tmp_path, name="clean.yaml"))
    second = next(v for v in clean["boards"][0]["thermal"]["visits"] if v["set_point_c"] == 25)
    (tmp_path / "runs.sqlite").unlink()
    p = _config(tmp_path, faults={"stall_at_s": (second["t_soaked_s"] + second["t_end_s"]) / 2})
    cfg = yaml.safe_load(p.read_text())
    cfg["chamber"].update(timeout_s=0.2, retries=0)
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 3
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    runs = db.execute("SELECT id, status, status_reason FROM runs").fetchall()
    assert len(runs) == 3 and all(s == "error" and "at set point 25 C" in why for _, s, why in runs)
    for run_id, _, _ in runs:
        names = [n for (n,) in db.execute("SELECT name FROM poses WHERE run_id = ?", (run_id,))]
        at25 = [n for n in names if n.endswith("@25C")]
        assert len(names) - len(at25) == 8 and 0 < len(at25) < 8  # all of -20 C, part of 25 C

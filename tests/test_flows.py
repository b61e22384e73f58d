"""The station's one flow: a run is boards x conditions.  One class (flow.StationFlow) serves a
single board, a panel, a thermal plan and a thermal panel; the panel part (panel.Panel) and the
conditions (room.RoomTemperature, thermal.ThermalConditions) are what it is given, and what a
single board does differently is its policy (policy.FlowPolicy), chosen from the config."""
from __future__ import annotations

import inspect
import json
import sqlite3
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

import accelcal_station.station as station_pkg
from accelcal_station.cli import cli
from accelcal_station.station.flow import StationFlow, make_flow
from accelcal_station.station.policy import FlowPolicy
from accelcal_station.station.room import RoomTemperature
from accelcal_station.station.settings import StationConfig
from accelcal_station.station.thermal import ThermalConditions

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CASES = [("sim.yaml", False, False), ("panel-sim.yaml", True, False),
         ("thermal-sim.yaml", False, True), ("thermal-panel-sim.yaml", True, True)]


@pytest.mark.parametrize(("config", "panel", "thermal"), CASES)
def test_the_config_names_its_case(config: str, panel: bool, thermal: bool) -> None:
    cfg = StationConfig.load(CONFIGS / config)
    assert (cfg.is_panel, cfg.is_thermal) == (panel, thermal)


@pytest.mark.parametrize(("config", "panel", "thermal"), CASES)
def test_one_flow_class_serves_the_four_cases(config: str, panel: bool, thermal: bool) -> None:
    """Every case is a StationFlow itself (no subclass), given its conditions and its policy."""
    flow = make_flow(StationConfig.load(CONFIGS / config), echo=lambda s: None)
    assert type(flow) is StationFlow
    assert type(flow.conditions) is (ThermalConditions if thermal else RoomTemperature)
    p = flow.policy
    assert p.single_board is (not panel) and (flow.panel_id is None) is (not panel)
    assert (p.device_fault_ends_run, p.wrong_pose_ends_run, p.live_reading, p.burn_steps_recorded) \
        == (not panel,) * 4
    assert p.says_default_limits is (not panel and not thermal) and p.closes_before_timing is panel


def test_no_other_flow_class_is_left_in_the_station_package() -> None:
    """The four flows of old are gone: no class of the station package has a run() but StationFlow."""
    import importlib
    import pkgutil

    runners = set()
    for m in pkgutil.iter_modules(station_pkg.__path__):
        mod = importlib.import_module(f"accelcal_station.station.{m.name}")
        for name, cls in inspect.getmembers(mod, inspect.isclass):
            if cls.__module__ == mod.__name__ and "run" in cls.__dict__:
                runners.add(name)
    assert runners == {"StationFlow"}
    for gone in ("Station", "PanelStation", "ThermalStation", "ThermalPanelStation"):
        assert all(not hasattr(importlib.import_module(f"accelcal_station.station.{m.name}"), gone)
                   for m in pkgutil.iter_modules(station_pkg.__path__)), gone


def _store_config(tmp_path: Path, name: str, **device: object) -> Path:
    doc = yaml.safe_load((CONFIGS / name).read_text())
    doc["store"] = {"path": str(tmp_path / "runs.sqlite")}
    doc["device"].update(device)
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    return p


def test_a_panel_of_one_is_a_panel_and_a_single_board_is_not(tmp_path: Path) -> None:
    """One board either way, but the policy differs as the config does: a panel of one carries its
    panel id and leaves no burn steps before its result; a single board's burn steps are recorded
    as they happen (nvm_burning before the first byte, then nvm_burned)."""
    single = make_flow(StationConfig.load(_store_config(tmp_path, "sim.yaml", seed=3)), echo=lambda s: None)
    one = make_flow(StationConfig.load(_store_config(tmp_path, "panel-sim.yaml", boards=1)), echo=lambda s: None)
    assert FlowPolicy.for_config(one.cfg).panel_id is not None and single.panel_id is None
    (a,), (b,) = single.run(), one.run()
    assert a.verdict == b.verdict == "PASS"
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    rows = db.execute("SELECT id, panel_id FROM runs ORDER BY id").fetchall()
    assert [r[1] for r in rows] == [None, one.panel_id]
    kinds = {rid: [k for (k,) in db.execute("SELECT kind FROM events WHERE run_id = ? ORDER BY id", (rid,))]
             for rid, _ in rows}
    assert kinds[a.run_id][:2] == ["nvm_burning", "nvm_burned"]
    assert not {"nvm_burning", "nvm_burned"} & set(kinds[b.run_id])


def test_a_thermal_plan_on_a_device_that_does_not_answer_leaves_an_error_record(tmp_path: Path) -> None:
    """The thermal plan opens its device as a single board does: one that does not answer is one
    line, exit 3, and a run recorded as an error naming the device (never no record at all)."""
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"] = {"driver": "mpu6050", "port": str(tmp_path / "no-such-tty"), "timeout_s": 0.1,
                     "retries": 0, "boot_wait_s": 0.0}
    p = tmp_path / "t.yaml"
    p.write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 3, r.output
    assert "no-such-tty" in json.loads(r.stdout)["error"]
    rows = sqlite3.connect(tmp_path / "runs.sqlite").execute("SELECT status, status_reason FROM runs").fetchall()
    assert len(rows) == 1 and rows[0][0] == "error" and rows[0][1].startswith("device: ")

"""The station's flows: a run is boards x conditions. Two run skeletons (one board, a panel)
serve the four cases, the thermal plan's flows supplying only their conditions."""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.station.board import Station
from accelcal_station.station.panel import PanelStation
from accelcal_station.station.settings import StationConfig
from accelcal_station.station.thermal import ThermalStation
from accelcal_station.station.thermal_panel import ThermalPanelStation

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_the_thermal_flows_run_the_room_temperature_skeletons() -> None:
    """ThermalStation and ThermalPanelStation have no run() of their own: they supply the
    conditions (``_calibrate``), their timing and what ends their flow."""
    assert ThermalStation.run is Station.run and "run" not in ThermalStation.__dict__
    assert ThermalPanelStation.run is PanelStation.run and "run" not in ThermalPanelStation.__dict__
    for cls in (ThermalStation, ThermalPanelStation):
        assert "_calibrate" in cls.__dict__ and "_timing" in cls.__dict__


@pytest.mark.parametrize(("config", "panel", "thermal"), [
    ("sim.yaml", False, False), ("panel-sim.yaml", True, False),
    ("thermal-sim.yaml", False, True), ("thermal-panel-sim.yaml", True, True),
])
def test_the_config_names_its_case(config: str, panel: bool, thermal: bool) -> None:
    cfg = StationConfig.load(CONFIGS / config)
    assert (cfg.is_panel, cfg.is_thermal) == (panel, thermal)


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

"""The thermal table's per-temperature uncertainty budget (issue 48's follow-up; station/thermal_budget.py,
docs/uncertainty.md): each calibration set point's fit gets the board's budget (Type A with the effective
sample count, Type B: jig angle, site gravity, temperature span, quantization) plus the temperature it is
filed at (``thermal.temperature_u_c``) through the table's slope, and the expanded U (k = 2) in run --json
and the store.

The checks use figures computed here, not by the budget: GUM eq. 10 (root sum of squares) and U = 2 u_c,
and at the coldest set point the one-sided slope (V(25 C) - V(-20 C)) / (T(25 C) - T(-20 C)) between the
two fits' own figures times the stated temperature uncertainty.
"""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.acceptance.budget import BudgetInputs, budget
from accelcal_station.cli import cli

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
U_T_C = 0.8


def test_the_assigned_temperature_term_is_the_slope_times_the_temperature_uncertainty():
    ref = np.vstack([np.eye(3), -np.eye(3)])
    slope = np.array([0.5, -0.2, 0.9] + [1e-4, 0, 0, 0, -2e-4, 0, 0, 0, 3e-4])
    b = budget(BudgetInputs("6", ref.copy(), ref, temp_u_c=U_T_C, temp_slope=slope))
    (c,) = [c for c in b.components if c.source == "assigned_temperature"]
    np.testing.assert_allclose(c.u, np.abs(slope) * U_T_C)
    assert c.type == "B" and c.value == U_T_C
    # without a thermal slope (a room-temperature board) there is no such line
    assert "assigned_temperature" not in [c.source for c in budget(BudgetInputs("6", ref.copy(), ref)).components]


@pytest.fixture(scope="module")
def thermal_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("thermal_budget")
    cfg = yaml.safe_load((CONFIGS / "thermal-sim.yaml").read_text())
    cfg["store"] = {"path": str(d / "runs.sqlite")}
    cfg["thermal"]["temperature_u_c"] = U_T_C
    (d / "t.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(d / "t.yaml"), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), d


def test_every_calibration_set_point_has_its_budget_and_expanded_u(thermal_run):
    out, _ = thermal_run
    cal = [v for v in out["thermal"]["visits"] if v["role"] == "calibrate"]
    assert len(cal) == 3 and all(v["role"] != "verify" or v["uncertainty"] is None for v in out["thermal"]["visits"])
    for v in cal:
        u = v["uncertainty"]
        assert u["k"] == 2.0
        comps = {c["source"]: c for c in u["budget"]}
        assert comps["noise"]["type"] == "A" and comps["assigned_temperature"]["value"] == U_T_C
        assert {"jig_angle", "site_gravity", "temperature", "quantization"} <= set(comps)
        rss = np.sqrt(sum(np.square(c["u"]["V_mg"]) for c in u["budget"]))  # GUM eq. 10
        np.testing.assert_allclose(u["combined"]["V_mg"], rss, rtol=1e-9)
        np.testing.assert_allclose(u["expanded"]["V_mg"], 2 * rss, rtol=1e-9)
        assert max(comps["noise"]["u"]["V_mg"]) > 0


def test_the_coldest_set_points_temperature_term_follows_the_tables_slope(thermal_run):
    out, _ = thermal_run
    cal = [v for v in out["thermal"]["visits"] if v["role"] == "calibrate"]
    temps = out["thermal"]["table"]["temps_c"]  # each fit's mean board temperature
    v0, v1 = np.array(cal[0]["fit"]["V_mg"]), np.array(cal[1]["fit"]["V_mg"])
    slope = (v1 - v0) / (temps[1] - temps[0])  # mg/K, one-sided at the end of the table
    (c,) = [c for c in cal[0]["uncertainty"]["budget"] if c["source"] == "assigned_temperature"]
    np.testing.assert_allclose(c["u"]["V_mg"], np.abs(slope) * U_T_C, rtol=1e-9)
    assert max(c["u"]["V_mg"]) > 0.1  # the simulated MPU6050's offset moves mg over the table's 45 K


def test_the_store_keeps_each_set_points_budget(thermal_run):
    out, d = thermal_run
    (summary,) = sqlite3.connect(d / "runs.sqlite").execute("SELECT fit_summary FROM runs").fetchone()
    stored = [v for v in json.loads(summary)["thermal"]["visits"] if v["role"] == "calibrate"]
    assert [v["uncertainty"]["expanded"] for v in stored] == \
           [v["uncertainty"]["expanded"] for v in out["thermal"]["visits"] if v["role"] == "calibrate"]

"""A board's time budget (issue 51, station/time_budget.py): parts sum to the total, the floor is not above
it, `accelcal run --json` prints it and the store keeps it, a panel's bus time grows with its boards."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.station.time_budget import COMPONENTS, bus_limit_boards, bus_time_s
from accelcal_station.store.runs import Store

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_json(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("budget")
    store, config = tmp / "runs.sqlite", tmp / "sim.yaml"
    config.write_text((REPO / "configs" / "sim.yaml").read_text().replace("  # seed: 1 ", "  seed: 5 "))
    r = CliRunner().invoke(cli, ["run", "--config", str(config), "--store", str(store), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout), store


def test_run_json_has_the_budget_and_it_adds_up(run_json):
    js, _ = run_json
    b = js["time_budget"]
    assert set(COMPONENTS) <= set(b)
    assert b["total_s"] == pytest.approx(sum(b[k] for k in COMPONENTS), abs=1e-5)
    assert 0 < b["floor_s"] <= b["total_s"]
    assert b["ratio_to_floor"] == pytest.approx(b["total_s"] / b["floor_s"], rel=1e-3)
    # configs/sim.yaml's jig: 8 fit poses from home and 3 verification poses, each settle 0.2 s + angle / 100
    # deg/s: at most 11 x 2.0 s, and the verification begins where the fit ended (fewer than 11 moves)
    assert 8 * 0.2 < b["jig_moves_s"] < 10 * 2.0
    # the device's own clock: no board here takes under its sampling
    assert b["sampling_s"] >= b["floor_sampling_s"] * 8 / 11 * 0.7


def test_the_store_keeps_the_budget(run_json):
    js, store = run_json
    with Store(store) as s:
        row = s.get_run(js["run_id"])
    assert row.fit_summary is not None
    assert row.fit_summary["time_budget"] == js["time_budget"]


def test_panel_bus_time_grows_with_boards():
    # 11 bytes x 9 bit-times per board per sample at 400 kHz (written here from the I2C arithmetic)
    assert bus_time_s(100, 1) == pytest.approx(100 * 99 / 400_000)
    assert bus_time_s(100, 16) == pytest.approx(16 * bus_time_s(100, 1))
    assert bus_time_s(100, 8) < bus_time_s(100, 16) < bus_time_s(100, 32)
    assert bus_limit_boards(100.0) == 40  # 400000 / (100 Hz x 99 bits) = 40.4


def test_the_board_page_shows_the_budget(run_json):
    from fastapi.testclient import TestClient

    from accelcal_station.web.app import create_app
    from accelcal_station.web.settings import WebSettings

    js, store = run_json
    html = TestClient(create_app(WebSettings(store=str(store)))).get(f"/board?serial={js['serial']}").text
    b = js["time_budget"]
    assert f'data-part="jig_moves_s"><th>jig moves</th><td class="n">{b["jig_moves_s"]:.2f}</td>' in html
    assert f'data-part="total_s"><th>total</th><td class="n">{b["total_s"]:.2f}</td>' in html
    assert f'<td class="n">{b["floor_s"]:.2f}</td><td class="n">× {b["ratio_to_floor"]:.2f}</td>' in html

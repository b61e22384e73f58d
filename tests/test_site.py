"""The site's gravity (issue 48): WGS84 normal gravity against published figures, the station's
references scaled to the site so a board at 9.780 m/s^2 is calibrated in standard g, and `fit`
reading the site from --gravity or a file's '# gravity_mps2:' line."""
from __future__ import annotations

import csv
import json
import sqlite3

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.config.site import normal_gravity_mps2
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

STANDARD = 9.80665  # CGPM 1901


@pytest.mark.parametrize(("lat", "height", "published"), [
    # WGS84 normal gravity (NIMA TR8350.2 table 3.4 / eq. 4-1; geodesy texts' tables):
    (0.0, 0.0, 9.7803253359),   # gamma_e, at the equator
    (90.0, 0.0, 9.8321849378),  # gamma_p, at the poles
    (-90.0, 0.0, 9.8321849378),
    (45.0, 0.0, 9.806199),      # at 45 deg (the "9.8062" of gravity tables)
])
def test_normal_gravity_matches_published_figures(lat, height, published):
    assert normal_gravity_mps2(lat, height) == pytest.approx(published, abs=2e-6)


def test_free_air_gradient_lowers_gravity_3_086e_6_per_metre():
    # 1000 m up: 3.086 mGal/m x 1000 m = 3.086e-3 m/s^2 less (free-air gradient, Heiskanen & Moritz)
    assert normal_gravity_mps2(45.0, 0.0) - normal_gravity_mps2(45.0, 1000.0) == pytest.approx(3.086e-3, rel=1e-9)


def _config(tmp_path, site, local_mps2=None, name="station.yaml"):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["seed"] = 7
    if local_mps2 is not None:
        cfg["device"]["simulator"]["effects"]["gravity"] = {"local_mps2": local_mps2}
    if site is not None:
        cfg["station"]["site"] = site
    p = tmp_path / name
    p.write_text(yaml.safe_dump(cfg))
    return p


def _gain_error(tmp_path, site, name):
    st = make_flow(StationConfig.load(_config(tmp_path, site, 9.780, name)), echo=lambda s: None)
    (rep,) = st.run()
    truth = st.boards[0].driver.board.truth()  # the simulator's W in standard g
    return rep, float(np.max(np.abs(rep.fit.W - truth.W)))


def test_station_at_a_9_780_site_recovers_the_simulators_gains_in_standard_g(tmp_path):
    """Done when: effects.gravity.local_mps2 9.780 with station.site.gravity_mps2 9.780 recovers the
    gains within 5e-4 (the 8-pose design's gain standard error is ~3e-5); without the site the gains
    are off by 1 - 9.780/9.80665 = 2.7e-3."""
    rep, err = _gain_error(tmp_path, {"gravity_mps2": 9.780}, "a.yaml")
    assert err < 5e-4, err
    assert rep.site == {"gravity_mps2": 9.780, "source": "measured", "gravity_u_mps2": 1e-5}
    assert rep.calibration is not None and rep.calibration.metadata["site"]["gravity_mps2"] == 9.780
    _, err_standard = _gain_error(tmp_path, None, "b.yaml")
    assert err_standard > 2e-3  # the gap the site closes (1 - 9.780 / 9.80665 = 2.71e-3)


def test_site_by_latitude_reports_normal_gravity_in_run_json_and_the_store(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = _config(tmp_path, {"latitude_deg": 45, "height_m": 0})
    r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert round(out["site"]["gravity_mps2"], 4) == 9.8062 and out["site"]["source"] == "normal_gravity"
    (site,) = sqlite3.connect(tmp_path / "runs.sqlite").execute("SELECT site FROM runs").fetchone()
    assert json.loads(site)["gravity_mps2"] == pytest.approx(9.8062, abs=1e-4)


@pytest.mark.parametrize(("site", "words"), [
    ({"gravity_mps2": 9.78, "latitude_deg": 10, "height_m": 0}, "not both"),
    ({"latitude_deg": 10}, "both latitude_deg and height_m"),
    ({"gravity_mps2": 9.5}, "gravity_mps2"),
    ({"latitude_deg": 91, "height_m": 0}, "latitude_deg"),
])
def test_a_bad_site_is_one_line_exit_2(tmp_path, monkeypatch, site, words):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, site)), "--json"])
    assert r.exit_code == 2, r.output
    line = r.stdout.strip()
    assert "\n" not in line and words in line and "Traceback" not in r.output


def _pose_table(path, header):
    """Six faces and eight cube corners read by a board with known W, V at a 9.780 m/s^2 site:
    counts = 4096 W^-1 (r 9.780/g0 - V), r the unit reference."""
    rng = np.random.default_rng(5)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) / np.sqrt(3)
    ref = np.vstack([np.eye(3), -np.eye(3), corners])
    W = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    V = np.array([0.02, -0.015, 0.03])
    counts = 4096 * np.linalg.solve(W, (ref * 9.780 / STANDARD - V).T).T
    rows = "\n".join(f"p{i},{x:.6f},{y:.6f},{z:.6f},{rx:.12f},{ry:.12f},{rz:.12f}"
                     for i, ((x, y, z), (rx, ry, rz)) in enumerate(zip(counts, ref, strict=True)))
    path.write_text(header + "pose,x,y,z,ref_x,ref_y,ref_z\n" + rows + "\n")
    return W, V


def test_fit_takes_the_site_from_gravity_or_the_files_gravity_mps2_line(tmp_path):
    plain = tmp_path / "plain.csv"
    W, V = _pose_table(plain, "# units: counts\n# counts_per_g: 4096\n")
    stated = tmp_path / "stated.csv"
    _pose_table(stated, "# units: counts\n# counts_per_g: 4096\n# gravity_mps2: 9.780\n")
    for i, args in enumerate(([str(plain), "--gravity", "9.780"], [str(stated)])):
        cal = tmp_path / f"cal{i}.json"
        r = CliRunner().invoke(cli, ["fit", *args, "--model", "12", "--json", "-o", str(cal)])
        assert r.exit_code == 0, r.output
        js = json.loads(r.stdout)
        np.testing.assert_allclose(js["W"], W, atol=1e-6)
        np.testing.assert_allclose(js["V"], V, atol=1e-6)
        assert js["site"]["gravity_mps2"] == 9.780
        assert json.loads(cal.read_text())["metadata"]["site"]["gravity_mps2"] == 9.780  # the file says which g
    r = CliRunner().invoke(cli, ["fit", str(plain), "--model", "12", "--json"])  # standard gravity assumed
    assert abs(np.array(json.loads(r.stdout)["W"])[0, 0] / W[0, 0] - STANDARD / 9.780) < 1e-6


def test_batch_lot_file_takes_the_site_from_its_gravity_mps2_line(tmp_path):
    """A lot file (one row per pose, a serial column) in counts with '# gravity_mps2: 9.780': each
    board's references are scaled to the site, so batch recovers the W and V it was made with."""
    src = tmp_path / "one.csv"
    W, V = _pose_table(src, "")
    rows = [line for line in src.read_text().splitlines()[1:] if line]
    lot = tmp_path / "lot.csv"
    lot.write_text("# units: counts\n# counts_per_g: 4096\n# gravity_mps2: 9.780\nserial,pose,x,y,z,ref_x,ref_y,ref_z\n"
                   + "".join(f"B{b},{r}\n" for b in range(2) for r in rows))
    out = tmp_path / "results.csv"
    r = CliRunner().invoke(cli, ["batch", str(lot), "--out", str(out), "--model", "12"])
    assert r.exit_code == 0, r.output
    got = list(csv.DictReader(line for line in out.read_text().splitlines() if not line.startswith("#")))
    assert len(got) == 2
    for row in got:
        np.testing.assert_allclose([float(row[f"W{i}{j}"]) for i in range(3) for j in range(3)], W.ravel(), atol=1e-6)
        np.testing.assert_allclose([float(row[f"V{i}"]) for i in range(3)], V, atol=1e-6)

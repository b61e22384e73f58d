"""Model 9 and the hand-placed norm fit at the site's gravity (issue 48's follow-up): the norm they
fit to is |a| = g_local / g_standard in standard g, so a board calibrated at 9.780 m/s^2 with the site
stated gets its gains in standard g, as the jig-referenced models do (tests/test_site.py).

The truths come from the simulator (forward physics: the gravity effect sets |f| = local / standard):
model 9 estimates the symmetric factor of W's polar decomposition, sqrt(W^T W), computed here from
the simulator's W; the hand-placed fit a diagonal W, on a board without cross-axis coupling.  The
gap without the site is 1 - 9.780 / 9.80665 = 2.71e-3 on every gain.
"""
from __future__ import annotations

import json

import numpy as np
import yaml
from click.testing import CliRunner
from scipy.linalg import sqrtm

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

LOCAL = 9.780
GAP = 1 - LOCAL / 9.80665  # 2.71e-3


def _station(tmp_path, site, name):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / f"{name}.sqlite")}
    cfg["device"]["seed"] = 11
    cfg["device"]["simulator"]["effects"]["gravity"] = {"local_mps2": LOCAL}
    cfg["plan"] = {"design": "nine-position", "model": 9}
    cfg["nvm"] = {"write": False}
    if site is not None:
        cfg["station"]["site"] = site
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def _model9_gain_error(tmp_path, site, name):
    st = make_flow(StationConfig.load(_station(tmp_path, site, name)), echo=lambda s: None)
    (rep,) = st.run()
    assert rep.fit is not None and rep.fit.calibration.model == "9", rep.reasons
    W = st.boards[0].driver.board.truth().W
    M_truth = np.real(sqrtm(W.T @ W))  # what the norm determines: W up to a rotation
    return float(np.max(np.abs(np.diag(rep.fit.W) - np.diag(M_truth))))


def test_model9_at_a_9_780_site_recovers_the_gains_in_standard_g(tmp_path):
    """Nine poses at 0.05 mg per pose: the gains' standard error is ~1e-4, so 5e-4 is 5 sd inside
    the limit while the unstated site's 2.7e-3 is far outside it."""
    err = _model9_gain_error(tmp_path, {"gravity_mps2": LOCAL}, "site")
    assert err < 5e-4, err
    err_standard = _model9_gain_error(tmp_path, None, "standard")
    assert abs(err_standard - GAP) < 5e-4, err_standard


def _simulate(tmp_path, poses: str, seed: int, scatter_deg: float = 0.0, cross_axis: bool = True):
    """A pose table of ``poses`` simulated at 9.780 m/s^2 (4000 samples a pose) and the truth's W."""
    cfg = yaml.safe_load(default_config_path().read_text())
    eff = cfg["device"]["simulator"]["effects"]
    if not cross_axis:
        eff.pop("cross_axis")
    eff["gravity"] = {"local_mps2": LOCAL}
    if scatter_deg:
        eff["pose_error"] = {"scatter_deg": scatter_deg}
    conf = tmp_path / f"{poses}.yaml"
    conf.write_text(yaml.safe_dump(cfg))
    table, truth = tmp_path / f"{poses}.csv", tmp_path / f"{poses}-truth.json"
    r = CliRunner().invoke(cli, ["simulate", "--config", str(conf), "--poses", poses, "--out", str(table),
                                 "--truth-out", str(truth), "--seed", str(seed), "--samples", "4000"])
    assert r.exit_code == 0, r.output
    return table, np.array(json.loads(truth.read_text())["W"])


def _simulate_faces(tmp_path):
    """Six faces placed by hand (2 deg rms scatter) on a board with gain and offset only, at 9.780."""
    return _simulate(tmp_path, "six-face", 4, scatter_deg=2.0, cross_axis=False)


def test_hand_placed_fit_at_a_9_780_site_recovers_the_gains_in_standard_g(tmp_path):
    """Six faces, 4000 samples each (0.011 mg a pose): the gains' standard error is ~2e-5."""
    table, W = _simulate_faces(tmp_path)
    errs = {}
    for label, extra in (("site", ["--gravity", str(LOCAL)]), ("standard", [])):
        r = CliRunner().invoke(cli, ["fit", str(table), "--hand-placed", "--json", *extra])
        assert r.exit_code == 0, r.output
        js = json.loads(r.stdout)
        errs[label] = float(np.max(np.abs(np.diag(np.array(js["W"])) - np.diag(W))))
        norm_gain = np.array(js["hand_placed"]["norm"]["gain"])
        assert np.max(np.abs(norm_gain - np.diag(js["W"]))) < 1e-12  # the calibration is the norm fit's
    assert errs["site"] < 5e-4, errs
    assert abs(errs["standard"] - GAP) < 5e-4, errs


def test_batch_model9_takes_the_site_gravity(tmp_path):
    """`accelcal batch --model 9 --gravity 9.780` on nine-position tables simulated at 9.780 m/s^2: the
    calibrations' gains in standard g (within 5e-4 of sqrt(W^T W)); without the site they are 2.7e-3 low,
    as every gain of a station that assumes standard gravity."""
    table, W = _simulate(tmp_path, "nine-position", 5)
    M_truth = np.real(sqrtm(W.T @ W))
    errs = {}
    for label, extra in (("site", ["--gravity", str(LOCAL)]), ("standard", [])):
        out = tmp_path / label
        r = CliRunner().invoke(cli, ["batch", str(table), "--model", "9", "--out-dir", str(out), *extra])
        assert r.exit_code == 0, r.output
        (cal,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
        errs[label] = float(np.max(np.abs(np.diag(np.array(cal["W"])) - np.diag(M_truth))))
    assert errs["site"] < 5e-4, errs
    assert abs(errs["standard"] - GAP) < 5e-4, errs


def test_batch_from_store_refits_model9_at_the_runs_site(tmp_path):
    """A model-9 run at a 9.780 m/s^2 site, refitted from the store with `batch --from-store --model 9`:
    the same poses, the same model and the stored run's site give the run's own gains (a refit at
    standard gravity would be 2.7e-3 off)."""
    st = make_flow(StationConfig.load(_station(tmp_path, {"gravity_mps2": LOCAL}, "run")), echo=lambda s: None)
    (rep,) = st.run()
    assert rep.fit is not None, rep.reasons
    out = tmp_path / "refit"
    r = CliRunner().invoke(cli, ["batch", "--from-store", str(tmp_path / "run.sqlite"), "--model", "9",
                                 "--out-dir", str(out)])
    assert r.exit_code == 0, r.output
    (cal,) = [json.loads(p.read_text()) for p in out.glob("*.json")]
    assert np.max(np.abs(np.diag(np.array(cal["W"])) - np.diag(rep.fit.W))) < 1e-6

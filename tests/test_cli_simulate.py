"""`accelcal simulate`: its output, fitted by `accelcal fit`, reproduces its own --truth-out."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.data.posetable import read_pose_table
from accelcal_station.drivers.simulated import SimulatedBoard

REPO = Path(__file__).resolve().parents[1]

BASE = {"offset": {"offset_mg": [18.0, -27.0, 41.0]}, "gain": {"gain": [1.012, 0.987, 1.021]},
        "noise": {}, "quantization": {}}
CROSS = {"coupling": [[0, 0.006, -0.004], [0.008, 0, 0.005], [-0.007, 0.003, 0]], "rotation_deg": [0.3, -0.5, 0.8]}
# model 9's W is symmetric: diag(gain) (I + C) symmetric, no package rotation
SYM = (np.array([[0, 0.006, -0.004], [0.006, 0, 0.005], [-0.004, 0.005, 0]]) / np.array(BASE["gain"]["gain"])[:, None])
CONFIGS = {
    "6": BASE,
    "12": {**BASE, "cross_axis": CROSS},
    "15": {**BASE, "cross_axis": CROSS, "cubic": {"cubic_per_g2": [0.004, -0.003, 0.005]}},
    "9": {**BASE, "cross_axis": {"coupling": SYM.tolist()}},
}


def run(*args: str):
    return CliRunner().invoke(cli, list(args))


def station_config(tmp_path: Path, effects: dict, **device) -> str:
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump({"device": {"driver": "simulated", **device, "simulator": {"effects": effects}}}))
    return str(p)


def z_scores(fit: dict, truth: dict, model: str) -> np.ndarray:
    """(fitted - truth) / fitted standard error, for every parameter of the model."""
    se = fit["stderr"]
    W = (np.array(fit["W"]) - truth["W"]) / np.where(np.array(se["W"]) > 0, se["W"], np.inf)
    parts = [W[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]] if model == "9" else
             np.diagonal(W) if model == "6" else W.ravel(),
             (np.array(fit["V"]) - truth["V"]) / se["V"]]
    if model == "15":
        parts.append((np.array(fit["Gamma"]) - truth["Gamma"]) / se["Gamma"])
    return np.concatenate(parts)


# One board per model, 6 + 9 + 12 + 15 = 42 z-scores: P(any |z| > 4) is 0.27 % for a correct
# simulator (the fit's own standard errors; a little larger than the predicted ones).
@pytest.mark.parametrize("model, design", [("6", "six-face"), ("9", "nine-position"), ("12", "an4399-8"),
                                           ("15", "an4399-8")])
def test_fit_of_simulated_table_reproduces_truth_out(tmp_path, model, design):
    cfg = station_config(tmp_path, CONFIGS[model])
    out, truth = tmp_path / "poses.csv", tmp_path / "truth.json"
    r = run("simulate", "--config", cfg, "--poses", design, "--out", str(out), "--seed", "42",
            "--truth-out", str(truth))
    assert r.exit_code == 0, r.output
    session = read_pose_table(out)
    assert session.counts_per_g == 4096.0 and session.units == "counts" and session.metadata["seed"] == "42"
    assert len(session) == {"six-face": 6, "nine-position": 9, "an4399-8": 8}[design]
    r = run("fit", str(out), "--model", model, "--json")
    assert r.exit_code == 0, r.output
    fit, t = json.loads(r.output), json.loads(truth.read_text())
    assert np.shape(t["W"]) == np.shape(fit["W"]) == (3, 3) and len(t["V"]) == len(t["Gamma"]) == 3
    z = z_scores(fit, t, model)
    assert len(z) == int(model)
    assert np.abs(z).max() < 4, z
    # and it is not the identity: the board really has errors the fit had to find
    assert np.abs(np.array(t["V"])).max() > 0.015


def test_raw_log_has_motion_and_fits_with_model_9(tmp_path):
    cfg = station_config(tmp_path, CONFIGS["9"])
    out, truth = tmp_path / "raw.csv", tmp_path / "truth.json"
    r = run("simulate", "--config", cfg, "--poses", "nine-position", "--out", str(out), "--raw", "--seed", "3",
            "--samples", "400", "--truth-out", str(truth))
    assert r.exit_code == 0, r.output
    lines = out.read_text().splitlines()
    header, *rows = [ln for ln in lines if not ln.startswith("#")]
    assert header == "t,x,y,z" and "# counts_per_g: 4096" in lines
    data = np.array([r.split(",") for r in rows], dtype=float)
    assert np.all(data[:, 1:] == np.round(data[:, 1:]))  # integer counts
    assert len(data) == 9 * (400 + 200)  # 400 static samples per pose, 2 s of motion at 100 Hz before each
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, atol=1e-6)
    r = run("fit", str(out), "--raw", "--model", "9", "--counts-per-g", "4096", "--json")
    assert r.exit_code == 0, r.output
    fit = json.loads(r.output)
    assert fit["pose_count"] == 9
    np.testing.assert_allclose(fit["V"], json.loads(truth.read_text())["V"], atol=5e-4)


def test_temperatures_give_a_table_and_a_truth_per_temperature(tmp_path):
    effects = {**BASE, "temperature": {"offset_mg_per_c": [0.1, 0.2, -0.3], "gain_ppm_per_c": [100, 0, -150]}}
    cfg = station_config(tmp_path, effects)
    out, truth = tmp_path / "poses.csv", tmp_path / "truth.json"
    r = run("simulate", "--config", cfg, "--poses", "six-face", "--out", str(out), "--seed", "1",
            "--temps", "0,25,50", "--truth-out", str(truth))
    assert r.exit_code == 0, r.output
    session = read_pose_table(out)
    assert len(session) == 18 and sorted(set(session.temps_c)) == [0.0, 25.0, 50.0]
    cal = Calibration.load(truth)
    assert cal.temperature is not None and cal.temperature.temps_c.tolist() == [0.0, 25.0, 50.0]
    r = run("fit", str(out), "--model", "6", "--json")
    assert r.exit_code == 0, r.output
    for per_t in json.loads(r.output)["temperatures"]:
        W, V, _ = cal.coefficients(per_t["temp_c"])
        z = z_scores(per_t, {"W": W, "V": V, "Gamma": np.zeros(3)}, "6")
        assert np.abs(z).max() < 4, (per_t["temp_c"], z)  # 3 x 6 z-scores: false failure 0.1 %
    # the offset really moved with temperature: 0.3 mg/C on z over 50 C
    assert abs((cal.coefficients(50.0)[1] - cal.coefficients(0.0)[1])[2]) == pytest.approx(0.015, rel=0.05)


def test_same_seed_same_output_and_json_summary(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    for out in (a, b):
        r = run("simulate", "--poses", "an4399-6", "--out", str(out), "--seed", "9", "--json")
        assert r.exit_code == 0, r.output
    assert a.read_text() == b.read_text()
    summary = json.loads(r.output)
    assert summary["seed"] == 9 and summary["poses"] == 6 and summary["counts_per_g"] == 4096.0
    assert summary["effects"] == ["noise", "quantization", "saturation"]


def test_default_station_config_is_the_as_designed_board(tmp_path):
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    dev = dict(cfg["device"])
    assert dev.pop("driver") == "simulated"
    board = SimulatedBoard.from_config(dev, seed=1)
    assert board.model.enabled == ("offset", "gain", "cross_axis", "noise", "quantization")
    assert (board.chip.name, board.range_g, board.odr_hz) == ("mma8451", 2, 100.0)
    off_mg = -np.linalg.solve(board.truth().W, board.truth().V) * 1e3
    assert 10 < np.abs(off_mg).max() < 100  # tens of mg
    out = tmp_path / "p.csv"
    r = run("simulate", "--config", str(REPO / "configs" / "sim.yaml"), "--poses", "an4399-8", "--out", str(out))
    assert r.exit_code == 0 and "seed" in r.output


@pytest.mark.parametrize("args, message", [
    (["--poses", "seven-face"], "unknown design 'seven-face'"),
    (["--poses", "six-face", "--temps", "0,hot"], "--temps '0,hot': 'hot'; allowed: comma-separated"),
    (["--poses", "six-face", "--temps", "25,25"], "a temperature repeats"),
])
def test_bad_arguments_one_line_error(tmp_path, args, message):
    out = tmp_path / "p.csv"
    r = run("simulate", *args, "--out", str(out))
    assert r.exit_code != 0 and message in r.output and "Traceback" not in r.output
    assert r.output.count("\n") == 1 and not out.exists()


def test_bad_config_names_the_key(tmp_path):
    out = tmp_path / "p.csv"
    cfg = station_config(tmp_path, {"offset": {"offset_mg": [1, 2]}})
    r = run("simulate", "--config", cfg, "--poses", "six-face", "--out", str(out))
    assert r.exit_code != 0 and not out.exists()
    assert f"error: {cfg}: device.simulator.effects.offset.offset_mg: [1, 2]; allowed" in r.output
    cfg = station_config(tmp_path, {}, chip="mpu6050", odr_hz=300)
    r = run("simulate", "--config", cfg, "--poses", "six-face", "--out", str(out))
    assert r.exit_code != 0 and f"{cfg}: device.odr_hz: 300" in r.output
    p = tmp_path / "hw.yaml"
    p.write_text("device: {driver: mma8451, bus: 1}\n")
    r = run("simulate", "--config", str(p), "--poses", "six-face", "--out", str(out))
    assert r.exit_code != 0 and "needs driver: simulated" in r.output


def test_unwritable_output_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "missing" / "p.csv"
    truth = tmp_path / "t.json"
    r = run("simulate", "--poses", "six-face", "--out", str(out), "--truth-out", str(truth))
    assert r.exit_code != 0 and "cannot write" in r.output and "Traceback" not in r.output
    assert not out.exists() and not truth.exists()
    # the truth's folder missing (the names keep their formats: a .json --out is refused by its suffix)
    table, lost = tmp_path / "p.csv", tmp_path / "missing" / "t.json"
    r = run("simulate", "--poses", "six-face", "--out", str(table), "--truth-out", str(lost))
    assert r.exit_code != 0 and "cannot write" in r.output and not table.exists()


@pytest.mark.parametrize(("args", "said"), [
    (["--lot", "3", "--out", "lot.parquet"], "--out lot.parquet: simulate writes a CSV table there, not a Parquet"),
    (["--out", "poses.json"], "--out poses.json: simulate writes a CSV table there, not a JSON file"),
    (["--out", "p.csv", "--truth-out", "truth.csv"], "--truth-out truth.csv: simulate writes a JSON file there"),
])
def test_a_suffix_of_another_format_is_refused(tmp_path, monkeypatch, args, said):
    """Issue 53: `simulate --lot --out x.parquet` wrote CSV text under a Parquet name."""
    monkeypatch.chdir(tmp_path)
    r = run("simulate", "--poses", "six-face", *args)
    assert r.exit_code == 2 and said in r.output and "allowed:" in r.output, r.output
    assert list(tmp_path.iterdir()) == []


def test_a_bad_lot_is_called_a_lot(tmp_path):
    """Issue 53: a bad --lot was 'not a serial number'; nothing is recorded."""
    store = tmp_path / "runs.sqlite"
    r = run("run", "--lot", "bad lot!", "--serial", "SN1", "--store", str(store))
    assert r.exit_code == 2 and "--lot: 'bad lot!' is not a lot name; allowed:" in r.output, r.output
    assert not store.exists()

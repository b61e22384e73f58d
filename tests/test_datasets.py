"""Real accelerometer data (tests/data, see its README) through `accelcal fit`."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.data.rawlog import read_raw_log
from accelcal_station.data.static_poses import detect_static

FACES = {  # expected output in g, axis-up convention of the data (x_p: x up reads +1 g)
    "x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0), "z_p": (0, 0, 1), "z_a": (0, 0, -1),
}
IMUCAL_RATE = "204.8"


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def imucal(data_dir):
    path = data_dir / "imucal_annotated_session.csv"
    with path.open() as f:
        rows = list(csv.DictReader(f))
    parts = np.array([r["part"] for r in rows])
    acc = np.array([[float(r[f"acc_{a}"]) for a in "xyz"] for r in rows])
    return path, parts, acc


@pytest.mark.parametrize("key", ["set_1_counts", "set_2_counts"])
def test_calibraxis_model_9_brings_every_norm_to_1g(tmp_path, calibraxis, key):
    table = tmp_path / f"{key}.csv"
    table.write_text("# units: counts\npose,pitch_deg,roll_deg,x,y,z\n" +
                     "".join(f"c{i + 1},,,{x!r},{y!r},{z!r}\n" for i, (x, y, z) in enumerate(calibraxis[key])))
    r = _run("fit", table, "--model", "9", "--json")  # no counts_per_g: model 9 estimates the scale
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["pose_count"] == 10 and js["success"]
    errs = [p["norm_error_g"] for p in js["poses"]]
    assert max(abs(e) for e in errs) < 0.01  # the source's own check
    # and the calibration really does that to the raw counts
    W, V = np.array(js["W"]), np.array(js["V"])
    cal = (np.array(calibraxis[key]) / js["input_per_g"]) @ W.T + V
    np.testing.assert_allclose(np.linalg.norm(cal, axis=1) - 1, errs, atol=1e-9)


def test_imucal_six_faces_model_12(tmp_path, imucal):
    path, parts, acc = imucal
    lines = ["# units: counts", "# counts_per_g: 2048", "# source: imucal_annotated_session.csv",
             "pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,n,std_x,std_y,std_z"]
    for face, ref in FACES.items():
        a = acc[parts == face]
        m, s = a.mean(axis=0), a.std(axis=0, ddof=1)
        m, s = m.tolist(), s.tolist()
        lines.append(f"{face},,,{m[0]!r},{m[1]!r},{m[2]!r},{ref[0]},{ref[1]},{ref[2]},{len(a)},"
                     f"{s[0]!r},{s[1]!r},{s[2]!r}")
    table = tmp_path / "imucal_faces.csv"
    table.write_text("\n".join(lines) + "\n")
    r = _run("fit", table, "--model", "12", "--json")
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["pose_count"] == 6 and js["success"]
    W = np.array(js["W"])
    # 2048 counts/g nominal: gains within 5 %, cross-axis terms a few percent at most
    assert np.all(np.abs(np.diag(W) - 1) < 0.05) and np.all(np.abs(W - np.diag(np.diag(W))) < 0.05)
    # six faces leave 2 degrees of freedom per channel: the residuals are small but not zero
    assert 0 < js["residual_rms_g"] < 0.005
    assert js["residual_rms_g"] < js["crossval_rms_g"] < 0.05  # 5 faces still determine model 12
    assert js["stderr"] is not None  # from the recorded std and n
    h = _run("fit", table, "--model", "12")
    assert h.exit_code == 0, h.stderr
    assert "model 12, 6 poses" in h.stdout and "residual RMS" in h.stdout
    for face in FACES:  # one residual row per face
        assert any(line.startswith(face + " ") for line in h.stdout.splitlines()), face


def test_imucal_raw_session_segments_into_the_six_faces(imucal):
    path, parts, acc = imucal
    log = read_raw_log(path, columns="-,-,x,y,z,-,-,-", rate_hz=float(IMUCAL_RATE))
    assert len(log) == len(parts) and np.array_equal(log.xyz, acc)  # header skipped, columns picked
    det = detect_static(log.xyz, log.rate_hz)
    # the noise floor it estimated is the faces' own sample std (6-8 counts)
    face_std = np.mean([acc[parts == f].std(axis=0) for f in FACES], axis=0)
    np.testing.assert_allclose(det.noise_sigma, face_std, rtol=0.15)
    labels = []
    for s in det.segments:
        used = np.concatenate([parts[a:b] for a, b in s.ranges])
        values, counts = np.unique(used, return_counts=True)
        labels.append(str(values[np.argmax(counts)]))
        # never two faces in one pose; the still start and end of the rotation about the
        # face's own (vertical) axis may join it: the gravity direction is the same
        assert set(used.tolist()) <= {labels[-1], labels[-1][0] + "_rot"}, set(used.tolist())
        face = acc[parts == labels[-1]].mean(axis=0)
        assert np.all(np.abs(s.mean - face) < 5), (labels[-1], s.mean, face)  # within 2.5 mg
    assert labels == ["x_a", "x_p", "y_a", "y_p", "z_a", "z_p"]
    # through the CLI: six poses are too few for model 9, and it says so on one line
    r = _run("fit", "--raw", path, "--columns", "-,-,x,y,z,-,-,-", "--rate", IMUCAL_RATE, "--model", "9")
    assert r.exit_code != 0 and r.stderr.count("\n") == 1
    assert "6 distinct orientations; the 9-parameter norm model needs at least 9 well spread" in r.stderr

"""`accelcal fit` on pose tables: AN4399 worked examples, outputs, temperature, bad input."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.calibration import Calibration
from accelcal_station.cli import cli
from accelcal_station.conventions import an4399_reference
from accelcal_station.data.posetable import read_pose_table, write_pose_table
from accelcal_station.session import PoseRecord, Session

TOL = 2e-5  # the vector file's tolerance for printed decimals
REPO = Path(__file__).resolve().parents[1]


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _table(tmp_path, an4399, name) -> Path:
    e = an4399[name]
    lines = [f"# counts_per_g: {an4399['counts_per_g']}", "pose,pitch_deg,roll_deg,x,y,z"]
    lines += [f"p{i + 1},{a[0]},{a[1]},{c[0]},{c[1]},{c[2]}"
              for i, (a, c) in enumerate(zip(e["poses_deg"], e["counts"], strict=True))]
    p = tmp_path / f"{name}.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


@pytest.mark.parametrize("name, model", [("example_3", "12"), ("example_4", "12"), ("example_5", "15")])
def test_an4399_examples_through_the_cli(tmp_path, an4399, name, model):
    r = _run("fit", _table(tmp_path, an4399, name), "--model", model, "--json")
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    exp = an4399[name]["expected"]
    assert js["model"] == model and js["pose_count"] == len(an4399[name]["counts"])
    if model == "15":
        rows = np.array([exp[a] for a in "xyz"])
        W, V, G = rows[:, :3], rows[:, 3], rows[:, 4]
    else:
        W, V, G = np.array(exp["W"]), np.array(exp["V"]), np.zeros(3)
    np.testing.assert_allclose(js["W"], W, atol=TOL)
    np.testing.assert_allclose(js["V"], V, atol=TOL)
    np.testing.assert_allclose(js["Gamma"], G, atol=TOL)
    if "P" in exp:
        np.testing.assert_allclose(js["P"], exp["P"], atol=TOL)
    if "P_times_1e6" in exp:
        # printed to 2 decimals; the note rounds some (186.666 -> 186.67) and truncates
        # others (196.628 -> 196.62), so allow one unit of the last printed decimal
        np.testing.assert_allclose(np.array(js["P"]) * 1e6, exp["P_times_1e6"], atol=0.01)
    assert len(js["poses"]) == js["pose_count"]
    assert {"pose", "reading_g", "residual_g"} <= set(js["poses"][0])
    assert np.isclose(js["residual_rms_g"], np.sqrt(np.mean(np.square([p["residual_g"] for p in js["poses"]]))))


def test_human_summary_and_calibration_output(tmp_path, an4399):
    table = _table(tmp_path, an4399, "example_4")
    out = tmp_path / "cal.json"
    r = _run("fit", table, "-o", out)
    assert r.exit_code == 0, r.stderr
    text = r.stdout
    assert "model 12, 6 poses, counts at 4096 counts/g (given)" in text
    assert "W     = [+1.019960 -0.026326 +0.004156]" in text
    assert "V     = [-0.027957 -0.019073 +0.004452] g" in text
    assert "residual RMS" in text and "leave-one-pose-out RMS" in text and "condition number" in text
    assert all(f"\np{i} " in text for i in range(1, 7))  # the per-pose residual table
    assert f"calibration written to {out}" in text
    cal = Calibration.load(out)
    assert cal.model == "12" and cal.input_units == "counts" and cal.input_per_g == 4096
    np.testing.assert_allclose(cal.W, an4399["example_4"]["expected"]["W"], atol=TOL)
    # applying the saved calibration to the pose readings gives reference minus residual
    js = json.loads(_run("fit", table, "--json").stdout)
    s = read_pose_table(table)
    got = cal.apply(s.readings, units="counts")
    np.testing.assert_allclose(got, s.references_g - np.array([p["residual_g"] for p in js["poses"]]), atol=1e-12)
    assert [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_model_6_and_model_9_on_a_table_without_angles(tmp_path):
    # the shipped example (a simulated board) also fits models 6 and 9
    r6 = json.loads(_run("fit", REPO / "examples" / "poses.csv", "--model", "6", "--json").stdout)
    W6 = np.array(r6["W"])
    assert np.count_nonzero(W6 - np.diag(np.diag(W6))) == 0 and r6["Gamma"] == [0, 0, 0]
    s = read_pose_table(REPO / "examples" / "poses.csv")
    for p in s.poses:  # strip the references: model 9 needs none
        p.reference_g, p.pitch_deg, p.roll_deg = None, None, None
    bare = tmp_path / "bare.csv"
    write_pose_table(s, bare)
    assert "ref_x" not in bare.read_text()
    r9 = _run("fit", bare, "--model", "9", "--json")
    assert r9.exit_code == 0, r9.stderr
    js = json.loads(r9.stdout)
    assert js["model"] == "9" and max(abs(p["norm_error_g"]) for p in js["poses"]) < 1e-3
    assert js["crossval_rms_g"] is not None


def test_shipped_example_is_what_the_script_writes(tmp_path):
    out = tmp_path / "poses.csv"
    subprocess.run([sys.executable, str(REPO / "examples" / "make_example.py"), str(out)], check=True)
    assert out.read_text() == (REPO / "examples" / "poses.csv").read_text()
    r = _run("fit", REPO / "examples" / "poses.csv", "--model", "15", "--json")
    js = json.loads(r.stdout)
    # the simulated board has a cubic term, which only model 15 captures (< 0.5 mg RMS)
    assert js["pose_count"] == 14 and js["residual_rms_g"] < 5e-4


def _temperature_session(seed=11):
    """A board whose gain and offset drift linearly with temperature, 8 poses at 3 temperatures."""
    rng = np.random.default_rng(seed)
    angles = [(0, 0), (0, 180), (-90, 0), (90, 0), (0, 90), (0, -90), (35, 45), (-35, -135)]
    poses = []
    for t in (-20.0, 25.0, 70.0):
        S = np.diag([1.02, 0.99, 1.01]) * (1 + 2e-4 * (t - 25))
        off = np.array([0.02, -0.01, 0.03]) + 1e-4 * (t - 25)
        for i, (p, r) in enumerate(angles):
            g = an4399_reference(p, r)
            raw = (S @ g + off + rng.normal(scale=2e-5, size=3)) * 4096
            poses.append(PoseRecord(f"a{i}", raw, None, None, g, float(p), float(r), t + rng.uniform(-0.5, 0.5)))
    return Session(poses, "counts", 4096.0)


@pytest.mark.parametrize("method", ["linear", "quadratic"])
def test_temperature_table_fits_each_temperature(tmp_path, method):
    table = tmp_path / "temp.csv"
    write_pose_table(_temperature_session(), table)
    out = tmp_path / "cal.json"
    r = _run("fit", table, "--temp-method", method, "--json", "-o", out)
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["pose_count"] == 24 and len(js["temperatures"]) == 3 and len(js["poses"]) == 24
    temps = [t["temp_c"] for t in js["temperatures"]]
    np.testing.assert_allclose(temps, [-20, 25, 70], atol=0.5)
    for t in js["temperatures"]:
        S = np.diag([1.02, 0.99, 1.01]) * (1 + 2e-4 * (t["temp_c"] - 25))
        # noise 0.02 mg per axis and +-0.5 C scatter of temp_c (2e-4/C): 3e-4 is > 3 sigma
        np.testing.assert_allclose(np.array(t["W"]), np.linalg.inv(S), atol=3e-4)
        assert t["pose_count"] == 8
    cal = Calibration.load(out)
    assert cal.temperature is not None and cal.temperature.method == method
    np.testing.assert_allclose(cal.temperature.temps_c, temps)
    h = _run("fit", table, "--temp-method", method)
    assert h.stdout.count("-- at ") == 3 and "24 poses at 3 temperatures" in h.stdout


def _bad(tmp_path, text, name="bad.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bad_input_is_one_line_and_non_zero(tmp_path, an4399):
    good = _table(tmp_path, an4399, "example_4")
    body = good.read_text().split("\n", 1)[1]  # without the counts_per_g line
    cases = [
        (["fit", tmp_path / "absent.csv"], "absent.csv: cannot read"),
        (["fit", _bad(tmp_path, "pose,pitch_deg,roll_deg,x,y\np,0,0,1,2\n", "m.csv")],
         "m.csv: line 1: missing column 'z'"),
        (["fit", _bad(tmp_path, "pose,pitch_deg,roll_deg,x,y,z\np,0,0,1,NaN,3\n", "n.csv")],
         "n.csv: line 2, column y: 'NaN'; allowed: a finite number"),
        (["fit", good, "--units", "furlongs"], "--units: unknown units 'furlongs'; allowed: counts, g, mps2"),
        (["fit", _bad(tmp_path, "# units: parsecs\n" + body, "u.csv")],
         "u.csv: line 1: unknown units 'parsecs'; allowed: counts, g, mps2"),
        (["fit", _bad(tmp_path, "\n".join(good.read_text().splitlines()[:5]) + "\n", "few.csv")],
         "few.csv: 3 distinct orientations; model 12 needs at least 4 poses"),
        (["fit", good, "--model", "9"],
         "6 distinct orientations; the 9-parameter norm model needs at least 9 well spread"),
        (["fit", good, "--model", "7"], "--model '7'; allowed: 6, 9, 12, 15"),
        (["fit", good, "--counts-per-g", "-4096"], "--counts-per-g '-4096'; allowed: a positive number"),
        (["fit", good, "--temp-method", "cubic"], "--temp-method 'cubic'; allowed: linear, quadratic"),
        (["fit", _bad(tmp_path, "pose,pitch_deg,roll_deg,x,y,z\np,,,1,2,3\n", "r.csv"), "--model", "12"],
         "r.csv: line 2, column pitch_deg: pose 'p' has no reference"),
        (["fit", good, "--units", "g"], "readings in g have a median norm of"),
        (["fit", good, "-o", tmp_path / "no" / "such" / "dir.json"], "dir.json: cannot write (No such file"),
        (["fit", _bad(tmp_path, "", "empty.csv")], "empty.csv: empty: no header line"),
        (["fit", _bad(tmp_path, "# counts_per_g: 4096\npose,pitch_deg,roll_deg,x,y,z,temp_c\n" +
                      "".join(f"p{i},0,{90 * i},0,0,4096,{'' if i == 2 else 25}\n" for i in range(4)), "t.csv")],
         "t.csv: pose 'p2' has no temp_c while others do"),
    ]
    for args, msg in cases:
        r = _run(*args)
        assert r.exit_code != 0, args
        assert r.stderr.startswith("error: ") and r.stderr.count("\n") == 1, (args, r.stderr)
        assert msg in r.stderr, (args, r.stderr)
        assert "Traceback" not in r.stdout + r.stderr and r.stdout == ""

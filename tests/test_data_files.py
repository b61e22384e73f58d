"""tests/data: every file the tests read is in the repository, with provenance and licence,
and the derived pose tables still hold their sources' numbers."""
from __future__ import annotations

import json
import re
import runpy
from pathlib import Path

import numpy as np
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.data.posetable import read_pose_table

DATA = Path(__file__).resolve().parent / "data"
TESTS = DATA.parent


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_every_data_file_has_provenance_and_licence():
    readme = (DATA / "README.md").read_text()
    rows = {}  # file name -> its table row
    for m in re.finditer(r"^\| (`[^|]+`) \|.*$", readme, re.M):
        rows.update({name: m.group(0) for name in re.findall(r"`([^`]+)`", m.group(1))})
    files = sorted(p.name for p in DATA.iterdir() if p.is_file() and p.name not in ("README.md", "make_tables.py"))
    for name in files:
        assert name in rows, f"{name} is not described in tests/data/README.md"
        if not name.startswith("LICENSE"):
            cells = [c.strip() for c in rows[name].strip("|").split("|")]
            assert len(cells) == 4 and all(cells), name  # file | what | provenance | licence
    for lic in ("LICENSE.calibraxis", "LICENSE.imucal"):
        assert "Permission is hereby granted" in (DATA / lic).read_text()


def test_nothing_points_outside_the_repository():
    outside = "../" + "shared"  # spelled apart so this file does not match itself
    files = [p for p in TESTS.glob("*.py") if p.name != Path(__file__).name]
    files += [TESTS.parent / "README.md", *(TESTS.parent / "docs").glob("*.md"), *(TESTS.parent / "examples").iterdir()]
    for p in files:
        assert outside not in p.read_text(), p.name


def test_derived_tables_hold_the_sources_numbers(tmp_path):
    make = runpy.run_path(str(DATA / "make_tables.py"))
    for name, build in make["TABLES"].items():
        src, shipped = build(), read_pose_table(DATA / name)
        np.testing.assert_array_equal(shipped.readings, src.readings)
        assert shipped.units == src.units and shipped.gravity_mps2 == src.gravity_mps2
    paper = yaml.safe_load((DATA / "nine_position_paper.yaml").read_text())
    faces = read_pose_table(DATA / "nine_position_paper_faces.csv", references=True)
    np.testing.assert_array_equal(faces.references_g, [p["expected"] for p in paper["positions"].values()])


def test_nine_position_paper_six_faces_model_12_against_the_papers_figures():
    """The paper's Table 3 (six MPU6050 faces, m/s^2) fitted by model 12.

    The paper reports that its six-position model leaves 5.48e-2 m/s^2 on the sensitive
    axis and its nine-position Gauss-Newton model 8.1e-3.  Six hand-placed faces
    determine model 12 with 2 degrees of freedom per channel: its sensitive-axis
    residual must be of the six-position figure's size (the faces' misplacement is not
    a calibration error the model can remove), far above the nine-position figure.
    """
    r = _run("fit", DATA / "nine_position_paper_faces.csv", "--model", "12", "--json")
    assert r.exit_code == 0, r.output
    js = json.loads(r.stdout)
    # the file's '# gravity: 9.79' is the site's gravity (issue 48): the references are scaled to it and
    # m/s^2 become standard g by 9.80665, so the calibration maps to standard g
    assert js["pose_count"] == 6 and js["input_units"] == "mps2" and js["input_per_g"] == 9.80665
    assert js["site"]["gravity_mps2"] == 9.79
    res_g = np.array([p["residual_g"] for p in js["poses"]])
    paper = yaml.safe_load((DATA / "nine_position_paper.yaml").read_text())["positions"]
    assert [p["pose"] for p in js["poses"]] == list(paper)
    ref = np.array([p["expected"] for p in paper.values()])
    sensitive_mps2 = np.abs(res_g[np.abs(ref) > 0.5]) * 9.80665
    rms = float(np.sqrt(np.mean(sensitive_mps2**2)))
    assert 0.5 * 5.48e-2 < rms < 2 * 5.48e-2, rms  # measured: 6.7e-2 m/s^2
    assert rms > 4 * 8.1e-3
    W = np.array(js["W"])
    # MPU6050 at 9.79 m/s^2 per g: gains within 3 %, cross terms a few percent (hand placement)
    assert np.all(np.abs(np.diag(W) - 1) < 0.03) and np.all(np.abs(W - np.diag(np.diag(W))) < 0.05)
    # each face is off by a few degrees: the residual is mostly across gravity, not along it
    across = np.linalg.norm(res_g * (np.abs(ref) < 0.5), axis=1)
    assert np.mean(across) > np.mean(np.abs(res_g[np.abs(ref) > 0.5]))

"""No --model: the model is chosen from the data (models/choice.py) and the choice is said."""
from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from accelcal_station.cli import cli

DATA = Path(__file__).parent / "data"


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_imucal_six_hand_placed_faces_from_a_raw_log_no_flags(tmp_path):
    """tests/data's imucal session: six faces placed by hand, no references in the file."""
    r = _run("fit", "--raw", DATA / "imucal_annotated_session.csv")
    assert r.exit_code == 0, r.output
    read = r.output.splitlines()[0]
    assert read.startswith("read ") and "six faces placed by hand" in read and "hand-placed norm fit" in read
    for face in ("+x", "-x", "+y", "-y", "+z", "-z"):
        assert f" {face}" in read
    assert "norm fit:" in r.output
    out = tmp_path / "cal.json"
    js = json.loads(_run("fit", "--raw", DATA / "imucal_annotated_session.csv", "--json", "-o", out).output)
    assert js["model_choice"]["method"] == "hand-placed norm fit"
    assert sorted({f["face"] for f in js["faces"]}) == ["+x", "+y", "+z", "-x", "-y", "-z"]
    assert max(f["angle_deg"] for f in js["faces"]) < 15
    gain = json.loads(out.read_text())["W"]
    assert [round(gain[i][i], 6) for i in range(3)] == [round(g, 6) for g in js["hand_placed"]["norm"]["gain"]]


def test_references_pick_15_when_the_cubic_is_determined_else_12(tmp_path):
    for design, model in (("an4399-8", "15"), ("six-face", "12")):
        out = tmp_path / f"{design}.csv"
        assert _run("simulate", "--poses", design, "--out", out, "--seed", "1").exit_code == 0
        js = json.loads(_run("fit", out, "--json").output)
        assert js["model"] == model and js["model_choice"]["model"] == model, js.get("model_choice")
        assert "references present" in js["model_choice"]["reason"]


def test_no_references_no_faces_refuses_naming_poses_to_add(tmp_path):
    p = tmp_path / "two.csv"
    p.write_text("# units: g\npose,x,y,z\na,0,0,1\nb,0,0,-1\nc,1,0,0\nd,0.7,0,0.7\n")
    r = _run("fit", p)
    assert r.exit_code == 2
    assert "no model is determined" in r.output and "all six faces" in r.output

"""diagnose stands on fit's ground: it reads a file exactly as `accelcal fit` does (the same static
poses, no --rate where fit needs none), takes fit's model choice for its baseline and fit's
identifiability for every held-out fold, refuses in fit's words what fit refuses, and suggests --raw
when a raw-looking file fails to parse as a pose table.  The six-face hand-placed raw log is the real
imucal session (tests/data/README.md)."""
from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from accelcal_station.cli import cli

LOG = Path(__file__).parent / "data" / "imucal_annotated_session.csv"


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_diagnose_finds_the_poses_fit_finds_with_no_flags_and_reports_no_gap_from_an_undetermined_baseline():
    fit = json.loads(_run("fit", "--raw", LOG, "--json").stdout)
    names = [s["pose"] for s in fit["segmentation"]["segments"]]
    r = _run("diagnose", "--raw", LOG, "--json")  # no --rate: fit needs none
    assert r.exit_code == 2
    err = json.loads(r.stdout)["error"]
    assert f"{len(names)} static poses found ({', '.join(names)})" in err  # the poses fit finds
    assert "no gap can be measured" in err and "do not determine the baseline (offset, gain)" in err
    assert "--rate HZ" in err  # what would add a view, and it works:
    js = json.loads(_run("diagnose", "--raw", "--rate", "102.4", LOG, "--json").stdout)
    assert js["data"]["poses"] == len(names)
    assert js["baseline"] == ["offset", "gain"]  # fit's choice: the hand-placed norm fit, no cross-axis
    assert js["data"]["static_view"] is False  # a face with one pose left out: the fold's fit is undetermined
    assert "held out, the other poses do not determine the baseline" in js["data"]["static_view_note"]
    assert "9 terms" not in json.dumps(js["identifiability"])


def test_a_design_fit_refuses_is_refused_in_fits_words(tmp_path):
    table = tmp_path / "five.csv"
    table.write_text("# units: counts\n# counts_per_g: 4096\npose,x,y,z\n" + "".join(
        f"p{k},{x},{y},{z}\n" for k, (x, y, z) in enumerate([(4096, 10, 5), (-4100, 3, 2), (5, 4090, 1),
                                                              (2, -4101, 9), (3, 7, 4095)])))
    fit_err = json.loads(_run("fit", table, "--json").stdout)["error"]
    err = json.loads(_run("diagnose", table, "--json").stdout)["error"]
    assert fit_err.split(": ", 1)[1] in err and "`accelcal fit` refuses these poses" in err


def test_a_raw_looking_file_without_raw_suggests_it_and_the_hint_works(tmp_path):
    for cmd in ("fit", "diagnose"):
        err = json.loads(_run(cmd, LOG, "--json").stdout)["error"]
        assert err.endswith(f"if {LOG} is a raw sample log, add --raw")
    assert _run("fit", LOG, "--raw").exit_code == 0

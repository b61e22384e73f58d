"""Raw-log header lines (`# units:`, `# counts_per_g:`) are honoured or refused exactly as the
pose-table reader does (one rule: data.posetable.stated_scale), and a line break inside a quoted
number cell is refused by every reader (pose table, raw log, lot file), never read as 2414."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from accelcal_station.api import load
from accelcal_station.cli import cli
from accelcal_station.data.posetable import write_pose_table


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A raw log of the simulated ten-pose board (counts, 4096 counts/g) and the pose table fit reads from it."""
    from test_held_terms import FACES, TILTS, write_log

    d = tmp_path_factory.mktemp("hdr")
    raw = write_log(d / "raw.csv", FACES + TILTS, 3)
    table = d / "table.csv"
    write_pose_table(load(raw, True).session, table)
    body = [ln for ln in table.read_text().splitlines() if not ln.startswith("#")]
    table.write_text("\n".join(body) + "\n")  # no metadata of its own: each case states its one line
    return raw, table


def _with_line(path, line, out):
    out.write_text(line + "\n" + path.read_text())
    return out


def _run(path, *args):
    r = CliRunner().invoke(cli, ["fit", str(path), "--json", "--model", "9", *args])
    return r.exit_code, json.loads(r.stdout)


@pytest.mark.parametrize("line", ["# units: g", "# units: furlongs", "# counts_per_g: 0", "# counts_per_g: -4096",
                                  "# counts_per_g: 1e999"])
def test_a_stated_line_the_readings_or_the_rules_refuse_is_refused_by_both_readers(pair, tmp_path, line):
    raw, table = pair
    code_t, js_t = _run(_with_line(table, line, tmp_path / "t.csv"))
    code_r, js_r = _run(_with_line(raw, line, tmp_path / "r.csv"), "--raw")
    assert code_t == code_r == 2, (js_t, js_r)
    value = line.split(":", 1)[1].strip()
    assert js_t["kind"] == js_r["kind"] == "UnitsError"
    assert ("median norm" if value == "g" else repr(value)) in js_r["error"]
    assert js_t["error"].split(": ", 1)[1] == js_r["error"].split(": ", 1)[1]  # the same words after the path


def test_a_stated_counts_per_g_is_honoured_by_both_readers(pair, tmp_path):
    raw, table = pair
    code_t, js_t = _run(_with_line(table, "# counts_per_g: 1000", tmp_path / "t.csv"))
    code_r, js_r = _run(_with_line(raw, "# counts_per_g: 1000", tmp_path / "r.csv"), "--raw")
    assert code_t == code_r == 0
    assert js_t["input_per_g"] == js_r["input_per_g"] == 1000.0
    text = CliRunner().invoke(cli, ["fit", "--raw", str(tmp_path / "r.csv"), "--model", "9"]).output
    assert "1000 counts/g given" in text.splitlines()[0]
    plain = _run(raw, "--raw")[1]
    assert plain["input_per_g"] == 4096.0  # without the line: the power of two nearest the readings' radius


def test_a_line_break_inside_a_number_cell_is_refused_by_every_reader(tmp_path):
    faces = [("a", 0, 0, 10, 4000), ("b", 0, 180, 10, -4100), ("c", 90, 0, -4100, 20), ("d", -90, 0, 4100, 20),
             ("e", 0, 90, 4100, 20), ("f", 0, -90, -4100, 20)]
    rows = [f'{n},{p},{r},"24\n14",{y},{z}' if n == "a" else f"{n},{p},{r},20,{y},{z}" for n, p, r, y, z in faces]
    table = tmp_path / "t.csv"
    table.write_text("pose,pitch_deg,roll_deg,x,y,z\n" + "\n".join(rows) + "\n")
    lot = tmp_path / "lot.csv"
    lot.write_text("serial,pose,pitch_deg,roll_deg,x,y,z\n" + "\n".join(f"S1,{r}" for r in rows) + "\n")
    raw = tmp_path / "raw.csv"
    raw.write_text("t,x,y,z\n" + '0.00,"24\n14",10,4000\n' + "".join(f"0.{k:02d},20,10,4000\n" for k in range(1, 99)))
    for cmd in (["fit", str(table), "--counts-per-g", "4096"], ["diagnose", str(table)],
                ["fit", "--raw", str(raw)]):
        r = CliRunner().invoke(cli, [*cmd, "--json"])
        assert r.exit_code == 2, (cmd, r.output)
        assert "2414" not in r.stdout
    out = tmp_path / "res.csv"
    r = CliRunner().invoke(cli, ["batch", str(lot), "--counts-per-g", "4096", "--model", "12", "--out", str(out)])
    assert "is not a number" in r.output and "0 of 1 boards" in r.output
    assert "line break inside a cell" in CliRunner().invoke(cli, ["fit", str(table), "--counts-per-g", "4096"]).output

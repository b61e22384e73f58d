"""tests/data/README.md's table of real data sets says what `accelcal fit` does with them now."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli

DATA = Path(__file__).parent / "data"


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split(" | ")]


def _rows() -> list[tuple[str, bool, str, str]]:
    """(file, raw, model chosen, held) of every table row that names a loadable file."""
    return [(r[0], r[1], r[2][1], r[2][2]) for r in _full_rows()]


def _full_rows() -> list[tuple[str, bool, list[str]]]:
    """(file, raw, every cell) of every table row that names a loadable file."""
    text = (DATA / "README.md").read_text()
    table = text[text.index("## Every data set here"):]
    out = []
    for line in table.splitlines():
        m = re.match(r"\| file ([\w.]+\.csv)( \(--raw\))? \|", line)
        if m:
            out.append((m.group(1), bool(m.group(2)), _cells(line)[1:]))
    return out


ROWS = _rows()


def test_the_table_names_every_csv_data_set():
    assert sorted(r[0] for r in ROWS) == sorted(p.name for p in DATA.glob("*.csv"))


@pytest.mark.parametrize(("name", "raw", "model", "held"), ROWS, ids=[r[0] for r in ROWS])
def test_each_row_matches_the_cli(name, raw, model, held):
    r = CliRunner().invoke(cli, ["fit", *(["--raw"] if raw else []), str(DATA / name), "--json"])
    assert r.exit_code == 0, r.output
    choice = json.loads(r.stdout)["model_choice"]
    if model.startswith("hand-placed"):
        assert choice["method"] == "hand-placed norm fit"
    else:
        assert choice["method"] == f"model {model.split()[0]}"
    assert choice["held"] == ([] if held.startswith("none") else [t.strip() for t in held.split(",")])


def _mg(text: str) -> float | None:
    m = re.match(r"(\d+\.\d+) mg", text)
    return float(m.group(1)) if m else None


@pytest.mark.parametrize(("name", "raw", "cells"), _full_rows(), ids=[r[0] for r in _full_rows()])
def test_each_rows_held_out_figures_and_hold_decisions_match_the_cli(name, raw, cells):
    """LOO and LOO by orientation to the table's 0.1 mg (n/a: none), and every standard error the
    hold decision quotes to its two significant digits."""
    r = CliRunner().invoke(cli, ["fit", *(["--raw"] if raw else []), str(DATA / name), "--json"])
    js = json.loads(r.stdout)
    loo, by_orient, decision = cells[3], cells[4], cells[5]
    if _mg(loo) is None:
        assert js["crossval_rms_g"] is None and "n/a" in loo
    else:
        assert round(js["crossval_rms_g"] * 1e3, 1) == _mg(loo)
    if by_orient.startswith("= LOO"):
        assert js["crossval_by_orientation_rms_g"] == js["crossval_rms_g"]
        assert f"{js['distinct_orientations']} distinct orientations of {js['pose_count']} poses" in by_orient
    else:
        assert by_orient.startswith("n/a") and js["crossval_by_orientation_rms_g"] is None
        assert f"{js['distinct_orientations']} distinct orientations of {js['pose_count']} poses" in by_orient
    quoted = [float(x) for x in re.findall(r"\+-(0\.\d+)(?!\d)", decision.split("; prior")[0])]
    if js["model"] == "9":
        W = js["stderr"]["W"]
        assert quoted == [float(f"{se:.2g}") for se in (W[0][1], W[0][2], W[1][2])]
        assert all(f"{t} fitted" not in decision or t not in [h["term"] for h in js["held"]]
                   for t in ("M_xy", "M_xz", "M_yz"))

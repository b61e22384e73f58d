"""tests/data/README.md's table of real data sets says what `accelcal fit` does with them now."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli

DATA = Path(__file__).parent / "data"


def _rows() -> list[tuple[str, bool, str, str]]:
    """(file, raw, model chosen, held) of every table row that names a loadable file."""
    text = (DATA / "README.md").read_text()
    table = text[text.index("## Every data set here"):]
    out = []
    for line in table.splitlines():
        m = re.match(r"\| file ([\w.]+\.csv)( \(--raw\))? \| [^|]+ \| ([^|]+) \| ([^|]+) \|", line)
        if m:
            out.append((m.group(1), bool(m.group(2)), m.group(3).strip(), m.group(4).strip()))
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

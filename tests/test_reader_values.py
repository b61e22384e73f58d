"""Issue 53: input values are checked once, at the reader, on every path, and no Python warning
reaches the terminal.

A lot (CSV and Parquet), a pose table and a raw log each get one hostile cell: infinity, NaN, a
negative or fractional sample count, '4_096', Arabic-Indic digits.  The lot readers make the board
a SKIP line naming pose, column and value; a pose table or raw log is refused in one line.  The
issue's own commands run as real processes, once as they are (stderr must hold no warning) and
once with PYTHONWARNINGS=error (a warning would be an internal error, exit 70).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.csv as pcsv
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.lot.synthetic import write_lot

REPO = Path(__file__).resolve().parents[1]
ARABIC_4096 = "\u0664\u0660\u0669\u0666"  # ٤٠٩٦


def _lot(folder: Path, col: str, value: str, boards: int = 100, parquet: bool = False) -> Path:
    """A 100-board lot with ``value`` in column ``col`` of the first board's first row."""
    src = write_lot(folder / "clean.csv", boards, seed=1)
    lines = src.read_text().splitlines()
    h = next(i for i, ln in enumerate(lines) if ln.startswith("serial"))
    cells = lines[h + 1].split(",")
    cells[lines[h].split(",").index(col)] = value
    lines[h + 1] = ",".join(cells)
    out = folder / f"lot-{col}.csv"
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    if not parquet:
        return out
    t = pcsv.read_csv(out, read_options=pcsv.ReadOptions(skip_rows=2),
                      convert_options=pcsv.ConvertOptions(null_values=[""]))
    pq.write_table(t.replace_schema_metadata({"units": "counts", "counts_per_g": "4096"}), folder / "lot.parquet")
    return folder / "lot.parquet"


def _run(*args: str, errors: bool = False) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    if errors:
        env["PYTHONWARNINGS"] = "error"
    return subprocess.run([sys.executable, "-m", "accelcal_station", *args], capture_output=True, text=True,
                          env=env, timeout=600)


@pytest.mark.parametrize("errors", [False, True], ids=["plain", "PYTHONWARNINGS=error"])
def test_twin_fit_with_an_infinite_angle(tmp_path, errors):
    lot = _lot(tmp_path, "roll_deg", "inf")
    r = _run("twin", "fit", str(lot), "-o", str(tmp_path / "twin.yaml"), errors=errors)
    assert r.returncode == 0, r.stderr
    assert "Warning" not in r.stderr and "internal error" not in r.stderr + r.stdout, r.stderr


@pytest.mark.parametrize("errors", [False, True], ids=["plain", "PYTHONWARNINGS=error"])
def test_batch_with_a_negative_sample_count(tmp_path, errors):
    lot = _lot(tmp_path, "n", "-5")
    r = _run("batch", str(lot), "--out", str(tmp_path / "res.csv"), errors=errors)
    assert r.returncode == 1, r.stderr  # one board skipped
    assert r.stderr == "", r.stderr
    first = r.stdout.splitlines()[0]
    assert first == "SKIP B00000000: pose 'p1': n -5: sample count n out of range; allowed a whole number 1 to 1e+15"
    assert "99 of 100 boards recalibrated" in r.stdout


CELLS = [("roll_deg", "inf", "roll_deg"), ("roll_deg", "-inf", "roll_deg"), ("std_y", "nan", "std_y"),
         ("std_y", "-1", "std_y"), ("n", "0", "n"), ("n", "2.5", "n"), ("x", "1e999", "x"),
         ("x", "4_096", "x"), ("x", ARABIC_4096, "x"), ("pitch_deg", "NaN", "pitch_deg")]


# a Parquet number column holds no text: '4_096' and other digits are the CSV readers' cases
LOT_CASES = [(*c, pq_) for c in CELLS for pq_ in (False, True) if not (pq_ and c[1] in ("4_096", ARABIC_4096))]


@pytest.mark.parametrize(("col", "value", "named", "parquet"), LOT_CASES,
                         ids=[f"{c}={v}-{'parquet' if p else 'csv'}" for c, v, _, p in LOT_CASES])
def test_a_hostile_cell_skips_its_board_in_every_lot_reader(tmp_path, col, value, named, parquet):
    lot = _lot(tmp_path, col, value, boards=20, parquet=parquet)
    r = CliRunner().invoke(cli, ["batch", str(lot), "--out", str(tmp_path / "res.csv")])
    skips = [ln for ln in r.output.splitlines() if ln.startswith("SKIP")]
    assert r.exit_code == 1 and len(skips) == 1, r.output
    assert skips[0].startswith("SKIP B00000000:") and named in skips[0], skips
    assert "19 of 20 boards recalibrated" in r.output


@pytest.mark.parametrize("value", ["4_096", ARABIC_4096, "nan", "inf"])
def test_a_pose_table_refuses_what_a_lot_refuses(tmp_path, value):
    text = (REPO / "examples" / "poses.csv").read_text().splitlines()
    h = next(i for i, ln in enumerate(text) if ln.startswith("pose"))
    cells = text[h + 1].split(",")
    cells[text[h].split(",").index("x")] = value
    text[h + 1] = ",".join(cells)
    p = tmp_path / "poses.csv"
    p.write_text("\n".join(text) + "\n", encoding="utf-8")
    r = CliRunner().invoke(cli, ["fit", str(p)])
    assert r.exit_code == 2 and f"line {h + 2}, column x" in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1


@pytest.mark.parametrize("value", ["4_096", ARABIC_4096])
def test_a_raw_log_refuses_other_notations(tmp_path, value):
    rows = [f"{i * 0.01:.2f},{0.001 * i},{0.002},{1.0}" for i in range(200)]
    rows[50] = f"0.50,{value},0.002,1.0"
    p = tmp_path / "raw.csv"
    p.write_text("t,x,y,z\n" + "\n".join(rows) + "\n", encoding="utf-8")
    r = CliRunner().invoke(cli, ["fit", str(p), "--raw", "--units", "g"])
    assert r.exit_code == 2 and "line 52" in r.output and "ASCII decimal" in r.output, r.output


@pytest.mark.parametrize("args", [["simulate", "--poses", "six-face", "--lot", "4_096", "--out", "x.csv"],
                                  ["simulate", "--poses", "six-face", "--lot", ARABIC_4096, "--out", "x.csv"],
                                  ["simulate", "--poses", "six-face", "--move-s", "1_0", "--out", "x.csv"],
                                  ["simulate", "--poses", "six-face", "--temps", f"{ARABIC_4096[:2]},25",
                                   "--out", "x.csv"],
                                  ["fit", "poses.csv", "--counts-per-g", "4_096"],
                                  ["batch", "poses.csv", "--counts-per-g", ARABIC_4096],
                                  ["poses", "six-face", "--noise-mg", "1_0"]])
def test_options_take_ascii_decimal_numbers_only(tmp_path, monkeypatch, args):
    monkeypatch.chdir(tmp_path)
    Path("poses.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 2, r.output
    assert len([ln for ln in r.output.splitlines() if ln.startswith("error")]) == 1, r.output
    assert not Path("x.csv").exists()


@pytest.mark.parametrize(("col", "value", "named"), CELLS)
def test_the_csv_module_reader_skips_the_same_boards(tmp_path, monkeypatch, col, value, named):
    """The reader used without pyarrow (the csv module): the same board bad, its value never a number."""
    import accelcal_station.data.lotfile as lotfile

    monkeypatch.setattr(lotfile, "arrow_available", lambda: False)
    lot = _lot(tmp_path, col, value, boards=3)
    _, chunks = lotfile.open_lot(lot)
    chunk = next(chunks)
    assert chunk.bad[0] is not None and named in chunk.bad[0], chunk.bad
    assert chunk.bad[1:] == [None, None]
    assert np.isnan(chunk.cols[col][0])  # NaN: nothing downstream computes with it


@pytest.mark.parametrize(("sql", "said"), [
    ("UPDATE poses SET n = 0 WHERE run_id = 1 AND idx = 0", "SKIP run 1: pose 'p0': n 0: sample count n out of range"),
    ("UPDATE poses SET std_x = -1 WHERE run_id = 1 AND idx = 0", "SKIP run 1: pose 'p0': std_x -1: std out of range")])
def test_a_store_value_no_table_allows_skips_its_run(tmp_path, sql, said):
    """A store's row checks take n = 0 and a negative std; batch --from-store checks the values as a
    pose table does, once, and names the run (issue 53)."""
    import sqlite3

    from test_store_outputs import _store

    db = tmp_path / "s.sqlite"
    _store(db)
    with sqlite3.connect(db) as c:
        c.execute(sql)
    r = _run("batch", "--from-store", str(db), errors=True)
    assert r.returncode == 1 and r.stderr == "", r.stderr
    assert said in r.stdout and "2 of 3 boards recalibrated" in r.stdout, r.stdout

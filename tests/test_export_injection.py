"""Issue 34: no export carries a formula.  A serial, operator or lot that starts with ``=`` (or
``+ - @``, tab, CR: OWASP's CSV-injection list) is written with a leading single quote in every
CSV export and results table, control characters (an ESC) as ``\\xNN``; numbers (``-0.5``) stay
numbers.  Each CSV is read back with the csv module and the cell checked.  On the way in,
``accelcal run`` refuses such an operator, lot or station id as it refuses such a serial."""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.fileguard.cells import safe_cell, safe_text
from accelcal_station.lot.synthetic import write_lot
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store

EVIL = "=cmd|' /C calc'!A0"
INERT = "'" + EVIL
REFS = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]


def _rows(path_or_text: str | Path) -> list[dict[str, str]]:
    text = Path(path_or_text).read_text() if isinstance(path_or_text, Path) else path_or_text
    return list(csv.DictReader(io.StringIO("".join(ln + "\n" for ln in text.splitlines()
                                                   if not ln.startswith("#")))))


@pytest.fixture()
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _hostile_store(path: Path) -> None:
    """A store written by something that did not validate (an old station, a hand edit)."""
    from accelcal_station.models.fitting import fit_session

    s = Session([PoseRecord(f"p{i}", np.array([4096.0 * a + 3, 4096.0 * b - 5, 4096.0 * c + 7]), np.full(3, 2.0),
                            100, np.array([a, b, c], float)) for i, (a, b, c) in enumerate(REFS)],
                "counts", 4096.0, device=EVIL)
    fit = fit_session(s, "12")
    with Store(path) as st:
        rid = st.start_run(device_serial=EVIL, operator=EVIL + "\x1b[31m", lot=EVIL, station_id="@SUM(A1)",
                           started_at=1.7e9)
        st.finish_run(rid, session=s, calibration=fit.calibration, verdict="PASS", fit_summary={})


@pytest.mark.parametrize("poses", [False, True])
def test_report_export_csv_neutralises_serial_operator_and_lot(here, poses):
    _hostile_store(here / "s.sqlite")
    r = CliRunner().invoke(cli, ["report", "export", "--db", "s.sqlite", "-o", "out.csv", *(["--poses"] * poses)])
    assert r.exit_code == 0, r.output
    rows = _rows(here / "out.csv")
    assert rows and all(row["device_serial"] == INERT and row["lot"] == INERT for row in rows)
    if not poses:
        assert rows[0]["operator"] == INERT + "\\x1b[31m" and rows[0]["station_id"] == "'@SUM(A1)"
        assert float(rows[0]["V0"]) < 0 and not rows[0]["V0"].startswith("'")  # a negative number stays one
    assert "\x1b" not in (here / "out.csv").read_text()


def test_batch_summary_csv_from_the_store_and_from_a_pose_table(here):
    _hostile_store(here / "s.sqlite")
    r = CliRunner().invoke(cli, ["batch", "--from-store", "s.sqlite", "--csv", "b.csv"])
    assert r.exit_code == 0, r.output
    assert _rows(here / "b.csv")[0]["serial"] == INERT
    table = Path(__file__).resolve().parents[1] / "examples" / "poses.csv"
    Path("@evil.csv").write_text(f"# serial: {EVIL}\n" + table.read_text())
    r = CliRunner().invoke(cli, ["batch", "@evil.csv", "--csv", "p.csv"])
    assert r.exit_code == 0, r.output
    row = _rows(here / "p.csv")[0]
    assert row["serial"] == INERT and row["source"] == "'@evil.csv"


@pytest.mark.parametrize("arrow", [True, False])
def test_lot_results_table_neutralises_a_lot_serial(here, monkeypatch, arrow):
    if not arrow:
        monkeypatch.setattr("accelcal_station.data.lotfile.arrow_available", lambda: False)
    write_lot("lot.csv", 4, seed=1)
    lines = Path("lot.csv").read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith("serial,")) + 1
    serial0 = lines[first].split(",")[0]
    evil = '"' + EVIL.replace('"', '""') + '"'
    Path("lot.csv").write_text("\n".join(ln.replace(serial0 + ",", evil + ",", 1) if ln.startswith(serial0 + ",")
                                         else ln for ln in lines) + "\n")
    r = CliRunner().invoke(cli, ["batch", "lot.csv", "--out", "r.csv"])
    assert r.exit_code in (0, 1), r.output
    rows = _rows(here / "r.csv")
    assert INERT in [row["serial"] for row in rows] and EVIL not in [row["serial"] for row in rows]
    assert all(not row["V0"].startswith("'") for row in rows)


@pytest.mark.parametrize(("flag", "value"), [("--operator", EVIL), ("--operator", "ana\x1b[2J"),
                                             ("--lot", EVIL), ("--operator", "@ana"), ("--lot", "-L1")])
def test_run_refuses_a_formula_or_control_character_on_the_way_in(here, flag, value):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": "runs.sqlite"}
    Path("st.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", "st.yaml", flag, value])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "allowed" in r.output, r.output
    assert not Path("runs.sqlite").exists()


def test_run_refuses_a_station_id_that_is_a_formula(here):
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": "runs.sqlite"}
    cfg["station"]["id"] = "=HYPERLINK(\"http://x\")"
    Path("st.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", "st.yaml"])
    assert r.exit_code == 2 and "station.id" in r.output, r.output


@pytest.mark.parametrize(("cell", "out"), [
    ("=1+1", "'=1+1"), ("+SUM(A1)", "'+SUM(A1)"), ("-2+3", "'-2+3"), ("@SUM(1)", "'@SUM(1)"),
    ("\t=1", "'\\x09=1"), ("\r=1", "'\\x0d=1"), ("-0.5", "-0.5"), ("+1e-3", "+1e-3"), ("SN-1", "SN-1"),
    ("a\x1bb", "a\\x1bb"), ("", ""), (-0.5, -0.5), (None, None), (3, 3)])
def test_cells_as_owasp_lists_them(cell, out):
    """The OWASP CSV-injection characters, written here from its guidance, not from the code."""
    assert safe_cell(cell) == out
    if isinstance(cell, str):
        assert safe_text(safe_text(cell)) == safe_text(cell) or cell.startswith(("\t", "\r"))

"""Issue 34's closing figures, counted on real SQLite files through the real command line (run by
benchmarks/robustness_counts.py; alone: python benchmarks/store_counts.py): writing commands
pointed at a store, damaged stores read by every reader and by `serve`, formula cells in exports,
the schema-2 store served, a run whose station process died."""
from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path

import yaml
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from accelcal_station.cli import cli  # noqa: E402
from accelcal_station.station.settings import default_config_path  # noqa: E402

BASE = yaml.safe_load(default_config_path().read_text())


def _sha(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _writer_counts(tmp: Path) -> tuple[int, int]:
    """Every writing command pointed at a store in its folder (default and another name): refused with
    exit 2 and the store's hash unchanged."""
    from test_store_outputs import _store, _writers

    from accelcal_station.lot.synthetic import write_lot

    cfg = dict(BASE, store={"path": "station-runs.sqlite"})
    tried = refused = 0
    cwd = os.getcwd()
    os.chdir(tmp)
    try:
        (tmp / "poses.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
        write_lot("lot.csv", 100, seed=1)
        _store(tmp / "source.sqlite")
        (tmp / "station.yaml").write_text(yaml.safe_dump(cfg))
        for name in ("accelcal-runs.sqlite", "other-name.db"):
            _store(tmp / name)
            before = _sha(tmp / name)
            for args in [*_writers(name), ["run", "--config", "station.yaml", "--store", "poses.csv"]]:
                r = CliRunner().invoke(cli, args)
                tried += 1
                refused += r.exit_code == 2 and _sha(tmp / name) == before
    finally:
        os.chdir(cwd)
    return tried, refused


def _damaged_stores(tmp: Path) -> list[Path]:
    """A good 3-run store damaged each way of issue 34: a bad UTF-8 byte in a text cell, a time
    'yesterday', negative ids, a dropped table, a renamed column, a page header overwritten, and
    30 seeded copies with 8 flipped bits."""
    import shutil
    import sqlite3

    from test_store_damage import ISSUE34, _flipped, _good_store

    good = tmp / "good.sqlite"
    _good_store(good)
    cases = {**ISSUE34, "negative_id": ["PRAGMA foreign_keys = OFF", "UPDATE runs SET id = -5 WHERE id = 3",
                                        "UPDATE poses SET run_id = -5 WHERE run_id = 3"],
             "runs_dropped": ["PRAGMA foreign_keys = OFF", "DROP TABLE runs"],
             "column_renamed": ["ALTER TABLE runs RENAME COLUMN operator TO op"]}
    out = []
    for name, statements in cases.items():
        db = tmp / f"{name}.sqlite"
        shutil.copy(good, db)
        with sqlite3.connect(db) as c:
            for st in statements:
                c.execute(st)
        out.append(db)
    return out + [_flipped(good, tmp, seed) for seed in range(30)]


def _reader_counts(stores: list[Path]) -> dict[str, int]:
    """Every reader on every damaged store: exit 70, tracebacks, damaged runs batch left out unnamed."""
    from test_store_damage import _cmds

    n = {"commands": 0, "exit70": 0, "traceback": 0, "hash_changed": 0, "silent_drop": 0}
    for db in stores:
        before = _sha(db)
        for args in _cmds(str(db)):
            r = CliRunner().invoke(cli, args)
            n["commands"] += 1
            n["exit70"] += r.exit_code == 70
            n["traceback"] += "Traceback" in r.output
            if args[0] == "batch" and r.exit_code in (0, 1):  # every run counted: fitted or SKIP
                import sqlite3

                with sqlite3.connect(db) as c:
                    try:
                        runs = c.execute("SELECT count(*) FROM runs").fetchone()[0]
                    except sqlite3.Error:
                        runs = None
                m = re.search(r"(\d+) of (\d+) boards", r.output)
                n["silent_drop"] += runs is not None and m is not None and int(m[2]) != runs
        n["hash_changed"] += _sha(db) != before
    return n


def _web_counts(stores: list[Path]) -> tuple[int, int]:
    """Requests to every page and endpoint of `accelcal serve` on every damaged store: how many were 500."""
    try:
        from fastapi.testclient import TestClient
    except ImportError:
        return 0, 0
    from test_web_damaged_store import PAGES

    from accelcal_station.web.app import create_app
    from accelcal_station.web.settings import WebSettings

    asked = failed = 0
    for db in stores:
        client = TestClient(create_app(WebSettings(store=str(db))), raise_server_exceptions=False)
        for url in PAGES:
            asked, failed = asked + 1, failed + (client.get(url).status_code == 500)
    return asked, failed


def _export_counts(tmp: Path) -> tuple[int, int]:
    """CSV cells starting with = + - @ tab CR that are not numbers, in every export of a hostile store."""
    import csv
    import io

    from test_export_injection import _hostile_store

    from accelcal_station.fileguard.cells import FORMULA_START

    db = tmp / "hostile.sqlite"
    _hostile_store(db)
    cells = live = 0
    for args in (["report", "export", "--db", str(db)], ["report", "export", "--poses", "--db", str(db)],
                 ["batch", "--from-store", str(db), "--csv", str(tmp / "b.csv")]):
        r = CliRunner().invoke(cli, args)
        text = (tmp / "b.csv").read_text() if "--csv" in args else r.stdout
        for row in csv.reader(io.StringIO(text)):
            for cell in row:
                cells += 1
                if cell.startswith(FORMULA_START):
                    try:
                        float(cell)
                    except ValueError:
                        live += 1
    return cells, live


def _legacy_served(tmp: Path) -> bool:
    """`serve` (its store open and every page) on a copy of the schema-2 store: its hash unchanged."""
    import shutil

    db = tmp / "v2.sqlite"
    shutil.copy(REPO / "tests" / "data" / "legacy_store_v2.sqlite", db)
    before = _sha(db)
    CliRunner().invoke(cli, ["serve", "--db", str(db), "--port", "8797"])
    _web_counts([db])
    return _sha(db) == before


def _crashed_run_reads(tmp: Path) -> str:
    """The status `report list` shows for a run whose station process died (os._exit) mid-run."""
    import subprocess

    db = tmp / "crash.sqlite"
    code = (f"import os; from accelcal_station.store.runs import Store; s = Store({str(db)!r}); "
            "s.start_run(device_serial='SN-crash'); os._exit(9)")
    subprocess.run([sys.executable, "-c", code], timeout=120, check=False)
    r = CliRunner().invoke(cli, ["report", "list", "--db", str(db), "--json"])
    return json.loads(r.stdout)[0]["status"]


def store_counts() -> None:
    """Issue 34's figures, each counted on real SQLite files through the real command line."""
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        (tmp / "w").mkdir()
        tried, refused = _writer_counts(tmp / "w")
        print(f"store as output: {tried} writing commands pointed at a store, {refused} refused with exit 2 "
              "and the store's hash unchanged")
        stores = _damaged_stores(tmp)
        n = _reader_counts(stores)
        print(f"damaged stores: {len(stores)} stores x {n['commands'] // len(stores)} readers = {n['commands']} "
              f"commands: exit 70 {n['exit70']}, traceback {n['traceback']}, a run left out of batch unnamed "
              f"{n['silent_drop']}, store changed {n['hash_changed']}")
        asked, failed = _web_counts(stores)
        print(f"serve on damaged stores: {asked} requests, HTTP 500 {failed}")
        cells, live = _export_counts(tmp)
        print(f"exports of a hostile store: {cells} CSV cells, {live} a spreadsheet would run")
        print(f"serve on a schema-2 store: hash {'unchanged' if _legacy_served(tmp) else 'CHANGED'}")
        print(f"a run whose station process died reads: {_crashed_run_reads(tmp)}")


if __name__ == "__main__":
    store_counts()

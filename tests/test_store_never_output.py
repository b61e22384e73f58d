"""Issue 53: a store is never an output, whatever the flags.

Three real stores sit in the folder: ``source.sqlite`` (a command's own ``--db`` /
``--from-store``), ``station-runs.sqlite`` (``store.path`` of ``station.yaml``) and
``accelcal-runs.sqlite`` (the default store in the working directory, also the default
station's).  Every writing option of every command is pointed at every store it can reach,
with ``--force`` where the command has it: exit 2, one line, the store's SHA-256 unchanged.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner
from test_store_outputs import _store

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.lot.synthetic import write_lot

REPO = Path(__file__).resolve().parents[1]
OWN, CONFIG, DEFAULT = "source.sqlite", "station-runs.sqlite", "accelcal-runs.sqlite"


def _sha(path: str | Path) -> str | None:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest() if Path(path).exists() else None


@pytest.fixture()
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("poses.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    write_lot("lot.csv", 20, seed=1)
    for name in (OWN, CONFIG, DEFAULT):
        _store(tmp_path / name)
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": CONFIG}
    cfg["device"]["seed"] = 3
    cfg["device"]["eeprom"]["image"] = "board.eeprom"
    Path("station.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["nvm", "backup", "--config", "station.yaml", "--out", "backup.json"])
    assert r.exit_code == 0, r.output
    return tmp_path


# (command line with {T} for the target, the stores it reaches); "--config station.yaml" reaches CONFIG,
# a command with --config left out reaches the default station's store (DEFAULT)
WRITERS: list[tuple[list[str], tuple[str, ...]]] = [
    (["fit", "poses.csv", "-o", "{T}", "--force"], (DEFAULT,)),
    (["fit", "poses.csv", "--hand-placed", "-o", "{T}", "--force"], (DEFAULT,)),
    (["simulate", "--config", "station.yaml", "--poses", "six-face", "--out", "{T}", "--force"], (CONFIG, DEFAULT)),
    (["simulate", "--poses", "six-face", "--raw", "--out", "{T}", "--force"], (DEFAULT,)),
    (["simulate", "--config", "station.yaml", "--poses", "six-face", "--out", "new.csv", "--truth-out", "{T}",
      "--force"], (CONFIG, DEFAULT)),
    (["simulate", "--config", "station.yaml", "--poses", "six-face", "--lot", "3", "--out", "{T}", "--force"],
     (CONFIG, DEFAULT)),
    (["batch", "poses.csv", "--config", "station.yaml", "--csv", "{T}", "--force"], (CONFIG, DEFAULT)),
    (["batch", "--from-store", OWN, "--config", "station.yaml", "--csv", "{T}", "--force"], (OWN, CONFIG, DEFAULT)),
    (["batch", "poses.csv", "--config", "station.yaml", "--out-dir", "{T}", "--force"], (CONFIG, DEFAULT)),
    (["batch", "lot.csv", "--config", "station.yaml", "--out", "{T}", "--force"], (CONFIG, DEFAULT)),
    (["twin", "fit", "lot.csv", "-o", "{T}", "--force"], (DEFAULT,)),
    (["twin", "fit", "--db", OWN, "-o", "{T}", "--force"], (OWN, DEFAULT)),
    (["report", "export", "--db", OWN, "--config", "station.yaml", "--force", "-o", "{T}"], (OWN, CONFIG, DEFAULT)),
    (["report", "export", "--config", "station.yaml", "--format", "json", "--force", "-o", "{T}"], (CONFIG, DEFAULT)),
    (["report", "summary", "--db", OWN, "--config", "station.yaml", "--force", "--html", "{T}"],
     (OWN, CONFIG, DEFAULT)),
    (["report", "plot", "1", "--db", OWN, "--config", "station.yaml", "--force", "-o", "{T}"], (OWN, CONFIG, DEFAULT)),
    (["report", "certificate", "1", "--db", OWN, "--config", "station.yaml", "--force", "-o", "{T}"],
     (OWN, CONFIG, DEFAULT)),
    (["report", "certificate", "--lot", "L", "--store", OWN, "--force", "-o", "{T}"], (OWN, DEFAULT)),
    (["nvm", "backup", "--config", "station.yaml", "--out", "{T}"], (CONFIG, DEFAULT)),
    (["nvm", "erase", "--config", "station.yaml", "--yes", "--backup-to", "{T}"], (CONFIG, DEFAULT)),
    (["nvm", "restore", "backup.json", "--config", "station.yaml", "--force", "--backup-to", "{T}"],
     (CONFIG, DEFAULT)),
    (["diagnose", "poses.csv", "--config", "station.yaml", "--report", "{T}"], (CONFIG, DEFAULT)),
]
CASES = [(i, store) for i, (_, stores) in enumerate(WRITERS) for store in stores]


@pytest.mark.parametrize(("i", "store"), CASES, ids=[f"{' '.join(WRITERS[i][0][:2])}-{i}-{s}" for i, s in CASES])
def test_no_writing_option_replaces_a_store_it_reaches(here, i, store):
    before = {name: _sha(name) for name in (OWN, CONFIG, DEFAULT)}
    image = _sha("board.eeprom")
    args = [a.replace("{T}", store) for a in WRITERS[i][0]]
    r = CliRunner().invoke(cli, args)
    errors = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2, (args, r.output)
    assert len(errors) == 1 and errors[0].startswith("error"), r.output
    assert {name: _sha(name) for name in (OWN, CONFIG, DEFAULT)} == before
    assert _sha("board.eeprom") == image  # nvm: refused before the device was written
    assert not Path("new.csv").exists()


def test_the_issue_case_names_the_config_store(here):
    """`batch poses.csv --config C --csv STORE --force`, C's store.path = STORE: the line says which store."""
    before = _sha(CONFIG)
    r = CliRunner().invoke(cli, ["batch", "poses.csv", "--config", "station.yaml", "--csv", CONFIG, "--force"])
    assert r.exit_code == 2 and _sha(CONFIG) == before
    assert "the same file as the store of --config station.yaml" in r.output, r.output


def test_a_store_not_yet_created_is_not_an_output_either(here):
    """The default store's name in the folder, before any run created it: a CSV written there would
    make every later `accelcal run` fail, so it is refused the same way."""
    Path(DEFAULT).unlink()
    r = CliRunner().invoke(cli, ["simulate", "--poses", "six-face", "--out", DEFAULT, "--force"])
    assert r.exit_code == 2 and "the default station's store" in r.output, r.output
    assert not Path(DEFAULT).exists()


def test_an_eeprom_image_is_never_a_store(here):
    """The board's EEPROM image (written on every page write) named as the config's store: refused."""
    cfg = yaml.safe_load(Path("station.yaml").read_text())
    cfg["device"]["eeprom"]["image"] = CONFIG
    Path("bad.yaml").write_text(yaml.safe_dump(cfg))
    before = _sha(CONFIG)
    r = CliRunner().invoke(cli, ["nvm", "erase", "--config", "bad.yaml", "--yes", "--backup-to", "b.json"])
    assert r.exit_code == 2 and _sha(CONFIG) == before, r.output
    assert not Path("b.json").exists()


def test_an_unrelated_database_is_still_replaced_with_force(here):
    """--force keeps its documented meaning for an SQLite file no store setting names."""
    _store(here / "scratch.db")
    r = CliRunner().invoke(cli, ["batch", "poses.csv", "--config", "station.yaml", "--csv", "scratch.db", "--force"])
    assert r.exit_code == 0, r.output
    assert Path("scratch.db").read_text().startswith("source,")

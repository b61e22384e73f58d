"""Issue 25: an output is never one of the command's inputs or the results store, by identity.

Each writing command is given, as its output, the very file it reads (or the store), named
four ways: the same name, ``./name``, ``sub/../name`` and a hard link.  Every time: exit 2, one
line naming both, and the input byte for byte as it was.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.lot.synthetic import write_lot
from accelcal_station.store.runs import Store

REPO = Path(__file__).resolve().parents[1]
ALIASES = ["same", "dot", "dotdot", "hardlink"]


def alias(name: str, how: str) -> str:
    """Another name for ``name`` (a file in the current directory)."""
    if how == "same":
        return name
    if how == "dot":
        return f"./{name}"
    if how == "dotdot":
        Path("sub").mkdir(exist_ok=True)
        return f"sub/../{name}"
    os.link(name, f"link-{name}")
    return f"link-{name}"


def refused(args: list[str], protected: str) -> None:
    before = Path(protected).read_bytes()
    r = CliRunner().invoke(cli, args)
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error")]
    assert r.exit_code == 2, r.output
    assert len(errors) == 1 and "the same file as" in errors[0] and "nothing written" in errors[0], r.output
    assert Path(protected).read_bytes() == before  # intact, byte for byte


@pytest.fixture()
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def sim_config(path: str = "station.yaml", **eeprom) -> str:
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": "runs.sqlite"}
    cfg["device"]["seed"] = 3
    cfg["device"]["eeprom"].update(eeprom)
    Path(path).write_text(yaml.safe_dump(cfg))
    return path


@pytest.mark.parametrize("how", ALIASES)
def test_fit_output_over_its_table(here, how):
    Path("t.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    refused(["fit", "t.csv", "-o", alias("t.csv", how)], "t.csv")


@pytest.mark.parametrize("how", ALIASES)
def test_batch_results_over_the_lot(here, how):
    write_lot("lot.csv", 5, seed=1)
    refused(["batch", "lot.csv", "--out", alias("lot.csv", how)], "lot.csv")


@pytest.mark.parametrize("how", ALIASES)
def test_batch_summary_csv_over_a_pose_table(here, how):
    Path("t.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    refused(["batch", "t.csv", "--csv", alias("t.csv", how)], "t.csv")


def test_batch_calibration_over_a_board_input(here):
    """--out-dir names a board's calibration for its table: a table named like that JSON stays."""
    Path("b1.json").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    refused(["batch", "b1.json", "--out-dir", "."], "b1.json")


@pytest.mark.parametrize("how", ALIASES)
@pytest.mark.parametrize("sub", [["export", "-o"], ["summary", "--html"], ["plot", "1", "-o"]])
def test_report_output_over_the_store(here, how, sub):
    with Store(here / "runs.sqlite"):
        pass  # an empty store, schema made
    refused(["report", *sub, alias("runs.sqlite", how), "--db", "runs.sqlite"], "runs.sqlite")


@pytest.mark.parametrize("how", ALIASES)
def test_report_output_over_its_config(here, how):
    cfg = sim_config()
    with Store(here / "runs.sqlite"):
        pass
    refused(["report", "export", "--config", cfg, "-o", alias(cfg, how)], cfg)


@pytest.mark.parametrize("how", ALIASES)
@pytest.mark.parametrize("flag", ["--out", "--truth-out"])
def test_simulate_output_over_its_config(here, how, flag):
    cfg = sim_config()
    other = ["--out", "s.csv"] if flag == "--truth-out" else []
    refused(["simulate", "--config", cfg, "--poses", "six-face", *other, flag, alias(cfg, how)], cfg)
    assert not Path("s.csv").exists()  # nothing written, not even the other output


def test_simulate_two_outputs_the_same_file(here):
    r = CliRunner().invoke(cli, ["simulate", "--poses", "six-face", "--out", "s.csv", "--truth-out", "./s.csv"])
    assert r.exit_code == 2 and "the same file as --out" in r.output and not Path("s.csv").exists()


@pytest.mark.parametrize("how", ALIASES)
def test_nvm_backup_over_its_config(here, how):
    cfg = sim_config()
    refused(["nvm", "backup", "--config", cfg, "--out", alias(cfg, how)], cfg)


@pytest.mark.parametrize("how", ALIASES)
def test_nvm_backup_over_the_boards_eeprom_image(here, how):
    cfg = sim_config(image="board.eeprom")
    Path("board.eeprom").write_bytes(b"\xff" * 4096)
    refused(["nvm", "backup", "--config", cfg, "--out", alias("board.eeprom", how)], "board.eeprom")


def test_nvm_restore_backup_over_the_image_it_restores(here):
    cfg = sim_config()
    assert CliRunner().invoke(cli, ["nvm", "backup", "--config", cfg, "--out", "img.json"]).exit_code == 0
    refused(["nvm", "restore", "img.json", "--config", cfg, "--backup-to", "./img.json"], "img.json")


def test_run_store_over_its_config(here):
    cfg = sim_config()
    refused(["run", "--config", cfg, "--store", f"./{cfg}"], cfg)


def test_a_new_output_beside_the_input_is_written(here):
    """The check compares files, not folders or names: a new file next to the input is fine."""
    Path("t.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    r = CliRunner().invoke(cli, ["fit", "t.csv", "-o", "./t.json"])
    assert r.exit_code == 0, r.output
    assert Path("t.json").read_text().startswith("{")

"""Issue 34: no output replaces a results store or a file of another kind.

A real 3-run store sits in the folder under its default name (accelcal-runs.sqlite) or
another one; every writing command is pointed at it and must exit 2 with one line, the
store's SHA-256 unchanged.  A calibration JSON where a CSV goes, a CSV where a JSON goes,
a database URL given as a file name: refused the same way; --force overrides the kind
check (never the identity check).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path
from accelcal_station.fileguard.kind import sniff
from accelcal_station.lot.synthetic import write_lot
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store

REPO = Path(__file__).resolve().parents[1]
REFS = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]


def _sha(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _store(path: Path) -> None:
    s = Session([PoseRecord(f"p{i}", np.array([4096.0 * a + 3, 4096.0 * b - 5, 4096.0 * c + 7]), np.full(3, 2.0),
                            100, np.array([a, b, c], float)) for i, (a, b, c) in enumerate(REFS)],
                "counts", 4096.0, device="SN")
    from accelcal_station.models.fitting import fit_session

    fit = fit_session(s, "12")
    with Store(path) as st:
        for i in range(3):
            rid = st.start_run(device_serial=f"SN{i}", lot="L", started_at=1.7e9 + i)
            st.finish_run(rid, session=s, calibration=fit.calibration, verdict="PASS", fit_summary={})


@pytest.fixture()
def here(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    Path("poses.csv").write_bytes((REPO / "examples" / "poses.csv").read_bytes())
    write_lot("lot.csv", 100, seed=1)
    _store(tmp_path / "source.sqlite")
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": "station-runs.sqlite"}
    cfg["device"]["seed"] = 3
    Path("station.yaml").write_text(yaml.safe_dump(cfg))
    return tmp_path


def _writers(target: str) -> list[list[str]]:
    """Every command that writes a file, its output given as ``target``."""
    src = ["--db", "source.sqlite"]
    return [
        ["fit", "poses.csv", "-o", target],
        ["fit", "poses.csv", "--hand-placed", "-o", target],
        ["simulate", "--poses", "six-face", "--out", target],
        ["simulate", "--poses", "six-face", "--raw", "--out", target],
        ["simulate", "--poses", "six-face", "--out", "new.csv", "--truth-out", target],
        ["simulate", "--poses", "six-face", "--lot", "3", "--out", target],
        ["batch", "poses.csv", "--csv", target],
        ["batch", "poses.csv", "--out-dir", target],
        ["batch", "lot.csv", "--out", target],
        ["batch", "--from-store", "source.sqlite", "--csv", target],
        ["twin", "fit", "lot.csv", "-o", target],
        ["twin", "fit", "--db", "source.sqlite", "-o", target],
        ["report", "export", *src, "-o", target],
        ["report", "export", *src, "--format", "json", "-o", target],
        ["report", "summary", *src, "--html", target],
        ["report", "plot", "1", *src, "-o", target],
        ["nvm", "backup", "--config", "station.yaml", "--out", target],
        ["diagnose", "poses.csv", "--report", target],
    ]


CASES = [(name, i) for name in ("accelcal-runs.sqlite", "other-name.db") for i in range(len(_writers("x")))]


@pytest.mark.parametrize(("name", "i"), CASES, ids=[f"{n}-{' '.join(_writers('T')[i][:2])}-{i}" for n, i in CASES])
def test_no_writer_replaces_a_store_in_the_folder(here, name, i):
    _store(here / name)
    before = _sha(name)
    args = _writers(name)[i]
    r = CliRunner().invoke(cli, args)
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error")]
    assert r.exit_code == 2, (args, r.output)
    assert len(errors) == 1, r.output
    assert _sha(name) == before
    assert not Path("new.csv").exists()  # nothing written, not even another output


@pytest.mark.parametrize("args", [["fit", "poses.csv", "-o", "the-store"],
                                  ["report", "export", "--db", "the-store", "-o", "the-store"],
                                  ["batch", "--from-store", "the-store", "--csv", "./the-store"]])
def test_the_store_a_command_reads_is_never_replaced_even_with_force(here, args):
    _store(here / "the-store")
    before = _sha("the-store")
    r = CliRunner().invoke(cli, [*args, "--force"] if args[0] != "report" else [*args[:2], "--force", *args[2:]])
    if args[0] == "fit":  # not an input of fit: --force replaces it as asked
        assert r.exit_code == 0 and sniff("the-store") == "json", r.output
    else:
        assert r.exit_code == 2 and "the same file as" in r.output and _sha("the-store") == before, r.output


@pytest.mark.parametrize("url", ["postgresql://station@localhost/line", "sqlite:///accelcal-runs.sqlite"])
@pytest.mark.parametrize("cmd", [["fit", "poses.csv", "-o"], ["batch", "poses.csv", "--csv"],
                                 ["simulate", "--poses", "six-face", "--out"]])
def test_a_database_url_is_not_a_file_name(here, url, cmd):
    r = CliRunner().invoke(cli, [*cmd, url])
    assert r.exit_code == 2 and "a database URL, not a file name" in r.output, r.output
    assert not Path("postgresql:").exists() and not Path("sqlite:").exists()


def _calibration_json() -> str:
    r = CliRunner().invoke(cli, ["fit", "poses.csv", "-o", "cal.json"])
    assert r.exit_code == 0, r.output
    return "cal.json"


@pytest.mark.parametrize(("make", "args"), [
    ("json", ["batch", "poses.csv", "--csv", "{t}"]),  # a calibration where a CSV goes
    ("json_text", ["simulate", "--poses", "six-face", "--out", "{t}"]),  # a .json name is refused by its name
    ("csv", ["fit", "poses.csv", "-o", "{t}"]),  # a pose table where a calibration goes
    ("csv", ["twin", "fit", "lot.csv", "-o", "{t}"]),  # a CSV where a YAML goes
    ("csv", ["report", "export", "--db", "source.sqlite", "--format", "json", "-o", "{t}"]),
    ("json", ["report", "summary", "--db", "source.sqlite", "--html", "{t}"]),
    ("csv", ["batch", "poses.csv", "--to-store", "{t}"]),  # a table is not a store
    ("csv", ["run", "--config", "station.yaml", "--store", "{t}"]),
])
def test_a_file_of_another_kind_is_refused_unless_forced(here, make, args):
    Path("table.csv").write_bytes(Path("poses.csv").read_bytes())
    target = _calibration_json() if make == "json" else "table.csv"
    if make == "json_text":  # a calibration's JSON under a name simulate may write (its content tells its kind)
        target = "calibration.txt"
        Path(target).write_bytes(Path(_calibration_json()).read_bytes())
    before = _sha(target)
    argv = [a.format(t=target) for a in args]
    r = CliRunner().invoke(cli, argv)
    assert r.exit_code == 2 and "of another kind" in r.output and _sha(target) == before, r.output
    if argv[0] in ("run",) or "--to-store" in argv:
        return  # a store target is never forced over another file
    assert "--force" in r.output
    r = CliRunner().invoke(cli, [*argv, "--force"])
    assert r.exit_code == 0, r.output
    assert _sha(target) != before


def test_an_output_of_the_same_kind_is_replaced(here):
    for _ in range(2):
        r = CliRunner().invoke(cli, ["batch", "poses.csv", "--csv", "summary.csv"])
        assert r.exit_code == 0, r.output
    _calibration_json()
    assert CliRunner().invoke(cli, ["fit", "poses.csv", "-o", "cal.json"]).exit_code == 0


@pytest.mark.parametrize(("head", "kind"), [
    (b"SQLite format 3\x00" + b"\x00" * 100, "sqlite"), (b"\x89PNG\r\n\x1a\n....", "png"),
    (b'{"model": "12"}', "json"), (b"  [1, 2]", "json"), (b"serial,pose,x\nA,1,2\n", "csv"),
    (b"# comment\nname,mean_x\n", "csv"), (b"# twin\ndevice:\n  seed: 3\n", "yaml"), (b"<!doctype html>", "html"),
    (b"just words\n", "text"), (b"\xff\xfe\x00a", "binary"), (b"", None),
    (b"serial,names\n" + "A,\u00e9\n".encode() * 2000, "csv")])  # a 2-byte character cut at 4 KiB: still text
def test_sniffed_kinds(tmp_path, head, kind):
    """The kind each head reads as, written here from the formats' own definitions."""
    p = tmp_path / "f"
    p.write_bytes(head)
    assert sniff(p) == kind


PG = "postgresql://station@localhost:5432/line"


@pytest.mark.parametrize("i", range(len(_writers(PG))), ids=[" ".join(a[:2]) + f"-{i}" for i, a in
                                                              enumerate(_writers(PG))])
def test_no_writer_takes_a_database_url_as_its_file(here, i):
    """A line database's URL where a file goes: refused (no file or folder named "postgresql:")."""
    before = sorted(p.name for p in here.iterdir())
    r = CliRunner().invoke(cli, _writers(PG)[i])
    assert r.exit_code == 2 and sum(ln.startswith("error") for ln in r.output.splitlines()) == 1, r.output
    assert sorted(p.name for p in here.iterdir()) == before

"""Issue 12, hostile inputs and the file system, through the command line: each is refused
in one line (or survived), nothing is half written, nothing is written through a symlink."""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import stat

import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.config.sections import default_config_path

# issue 53: no Python warning reaches the terminal: any warning raised here fails its test (-W error)
pytestmark = pytest.mark.filterwarnings("error")


def one_line_error(r, code=2):
    assert r.exit_code == code, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error") or "internal error" in ln]
    assert "Traceback" not in r.output and len(errors) == 1, r.output
    return errors[0]


def sim_cfg(tmp_path, mutate=None) -> str:
    cfg = yaml.safe_load(default_config_path().read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["device"]["seed"] = 7
    if mutate:
        mutate(cfg)
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))


@pytest.mark.parametrize("name,text,words", [
    ("bomb", BOMB, "alias bomb"),
    ("deep", "station: " + "[" * 1000 + "]" * 1000 + "\n", "nested more than 64 levels"),
    ("dup", "station: {id: a}\nstation: {id: b}\n", "duplicate key 'station'"),
])
def test_hostile_yaml_is_refused_fast_in_one_line(tmp_path, name, text, words):
    p = tmp_path / f"{name}.yaml"
    p.write_text(text)
    def expire(signum: int, frame: object) -> None:  # a hang guard, not a speed claim
        raise TimeoutError(f"{name}: run --config did not return within 10 s")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, 10.0)
    try:
        r = CliRunner().invoke(cli, ["run", "--config", str(p)])
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert words in one_line_error(r)


def test_a_50_mb_config_is_refused_by_its_size(tmp_path):
    p = tmp_path / "huge.yaml"
    with open(p, "wb") as f:
        f.truncate(50 * 1024 * 1024)  # sparse: never read
    assert "a configuration is at most" in one_line_error(CliRunner().invoke(cli, ["run", "--config", str(p)]))


@pytest.mark.parametrize("mutate,words", [
    (lambda c: c["capture"].update(max_s=0), "capture.max_s: 0"),
    (lambda c: c["device"]["eeprom"].update(image="no-such-folder/board.eeprom"), "does not exist"),
])
def test_bad_capture_and_image_settings_fail_before_any_pose(tmp_path, mutate, words):
    r = CliRunner().invoke(cli, ["run", "--config", sim_cfg(tmp_path, mutate)])
    assert words in one_line_error(r)
    assert not (tmp_path / "runs.sqlite").exists() or sqlite3.connect(tmp_path / "runs.sqlite").execute(
        "SELECT count(*) FROM runs WHERE status = 'running'").fetchone()[0] == 0


def _one_run(tmp_path) -> str:
    assert CliRunner().invoke(cli, ["run", "--config", sim_cfg(tmp_path)]).exit_code == 0
    return str(tmp_path / "runs.sqlite")


def test_a_damaged_row_is_shown_as_damaged_and_the_listing_goes_on(tmp_path):
    db = _one_run(tmp_path)
    assert CliRunner().invoke(cli, ["run", "--config", sim_cfg(tmp_path)]).exit_code == 0
    con = sqlite3.connect(db)
    con.execute("UPDATE runs SET fit_summary = '{not json', reasons = '[' WHERE id = 1")
    con.commit()
    r = CliRunner().invoke(cli, ["report", "list", "--db", db])
    assert r.exit_code == 0 and "DAMAGED (fit_summary, reasons unreadable)" in r.output and "2 run(s)" in r.output
    js = json.loads(CliRunner().invoke(cli, ["report", "list", "--db", db, "--json"]).stdout)
    assert js[0]["damaged"] == ["fit_summary", "reasons"] and "damaged" not in js[1]
    show = CliRunner().invoke(cli, ["report", "show", "1", "--db", db])
    assert show.exit_code == 0 and "DAMAGED" in show.output
    assert CliRunner().invoke(cli, ["report", "summary", "--db", db]).exit_code == 0


def test_a_damaged_store_page_is_one_line_naming_the_file(tmp_path):
    db = _one_run(tmp_path)
    size = os.path.getsize(db)
    with open(db, "r+b") as f:  # scribble over every page after the header page
        f.seek(4096)
        f.write(b"\xa5" * (size - 4096))
    r = CliRunner().invoke(cli, ["report", "list", "--db", db])
    assert r.exit_code not in (0, 70) and db in one_line_error(r, r.exit_code)


def test_readers_never_write_a_schema_into_a_file(tmp_path):
    empty = tmp_path / "empty.sqlite"
    empty.write_bytes(b"")
    r = CliRunner().invoke(cli, ["report", "list", "--db", str(empty)])
    assert "not an accelcal results store" in one_line_error(r)
    assert empty.read_bytes() == b""


def test_a_symlink_planted_at_the_image_tmp_is_not_followed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (tmp_path / "board.eeprom.tmp").symlink_to(victim)
    path = sim_cfg(tmp_path, lambda c: c["device"]["eeprom"].update(image="board.eeprom"))
    r = CliRunner().invoke(cli, ["run", "--config", path])
    assert r.exit_code == 0, r.output
    assert victim.read_text() == "precious\n" and os.path.getsize("board.eeprom") == 4096
    assert (tmp_path / "board.eeprom.tmp").is_symlink()  # left alone, never opened


def test_an_image_that_is_a_symlink_is_refused_up_front(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "victim.bin").write_bytes(b"x")
    (tmp_path / "board.eeprom").symlink_to(tmp_path / "victim.bin")
    path = sim_cfg(tmp_path, lambda c: c["device"]["eeprom"].update(image="board.eeprom"))
    assert "symbolic link" in one_line_error(CliRunner().invoke(cli, ["run", "--config", path]))
    assert (tmp_path / "victim.bin").read_bytes() == b"x"


@pytest.mark.parametrize("kind", ["fifo", "dir", "symlink"])
def test_output_paths_that_are_not_regular_files_are_refused(tmp_path, kind):
    db = _one_run(tmp_path)
    out = tmp_path / "out.csv"
    if kind == "fifo":
        os.mkfifo(out)
    elif kind == "dir":
        out.mkdir()
    else:
        (tmp_path / "victim.csv").write_text("keep\n")
        out.symlink_to(tmp_path / "victim.csv")
    r = CliRunner().invoke(cli, ["report", "export", "--db", db, "-o", str(out)])
    one_line_error(r, r.exit_code)
    assert r.exit_code != 0
    if kind == "fifo":
        assert stat.S_ISFIFO(os.lstat(out).st_mode)
    if kind == "symlink":
        assert out.is_symlink() and (tmp_path / "victim.csv").read_text() == "keep\n"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_an_overwritten_file_keeps_its_permissions(tmp_path):
    db = _one_run(tmp_path)
    out = tmp_path / "out.csv"
    out.write_text("old\n")
    out.chmod(0o600)
    assert CliRunner().invoke(cli, ["report", "export", "--db", db, "-o", str(out)]).exit_code == 0
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o600 and out.read_text().startswith("id,")


@pytest.mark.parametrize("folder", ["/", "/etc", "/usr/lib"])
def test_diagnose_report_refuses_system_folders(tmp_path, folder):
    pytest.importorskip("matplotlib")
    r = CliRunner().invoke(cli, ["diagnose", "x.csv", "--report", folder])
    assert "refusing a system folder" in one_line_error(r)


def test_terminal_escapes_in_pose_names_are_not_echoed_raw(tmp_path):
    lines = ["# units: g", "pose,ref_x,ref_y,ref_z,x,y,z"]
    faces = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    for i, f in enumerate(faces):
        name = "\x1b[2J\x1b]0;owned\x07" if i == 0 else f"p{i}"
        x = [1.01 * v + 0.01 * (k + 1) + 1e-4 * i for k, v in enumerate(f)]
        lines.append(f"{name},{f[0]},{f[1]},{f[2]},{x[0]},{x[1]},{x[2]}")
    p = tmp_path / "esc.csv"
    p.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(cli, ["fit", str(p), "--model", "6"])
    assert r.exit_code == 0, r.output
    assert "\x1b" not in r.output and "\x07" not in r.output and "\\x1b[2J" in r.output


def test_diagnose_summary_does_not_echo_escape_codes_in_pose_names(tmp_path):
    rows = ["0,0,1,0.01,0.02,1.01", "0,0,-1,0.0,0.01,-0.99", "1,0,0,1.02,0.0,0.01", "-1,0,0,-0.98,0.01,0.0",
            "0,1,0,0.0,1.01,0.02", "0,-1,0,0.01,-0.99,0.0"]
    p = tmp_path / "t.csv"
    p.write_text("# units: g\npose,ref_x,ref_y,ref_z,x,y,z\n"
                 + "".join(f"\x1b]0;owned\x07p{i},{r}\n" for i, r in enumerate(rows)))
    r = CliRunner().invoke(cli, ["diagnose", str(p)])
    assert r.exit_code != 70 and "Traceback" not in r.output
    assert "\x1b" not in r.output and "\x07" not in r.output and "\\x1b]0;owned\\x07p" in r.output


def test_batch_chunk_boards_outside_lot_mode_is_refused_not_ignored(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("# units: g\npose,ref_x,ref_y,ref_z,x,y,z\np1,0,0,1,0,0,1\n")
    r = CliRunner().invoke(cli, ["batch", str(p), "--chunk-boards", "x"])
    assert "--chunk-boards x: applies to lot file mode only" in one_line_error(r)

"""The station's event log (`logging:` in a station config): a real simulated run writes its run,
burn and port events to the file, each checked against what the store recorded; without the
section nothing new reaches the operator's terminal; a log file that is a symlink, the config or the
store is refused in one line before any work."""
from __future__ import annotations

import json
import logging
import re
import sqlite3
from pathlib import Path

import yaml
from click.testing import CliRunner
from test_port_faults import rig

from accelcal_station.cli import cli
from accelcal_station.config.schema import validate_device
from accelcal_station.drivers.mma8451 import MMA8451
from accelcal_station.drivers.mma8451_emulator import MMA8451Emulator
from accelcal_station.drivers.mma8451_registers import WHO_AM_I

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} (DEBUG|INFO|WARNING|ERROR) (accelcal_station[\w.]*): (.*)$")


def _config(tmp_path: Path, section: dict | None, base: str = "sim.yaml") -> Path:
    cfg = yaml.safe_load((CONFIGS / base).read_text())
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    if section is not None:
        cfg["logging"] = section
    p = tmp_path / "station.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def _events(log: Path) -> list[tuple[str, str, str]]:
    lines = log.read_text().splitlines()
    parsed = [LINE.match(ln) for ln in lines]
    assert all(parsed), [ln for ln, m in zip(lines, parsed, strict=True) if not m]
    return [m.groups() for m in parsed if m]


def _stored_run(tmp_path: Path) -> sqlite3.Row:
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    db.row_factory = sqlite3.Row
    return db.execute("SELECT * FROM runs").fetchone()


def test_a_simulated_run_logs_its_burn_as_the_store_recorded_it(tmp_path):
    log = tmp_path / "station.log"
    r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, {"level": "INFO", "file": str(log)})),
                                 "--serial", "SN-LOG-1", "--json"])
    assert r.exit_code == 0, r.output
    run = _stored_run(tmp_path)
    burn = json.loads(run["nvm_outcome"])
    events = _events(log)
    text = [f"{name}: {msg}" for _, name, msg in events]
    rid = run["id"]
    assert f"accelcal_station.store.runs: run {rid} started: board SN-LOG-1, station sim-station-1, lot None" in text
    assert (f"accelcal_station.nvm.writer: burning SN-LOG-1: slot {burn['slot']}, generation {burn['generation']}, "
            f"{burn['length']} bytes, CRC-32 {burn['crc32']:08x}") in text
    assert (f"accelcal_station.nvm.writer: burned SN-LOG-1: slot {burn['slot']}, generation {burn['generation']}, "
            "read back and verified") in text
    assert f"accelcal_station.store.runs: run {rid} complete: {run['verdict']}, NVM written" in text
    order = [m.split(":")[1].split()[0] for m in text]  # started, burning, burned, complete: in that order
    assert order.index("run") < order.index("burning") < order.index("burned")
    assert "burning" not in r.stderr and "burned" not in r.stderr  # the file has them, the terminal does not


def test_a_lost_jig_port_is_logged_as_an_error(tmp_path):
    bridge, port, jig, cfg = rig(tmp_path)
    log = tmp_path / "station.log"
    raw = yaml.safe_load(cfg.read_text()) | {"logging": {"level": "WARNING", "file": str(log)}}
    cfg.write_text(yaml.safe_dump(raw))
    jig.inject("disconnect", after=40)
    try:
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg), "--port", port, "--jig-port", jig.port, "--json"])
    finally:
        jig.stop()
        bridge.stop()
    assert r.exit_code == 3, r.output  # the station's fault (issue 49), not the board's FAIL
    events = _events(log)
    lost = [e for e in events if e[1] == "accelcal_station.fixtures.motorized_jig"]
    assert lost and lost[0][0] == "ERROR" and f"jig on {jig.port}" in lost[0][2] and "connection lost" in lost[0][2]
    assert all(level != "INFO" for level, _, _ in events), events  # level WARNING: no INFO lines
    assert "connection lost" in json.loads(r.stdout)["error"]
    assert any(level == "WARNING" and "station fault (jig)" in msg for level, _, msg in events), events


def test_without_a_logging_section_the_terminal_is_as_before(tmp_path):
    r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, None)), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["verdict"] == "PASS"
    assert not re.search(r"burning|burned|run \d+ (started|complete)", r.stderr), r.stderr
    assert not list(tmp_path.glob("*.log"))


def test_a_log_on_stderr_when_no_file_is_given(tmp_path):
    r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, {"level": "INFO"})), "--json"])
    assert r.exit_code == 0, r.output
    logged = [m.groups() for ln in r.stderr.splitlines() if (m := LINE.match(ln))]
    assert any(name == "accelcal_station.nvm.writer" and msg.startswith("burned ") for _, name, msg in logged), r.stderr
    assert json.loads(r.stdout)["verdict"] == "PASS"  # stdout stays the one JSON object


def test_a_log_file_that_is_a_symlink_the_config_or_the_store_is_refused(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("keep me\n")
    (tmp_path / "link.log").symlink_to(target)
    for file, why in ((tmp_path / "link.log", "symlink"), (tmp_path / "station.yaml", "station.yaml"),
                      (tmp_path / "runs.sqlite", "runs.sqlite")):
        cfg = _config(tmp_path, {"file": str(file)})
        r = CliRunner().invoke(cli, ["run", "--config", str(cfg)])
        assert r.exit_code == 2, r.output
        assert len(r.output.strip().splitlines()) == 1 and "logging.file" in r.output and why in r.output, r.output
    assert target.read_text() == "keep me\n"
    assert not (tmp_path / "runs.sqlite").exists()  # refused before the run started: no store written


def test_the_level_and_keys_are_checked(tmp_path):
    for bad in ({"level": "LOUD"}, {"file": 3}, {"rotate": True}):
        r = CliRunner().invoke(cli, ["run", "--config", str(_config(tmp_path, bad))])
        assert r.exit_code == 2 and "logging." in r.output and len(r.output.strip().splitlines()) == 1, r.output


def test_i2c_retries_are_logged_as_the_bus_nacked(caplog):
    """An MMA8451 driver on its register-level emulator (handed in as its SMBus): each NACK the
    emulator records is one INFO line naming bus, address and register, numbered."""
    emu = MMA8451Emulator.from_section(validate_device({"driver": "mma8451", "bus": "emulated", "seed": 7}), "device",
                                       eeprom_address=None)
    drv = MMA8451(emu, clock=emu.clock, bus_label="emulated")
    emu.nack_next(2, register=WHO_AM_I)  # within the driver's 3 retries
    with caplog.at_level(logging.INFO, logger="accelcal_station"), drv:
        pass
    tries = [r for r in caplog.records if r.name == "accelcal_station.drivers.mma8451"]
    assert len(tries) == emu.nack_log.count((0x1D, WHO_AM_I)) == 2
    pattern = re.compile(r"^read i2c bus emulated address 0x1d register 0x0D \(WHO_AM_I\): "
                         r".*Remote I/O error.* \(try (\d)\)$")
    matched = [pattern.match(r.getMessage()) for r in tries]
    assert all(matched) and [int(m.group(1)) for m in matched if m] == [1, 2], [r.getMessage() for r in tries]
    assert all(r.levelno == logging.INFO for r in tries)


def test_capture_retries_are_logged_as_the_store_counts_them(tmp_path):
    """The simulated hand bumps the board during pose p3's averaging: each discarded capture is one
    INFO line, as many as the retries the store records for the run's poses."""
    cfg = yaml.safe_load((CONFIGS / "sim.yaml").read_text())
    cfg["device"]["seed"] = 7  # the bump lands inside the averaging (tests/test_station.py)
    cfg["jig"] = {"type": "operator", "hand": {"bump": ["p3"], "bump_after_s": 1.5}}
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    cfg["logging"] = {"file": str(tmp_path / "station.log")}
    (tmp_path / "station.yaml").write_text(yaml.safe_dump(cfg))
    r = CliRunner().invoke(cli, ["run", "--config", str(tmp_path / "station.yaml")], input="\n" * 11)
    assert r.exit_code == 0, r.output
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    stored = db.execute("SELECT SUM(retries) FROM poses").fetchone()[0]
    retried = [m for lvl, name, m in _events(tmp_path / "station.log")
               if name == "accelcal_station.station.capture" and m.startswith("capture retried (")]
    assert stored >= 1 and len(retried) == stored, (stored, retried)
    assert all("moved during capture" in m for m in retried)

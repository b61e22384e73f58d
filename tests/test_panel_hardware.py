"""Panels through the real-chip code paths: 8 MMA8451 behind a TCA9548A emulator (smbus2 API), and
2 MPU6050 bridges on two pseudo-terminals with the motorized jig (pyserial)."""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.drivers.tca9548a import MuxChannel
from accelcal_station.errors import ConfigError
from accelcal_station.nvm.writer import CalibrationWriter
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def mux_config(tmp_path, boards=None) -> str:
    cfg = yaml.safe_load((CONFIGS / "panel-mma8451-emulated.yaml").read_text())
    if boards is not None:
        cfg["device"]["boards"] = boards
    cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
    p = tmp_path / "panel.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return str(p)


def test_eight_mma8451_behind_a_tca9548a_with_three_bad_boards(tmp_path):
    boards = [{"channel": ch} for ch in range(8)]
    boards[2]["emulator"] = {"present": False}  # nothing answers at 0x1d behind channel 2: NACK
    boards[4]["seated_deg"] = [180.0, 0.0, 0.0]  # seated upside down in its slot: wrong face
    boards[6]["simulator"] = {"effects": {"gain": {"gain": [1.09, 1.0, 1.0]}, "noise": {},
                                          "quantization": {}}}  # 9 % gain: beyond gain_error_max
    cfg = StationConfig.load(mux_config(tmp_path, boards))
    st = make_flow(cfg, echo=lambda s: None)
    reps = st.run()
    verdicts = [r.verdict for r in reps]
    # the board that never answers is the station's fault (issue 49: not judged, in no yield); the others
    # are judged: a wrong face and a gain beyond its limit FAIL
    assert verdicts == ["PASS", "PASS", "ERROR", "PASS", "FAIL", "PASS", "FAIL", "PASS"]
    fault = reps[2].station_fault
    assert fault.startswith("station fault (device): ") and "0x1d" in fault and reps[2].reasons == []
    assert "NACK" in fault or "Remote I/O" in fault
    assert len(reps[4].reasons) == 1 and "from the planned pose" in reps[4].reasons[0]
    assert any(r.startswith("gain_error_max") for r in reps[6].reasons)
    # every transaction of every board went through its mux channel on the one emulated bus
    drivers = [b.driver for b in st.boards]
    assert all(isinstance(d._bus_spec, MuxChannel) for d in drivers)
    mux = drivers[0]._bus_spec.mux.smbus
    assert {d._bus_spec.mux.smbus for d in drivers} == {mux} and mux.selects > 8
    # each passing board's own EEPROM (0x50 behind its channel) holds its own fit
    for b, rep in zip(st.boards, reps, strict=True):
        if rep.verdict == "PASS":
            assert rep.nvm_verified
            cal, _, _ = CalibrationWriter(b.driver.emulator.board.eeprom).read_newest(rep.serial)
            np.testing.assert_array_equal(cal.W, rep.calibration.W)
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    rows = db.execute("SELECT count(*), count(DISTINCT panel_id), sum(verdict = 'PASS'), "
                      "sum(nvm_status = 'written'), sum(status = 'error' AND verdict IS NULL) FROM runs").fetchone()
    assert rows == (8, 1, 5, 5, 1)


def test_mux_panel_cli_json_and_exit_status(tmp_path):
    boards = [{"channel": 0}, {"channel": 3, "emulator": {"present": False}}]
    r = CliRunner().invoke(cli, ["run", "--config", mux_config(tmp_path, boards), "--json"])
    assert r.exit_code == 3  # a board that does not answer is the station's fault (issue 49)
    out = json.loads(r.stdout)
    assert [b["verdict"] for b in out["boards"]] == ["PASS", "ERROR"] and out["panel_id"]


def test_two_boards_on_one_channel_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"device.boards\[1\].channel: 0 already holds a board"):
        make_flow(StationConfig.load(mux_config(tmp_path, [{"channel": 0}, {"channel": 0}])),
                  echo=lambda s: None).run()


def test_two_mpu6050_bridges_on_two_ptys_with_the_motorized_jig(tmp_path):
    from accelcal_station.drivers.mpu6050_emulator import MPU6050BridgeEmulator
    from accelcal_station.drivers.simulated import SimulatedBoard
    from accelcal_station.fixtures.jig_emulator import EmulatedAxes, JigEmulator
    from accelcal_station.fixtures.simulated_jig import FixtureBoards

    sim = yaml.safe_load((CONFIGS / "sim.yaml").read_text())["device"]["simulator"]
    boards = [SimulatedBoard.from_config(sim, chip="mpu6050", seed=s) for s in (3, 4)]
    # the second board is 9 % too sensitive on x: beyond gain_error_max, it alone fails
    boards[1].model.effects["gain"]["gain"] = np.array([1.09, 0.987, 1.021])
    bridges = [MPU6050BridgeEmulator(b) for b in boards]
    ports = [br.start() for br in bridges]
    jig = JigEmulator(EmulatedAxes(speed_deg_s=4000, accel_deg_s2=1e5),
                      board=FixtureBoards(boards, [br.lock for br in bridges]))
    jig.start()
    try:
        cfg = yaml.safe_load((CONFIGS / "mpu6050.yaml").read_text())
        cfg["store"] = {"path": str(tmp_path / "runs.sqlite")}
        cfg["jig"].update(port=jig.port, settle_s=0.0, speed_deg_s=4000, accel_deg_s2=1e5)
        cfg["device"]["boards"] = [{"port": ports[0]}, {"port": ports[1]}]
        p = tmp_path / "mpu.yaml"
        p.write_text(yaml.safe_dump(cfg))
        r = CliRunner().invoke(cli, ["run", "--config", str(p), "--json"])
        assert r.exit_code == 1, r.output
        out = json.loads(r.stdout)
        a, b = out["boards"]
        assert a["verdict"] == "PASS" and a["nvm_verified"] and a["chip"] == "mpu6050"
        assert b["verdict"] == "FAIL" and any(x.startswith("gain_error_max") for x in b["reasons"])
        assert sum(c.startswith("MOVE") for c in jig.received) >= 8  # one jig moved both boards
        cal, _, _ = CalibrationWriter(bridges[0].nvm).read_newest(a["serial"])
        np.testing.assert_allclose(cal.W, a["W"], rtol=0, atol=0)
        assert CalibrationWriter(bridges[1].nvm).read_newest(b["serial"]) is None  # a failed board is never written
        db = sqlite3.connect(tmp_path / "runs.sqlite")
        assert db.execute("SELECT count(*), count(DISTINCT panel_id) FROM runs").fetchone() == (2, 1)
    finally:
        jig.stop()
        for br in bridges:
            br.stop()


def test_a_mux_that_resets_mid_run_is_reselected_and_recorded(tmp_path):
    """TCA9548A data sheet: power-on / RESET leaves no channel selected.  Board 3's mux resets after
    its 40th transaction (mid-run, every channel dropped); the driver sees the NACK, reads the control
    register (0x00), selects its channel again and retries once; every board still PASSes and the
    board that hit it records the re-selection."""
    boards = [{"channel": ch} for ch in range(4)]
    boards[3]["emulator"] = {"mux_reset_after": 40}
    cfg = StationConfig.load(mux_config(tmp_path, boards))
    st = make_flow(cfg, echo=lambda s: None)
    reps = st.run()
    assert [r.verdict for r in reps] == ["PASS"] * 4, [r.reasons for r in reps]
    mux = st.boards[0].driver._bus_spec.mux.smbus
    assert mux.resets == 1
    hit = [r for r in reps if any("had lost channel" in e for e in r.events)]
    assert len(hit) == 1 and "re-selected" in next(e for e in hit[0].events if "lost channel" in e)
    db = sqlite3.connect(tmp_path / "runs.sqlite")
    assert db.execute("SELECT count(*) FROM runs WHERE verdict = 'PASS'").fetchone() == (4,)



def test_mux_channel_reselects_only_when_the_mux_forgot_its_channel():
    """Through smbus2's API on the register-level TCA9548A emulator: after a mux reset the next
    transaction NACKs, the channel reads deselected (control 0x00), is selected again and the
    transaction retried once; a NACK of the device itself (nothing at the address) is not retried
    through the mux and reaches the driver as the bus error it is."""
    from accelcal_station.drivers.mma8451_emulator import MMA8451Emulator
    from accelcal_station.drivers.simulated import SimulatedBoard
    from accelcal_station.drivers.tca9548a import MuxBus
    from accelcal_station.drivers.tca9548a_emulator import TCA9548AEmulator

    emu = TCA9548AEmulator(0x70)
    emu.attach(1, MMA8451Emulator(SimulatedBoard.from_config(None, chip="mma8451", seed=1)))
    bus = MuxBus(emu, 0x70, "emulated")
    ch = MuxChannel(bus, 1)
    who = ch.read_byte_data(0x1D, 0x0D)  # WHO_AM_I
    emu.reset()
    assert emu.control == 0
    assert ch.read_byte_data(0x1D, 0x0D) == who and emu.control == 0b10 and emu.resets == 1
    assert len(ch.take_events()) == 1 and ch.take_events() == []
    selects = emu.selects
    with pytest.raises(OSError):
        ch.read_byte_data(0x1E, 0x0D)  # nothing at 0x1e: the device's NACK, the mux still selects 1
    assert emu.selects == selects and ch.take_events() == []

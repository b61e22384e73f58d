"""Declared capabilities: what a driver, a jig, a clock or an instrument can do is declared on its
base class, the station asks through those (never by probing attributes), real drivers carry
nothing of emulation, and the chamber's VISA backend comes from the config."""
from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

from accelcal_station.config.schema import validate_chamber, validate_device
from accelcal_station.drivers.base import Driver
from accelcal_station.drivers.factory import make_driver
from accelcal_station.drivers.mma8451 import MMA8451
from accelcal_station.drivers.mpu6050 import MPU6050Bridge
from accelcal_station.drivers.simulated import VirtualClock
from accelcal_station.errors import AccelcalError, DeviceError, NVMError, PortLostError
from accelcal_station.fixtures.base import Jig
from accelcal_station.fixtures.factory import board_of, clock_of
from accelcal_station.fixtures.motorized_jig import MotorizedJig
from accelcal_station.fixtures.operator_jig import OperatorJig
from accelcal_station.instruments.chamber import AsciiChamber, ChamberError
from accelcal_station.instruments.chamber_emulator import ChamberEmulator, ChamberPhysics
from accelcal_station.instruments.factory import make_chamber

PKG = Path(__file__).resolve().parents[1] / "accelcal_station"


def _probes(path: Path) -> list[str]:
    """getattr/hasattr calls naming an attribute (a capability probed, not declared), and isinstance
    checks against a jig class."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Name):
            continue
        args = node.args
        if node.func.id in ("getattr", "hasattr") and len(args) >= 2 and isinstance(args[1], ast.Constant):
            out.append(f"{path.name}:{node.lineno} {node.func.id}(..., {args[1].value!r})")
        if node.func.id == "isinstance" and len(args) == 2 and ast.unparse(args[1]).endswith("Jig"):
            out.append(f"{path.name}:{node.lineno} isinstance(..., {ast.unparse(args[1])})")
    return out


def test_the_station_and_the_jig_factory_ask_declared_capabilities_not_probe(tmp_path: Path) -> None:
    # fixtures/ and drivers/ sit at the top of the repository (installed as accelcal_station.fixtures, ...)
    files = [*sorted((PKG / "station").glob("*.py")), PKG.parent / "fixtures" / "factory.py",
             *sorted((PKG / "instruments").glob("*.py")), PKG.parent / "drivers" / "factory.py"]
    found = [p for f in files for p in _probes(f)]
    assert not found, found
    # the scan itself finds probes when there are some
    example = tmp_path / "example.py"
    example.write_text("w = getattr(jig, 'wait_s', 0.0)\nok = hasattr(d, 'set_offset_trim')\n"
                       "op = isinstance(jig, OperatorJig)\n")
    assert len(_probes(example)) == 3


def test_real_drivers_carry_no_emulator() -> None:
    """The MMA8451 and MPU6050 drivers have no emulator attribute, parameter or branch: the
    factory hands the emulated bus (MMA8451) in or starts the emulated bridge around the port
    (drivers/emulated.py), as python-can's virtual bus."""
    for cls in (MMA8451, MPU6050Bridge):
        src = inspect.getsource(cls)
        assert "emulator" not in inspect.signature(cls.__init__).parameters
        assert "self.emulator" not in src, cls.__name__
    with make_driver(validate_device({"driver": "mma8451", "bus": "emulated", "seed": 3})) as d:
        assert type(d) is not MMA8451 and isinstance(d, MMA8451)  # the real driver code, emulated bus beside it
        assert d.board is not None and board_of(d) is d.board and clock_of(d) is d.board.clock
    with make_driver(validate_device({"driver": "mpu6050", "port": "emulated", "seed": 3, "timeout_s": 0.3})) as d:
        assert isinstance(d, MPU6050Bridge) and d.board is not None
        assert d.board.chip.name == "mpu6050"


def test_capabilities_are_declared_on_the_base_classes() -> None:
    assert Driver.supports_offset_trim is False and Driver.board is None
    assert MMA8451.supports_offset_trim is True and MMA8451.offset_trim_lsb_g == pytest.approx(1 / 512)
    assert MPU6050Bridge.supports_offset_trim is False
    with make_driver(validate_device({"driver": "simulated", "seed": 1})) as sim, \
            pytest.raises(DeviceError, match="no offset-trim"):
        sim.set_offset_trim((0, 0, 0))
    assert (Jig.shows_live_reading, Jig.places_again, Jig.wait_s) == (False, False, 0.0)
    assert OperatorJig.shows_live_reading and OperatorJig.places_again
    assert not MotorizedJig.places_again and not MotorizedJig.shows_live_reading
    # the typed reason a run records when an error ends it
    assert (AccelcalError.reason_code, DeviceError.reason_code, PortLostError.reason_code,
            NVMError.reason_code) == ("device", "device", "port_lost", "nvm")
    assert VirtualClock().realtime is False and VirtualClock(realtime=True).realtime is True


def test_the_chamber_opens_through_the_visa_backend_its_config_names(tmp_path: Path) -> None:
    """chamber.visa_library reaches pyvisa's ResourceManager: the default @py talks to the emulated
    chamber; a vendor library that is not there is refused by pyvisa, one ChamberError line."""
    clock = VirtualClock()
    emu = ChamberEmulator(ChamberPhysics(clock, start_c=25.0))
    port = emu.start()
    try:
        with make_chamber(validate_chamber({"port": port, "timeout_s": 0.5})) as ch:
            assert isinstance(ch, AsciiChamber)
            assert ch.visa_library == "@py"
            assert ch.status().air_c == pytest.approx(25.0, abs=0.1)
        missing = tmp_path / "libvendorvisa.so"
        ch = make_chamber(validate_chamber({"type": "visa", "port": port, "timeout_s": 0.5,
                                            "visa_library": str(missing)}))
        assert isinstance(ch, AsciiChamber)
        assert ch.visa_library == str(missing)
        with pytest.raises(ChamberError, match="cannot open"):
            ch.open()
    finally:
        emu.stop()

"""Drivers found through a registry (drivers/registry.py): the entry-point group ``accelcal.drivers``
names each driver's factory, so a new chip is a module plus one entry point (docs/architecture.md,
"Adding a chip"); ``make_driver`` looks the section's ``driver`` up there, ``NAME-emulated`` when the
section asks for an emulated bus or port."""
from __future__ import annotations

import inspect
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from accelcal_station.config.schema import DEVICE_MODELS, validate_device
from accelcal_station.drivers import registry
from accelcal_station.drivers.emulated import EmulatedMMA8451, EmulatedMPU6050Bridge
from accelcal_station.drivers.factory import make_driver
from accelcal_station.drivers.simulated import SimulatedDriver
from accelcal_station.errors import ConfigError

BUILT_IN = {"simulated", "mma8451", "mpu6050", "mma8451-emulated", "mpu6050-emulated"}


def test_the_entry_point_group_lists_the_built_in_drivers():
    names = {ep.name for ep in entry_points(group="accelcal.drivers")}
    assert {"mma8451", "mpu6050", "simulated"} <= names
    assert names >= BUILT_IN
    # one schema model per registered chip (config declares the device union; the registry builds)
    assert {n for n in BUILT_IN if not n.endswith("-emulated")} == set(DEVICE_MODELS)


def test_each_factory_takes_the_declared_arguments():
    """DriverFactory: (device, path, buses) -> Driver."""
    for ep in entry_points(group="accelcal.drivers"):
        if ep.name in BUILT_IN:
            factory = ep.load()
            assert list(inspect.signature(factory).parameters) == ["device", "path", "buses"], ep.name


@pytest.mark.parametrize("section, kind", [
    ({"driver": "simulated", "seed": 1}, SimulatedDriver),
    ({"driver": "mma8451", "bus": "emulated", "seed": 1}, EmulatedMMA8451),
    ({"driver": "mpu6050", "port": "emulated", "seed": 1}, EmulatedMPU6050Bridge),
])
def test_make_driver_builds_through_the_registry(section, kind):
    d = make_driver(validate_device(section))
    assert type(d) is kind


def test_a_name_not_registered_is_one_line_naming_those_that_are():
    with pytest.raises(ConfigError) as e:
        registry.driver_factory("lis3dh", "device.driver")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("device.driver: no driver 'lis3dh'")
    assert "mma8451, mma8451-emulated, mpu6050, mpu6050-emulated, simulated" in msg


def test_a_chip_from_another_distribution_is_found_by_its_entry_point(tmp_path: Path, monkeypatch):
    """A third-party distribution (its module and its dist-info on sys.path, as pip installs it) adds
    a driver without an edit to this package."""
    (tmp_path / "demo_chip.py").write_text(
        "from accelcal_station.config.kinds import SimulatedDevice\n"
        "from accelcal_station.drivers.builtin import build_simulated\n"
        "from accelcal_station.drivers.registry import declares\n\n"
        "@declares(SimulatedDevice)\n"
        "def build(device, path, buses):\n    return build_simulated(device, path, buses)\n")
    info = tmp_path / "demo_chip-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: demo-chip\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[accelcal.drivers]\ndemo = demo_chip:build\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    try:
        assert "demo" in registry.driver_names()
        d = registry.driver_factory("demo")(validate_device({"driver": "simulated", "seed": 2}), "device", {})
        assert isinstance(d, SimulatedDriver)
    finally:
        monkeypatch.undo()
        sys.modules.pop("demo_chip", None)
        registry.refresh()
    assert "demo" not in registry.driver_names()


DEMO_CHIP = '''\
"""A third party's chip: a module and one entry point (docs/drivers.md, "Adding a chip")."""
from typing import Literal

from pydantic import Field

from accelcal_station.config.kinds import DeviceKeys, SimulatedBoardSection
from accelcal_station.drivers.registry import declares
from accelcal_station.drivers.simulated import SimulatedBoard, SimulatedDriver


class DemoDevice(DeviceKeys, SimulatedBoardSection):
    driver: Literal["demo"] = Field(..., description="the driver: demo")
    gain_code: int = Field(1, ge=0, le=7, description="the demo chip's gain register")
    boards: int | None = Field(None, ge=1, le=8, description="panel: a count")


@declares(DemoDevice)
def build(device, path, buses):
    return SimulatedDriver(SimulatedBoard.from_section(device, path=path))
'''

PROBE = '''\
import json
from accelcal_station.config.schema import DEVICE_MODELS, validate_device
from accelcal_station.drivers.factory import make_driver
from accelcal_station.errors import ConfigError

out = {"models": {k: m.__name__ for k, m in DEVICE_MODELS.items()}}
d = validate_device({"driver": "demo", "gain_code": 5, "seed": 3, "mount": ["y", "-x", "z"]})
out["validated"] = [type(d).__name__, d.gain_code, d.mount]
out["driver"] = type(make_driver(d)).__name__
errors = []
for bad in ({"driver": "demo", "gain_code": 9}, {"driver": "demo", "address": 29}, {"driver": "lis3dh"}):
    try:
        validate_device(bad)
    except ConfigError as e:
        errors.append(str(e))
out["errors"] = errors
print(json.dumps(out))
'''


def _demo_distribution(root: Path) -> dict[str, str]:
    """A distribution as pip leaves it (its module and its dist-info with a real entry point) in a folder
    on a fresh interpreter's path; the environment that puts it there."""
    import os

    (root / "demo_chip.py").write_text(DEMO_CHIP)
    info = root / "demo_chip-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: demo-chip\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[accelcal.drivers]\ndemo = demo_chip:build\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}


def test_a_third_party_chip_is_a_member_of_the_schemas_device_union(tmp_path: Path):
    """Issue 52: the config schema's ``device`` union is built from the registry: a chip from another
    distribution (a module plus one entry point declaring its model) is validated by the one validation,
    its own keys and ranges and the station's keys, in a fresh interpreter that found its entry point."""
    import json
    import subprocess

    env = _demo_distribution(tmp_path)
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["models"] == {"simulated": "SimulatedDevice", "demo": "DemoDevice", "mma8451": "Mma8451Device",
                             "mpu6050": "Mpu6050Device"}
    assert out["validated"] == ["DemoDevice", 5, ["y", "-x", "z"]]
    assert out["driver"] == "SimulatedDriver"
    gain, unknown, other = out["errors"]
    assert gain == "device.gain_code: 9 out of range; allowed: 0 to 7"
    allowed = unknown.removeprefix("device.address: unknown key; allowed: ").split(", ")
    assert {"driver", "gain_code", "mount", "boards", "seed"} <= set(allowed) and "address" not in allowed, unknown
    assert other == "device.driver: 'lis3dh'; allowed: simulated, demo, mma8451, mpu6050"
    # without the distribution, the same probe knows no demo driver
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "device.driver: 'demo'; allowed: simulated, mma8451, mpu6050" in r.stderr


def test_an_entry_that_declares_no_model_is_one_line(tmp_path: Path):
    """A factory without its ``config`` model cannot join the union: a command that reads a config says
    which entry point and what it must declare, in one line, exit 2."""
    import subprocess

    env = _demo_distribution(tmp_path)
    (tmp_path / "demo_chip.py").write_text("def build(device, path, buses):\n    raise AssertionError\n")
    (tmp_path / "x.yaml").write_text("device: {driver: simulated}\n")
    r = subprocess.run([sys.executable, "-m", "accelcal_station", "probe", "--config", "x.yaml"],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.strip().splitlines() == [
        "error: accelcal.drivers entry point 'demo': declares no device model; allowed: a factory whose "
        "'config' is a pydantic model subclassing accelcal_station.config.kinds.DeviceKeys with a 'boards' key"]

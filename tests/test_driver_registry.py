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

from accelcal_station.config.kinds import DEVICE_MODELS
from accelcal_station.config.schema import validate_device
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
        "from accelcal_station.drivers.builtin import build_simulated\n\n"
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

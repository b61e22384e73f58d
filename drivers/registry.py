"""The driver registry: the entry-point group ``accelcal.drivers`` maps a name to a factory (python-can's
interface registry in spirit), so a new chip is a new module plus one entry point.

A name is a ``device.driver`` value (``simulated``, ``mma8451``, ``mpu6050``); ``NAME-emulated`` is the
same driver on an emulated bus or port, chosen when the section says ``bus: emulated`` or ``port:
emulated``, so a driver never imports its emulator (the registry loads the emulated factory by name).
Each factory is a :class:`DriverFactory`: the validated device section, its key path for error lines and
the panel's shared multiplexed buses in, a :class:`~.base.Driver` out; and it declares its section's
pydantic model (``config``), from which config/schema.py builds the ``device`` union (config/driver_models.py).
``@declares(Model)`` on a build function makes it one.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from ..config.driver_models import EMULATED, GROUP, driver_entries
from ..errors import ConfigError
from .base import Driver

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

    from ..config.section import Section
    from .tca9548a import MuxBuses

__all__ = ["EMULATED", "GROUP", "DriverFactory", "declares", "driver_factory", "driver_names", "refresh"]


class DriverFactory(Protocol):
    """What an ``accelcal.drivers`` entry point names: build the driver of a validated ``device`` section,
    and declare that section's pydantic model (``config``: a config.kinds.DeviceKeys with ``driver:
    Literal["NAME"]``)."""

    config: type[Section]

    def __call__(self, device: Section, path: str, buses: MuxBuses) -> Driver: ...


Build = Callable[["Section", str, "MuxBuses"], Driver]


@dataclass(frozen=True)
class Declared:
    """A build function with the device model it declares: a :class:`DriverFactory`."""

    config: type[Section]
    build: Build

    def __call__(self, device: Section, path: str, buses: MuxBuses) -> Driver:
        return self.build(device, path, buses)


def declares(config: type[Section]) -> Callable[[Build], Declared]:
    """``@declares(Model)`` on ``build(device, path, buses)``: the factory an entry point names, with the
    ``device`` model the config schema's union takes from it."""
    def wrap(build: Build) -> Declared:
        return Declared(config, build)
    return wrap


def _entries() -> dict[str, EntryPoint]:
    return driver_entries()


def driver_names() -> tuple[str, ...]:
    """Every registered name, emulated variants included, sorted."""
    return tuple(sorted(_entries()))


def driver_factory(name: str, path: str = "device.driver") -> DriverFactory:
    """The factory registered as ``name``; a name not registered is a one-line ConfigError naming those that are."""
    entry = _entries().get(name)
    if entry is None:
        raise ConfigError(f"{path}: no driver {name!r} in the {GROUP} entry points; allowed: "
                          f"{', '.join(driver_names()) or 'none (is accelcal-station installed?)'}")
    factory: DriverFactory = entry.load()
    return factory


def refresh() -> None:
    """Read the entry points again (after a distribution was installed in this process; the schema's
    ``device`` union was built when it was first imported and keeps its members)."""
    driver_entries.cache_clear()

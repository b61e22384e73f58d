"""The driver registry: the entry-point group ``accelcal.drivers`` maps a name to a factory (python-can's
interface registry in spirit), so a new chip is a new module plus one entry point.

A name is a ``device.driver`` value (``simulated``, ``mma8451``, ``mpu6050``); ``NAME-emulated`` is the
same driver on an emulated bus or port, chosen when the section says ``bus: emulated`` or ``port:
emulated``, so a driver never imports its emulator (the registry loads the emulated factory by name).
Each factory is a :class:`DriverFactory`: the validated device section, its key path for error lines and
the panel's shared multiplexed buses in, a :class:`~.base.Driver` out.
"""
from __future__ import annotations

from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Protocol

from ..errors import ConfigError
from .base import Driver

if TYPE_CHECKING:
    from ..config.section import Section
    from .tca9548a import MuxBuses

GROUP = "accelcal.drivers"
EMULATED = "-emulated"


class DriverFactory(Protocol):
    """What an ``accelcal.drivers`` entry point names: build the driver of a validated ``device`` section."""

    def __call__(self, device: Section, path: str, buses: MuxBuses) -> Driver: ...


@cache
def _entries() -> dict[str, EntryPoint]:
    """The group's entry points by name, read once per process (a scan of every installed
    distribution's metadata costs ~0.1 s)."""
    return {ep.name: ep for ep in entry_points(group=GROUP)}


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
    """Read the entry points again (after a distribution was installed in this process)."""
    _entries.cache_clear()

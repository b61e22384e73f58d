"""The device models the driver registry declares: each ``accelcal.drivers`` entry point names a factory
that carries its ``device`` section's pydantic model (``config``), and the schema's ``device`` union
(schema.py) is built from them, discriminated on ``driver``, so a new chip is a module plus one entry point.

The entry points are read here, once per process (drivers/registry.py reads this same scan): config sits
below the drivers, so it never imports them by name; loading an entry point imports its module when the
schema is first built. ``NAME-emulated`` entries are the same driver on an emulated bus or port and
declare the same model; the union holds one member per ``device.driver`` value.
"""
from __future__ import annotations

from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Literal, Protocol, get_args, get_origin

from ..errors import ConfigError
from .section import Section

GROUP = "accelcal.drivers"
EMULATED = "-emulated"


class DeclaresConfig(Protocol):
    """What config reads of an ``accelcal.drivers`` entry: the pydantic model of its ``device`` section (a
    :class:`~.kinds.DeviceKeys` with ``driver: Literal["NAME"]``)."""

    config: type[Section]


@cache
def driver_entries() -> dict[str, EntryPoint]:
    """The group's entry points by name, read once per process (a scan of every installed distribution's
    metadata costs ~0.1 s)."""
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def declared_model(name: str, entry: object) -> type[Section]:
    """The device model an entry declares, checked against the declared interface: a DeviceKeys model
    whose ``driver`` is exactly ``name`` (ConfigError: one line naming the entry and what is allowed)."""
    from .kinds import _PanelKeys, _SlotKeys

    model: Any = getattr(entry, "config", None)
    where = f"{GROUP} entry point {name!r}"
    # DeviceKeys or a built-in model: the station's keys (mount, spread, ...), boards and emulated
    if not (isinstance(model, type) and issubclass(model, _SlotKeys) and issubclass(model, _PanelKeys)
            and "boards" in model.model_fields and hasattr(model, "emulated")):
        raise ConfigError(f"{where}: declares no device model; allowed: a factory whose 'config' is a "
                          "pydantic model subclassing accelcal_station.config.kinds.DeviceKeys with a 'boards' key")
    field = model.model_fields.get("driver")
    ann = None if field is None else field.annotation
    if get_origin(ann) is not Literal or get_args(ann) != (name,):
        raise ConfigError(f"{where}: {model.__name__}.driver must be Literal[{name!r}] (the value that picks it)")
    return model


def device_models() -> dict[str, type[Section]]:
    """``device.driver`` value -> its section model, from the registry (emulated variants folded into their
    driver), sorted by name with ``simulated`` (the default) first."""
    found = {name: declared_model(name, ep.load()) for name, ep in driver_entries().items()
             if not name.endswith(EMULATED)}
    if not found:  # a source tree run without its metadata (never pip-installed): the built-in drivers
        from .kinds import BUILT_IN_DEVICES

        found = dict(BUILT_IN_DEVICES)
    return dict(sorted(found.items(), key=lambda kv: (kv[0] != "simulated", kv[0])))

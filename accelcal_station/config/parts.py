"""``parse``: a mapping checked against a section model (one ConfigError line), for the parts
that are still handed mappings (a command's own device file, a test, a simulator file); and
the small sections those parts check on their own (a seed, a mux channel, a simulator file).

The driver and jig models themselves live in schema.py, where the station schema's
discriminated unions (``device.driver``, ``jig.type``) use them: a station config is checked
once, each driver's and jig type's keys included.  They are re-exported here for the parts'
own imports.
"""
from __future__ import annotations

from typing import Any, Literal, TypeVar

from pydantic import BaseModel

from .schema import (  # noqa: F401 - re-exported: the drivers' and jigs' own models
    BridgeEmulatorSection,
    I2cEepromSection,
    Mma8451Section,
    MotorizedJigSection,
    Mpu6050Section,
    OperatorJigSection,
    Section,
    SimEepromSection,
    SimulatedBoardSection,
    SimulatedJigSection,
    _f,
    validate,
)

M = TypeVar("M", bound=BaseModel)


def parse(data: Any, model: type[M], where: str) -> M:
    """``data`` (None: an empty mapping) checked against ``model``: ConfigError, one line."""
    return validate({} if data is None else data, model, where)  # type: ignore[return-value]


class SimulatorFileSection(Section):
    """A simulator file or mapping: ``{effects: ...}``."""

    effects: dict[str, Any] | None = _f(None, "effects of the catalog (sim/sensor_model.py EFFECTS)")
    population: dict[str, Any] | None = _f(None, "the population boards are drawn from (sim/population.py)")
    physics: Literal["implicit", "forward"] = _f("implicit", "the cubic's physics (sim/sensor_model.py PHYSICS)")


class Mpu6050SimSection(Section):
    """The ``simulator``, ``seed`` and ``emulator`` of an emulated mpu6050 (other device keys are ignored)."""

    simulator: dict[str, Any] | str | None = None
    seed: int | None = _f(None, "random seed", ge=0, le=2**32 - 1)
    emulator: BridgeEmulatorSection | None = None


class EmulatedSeedSection(Section):
    """An emulated chip's seed."""

    seed: int | None = _f(None, "random seed", ge=0, le=2**63 - 1)


class MuxChannelSection(Section):
    """A board behind a TCA9548A: its channel."""

    channel: int = _f(..., "multiplexer channel; required behind a mux", ge=0, le=7)


class PanelSeedSection(Section):
    """A simulated panel's seed: board i draws from seed * 1000 + i."""

    seed: int = _f(1, "panel seed", ge=0, le=2**32 - 1)



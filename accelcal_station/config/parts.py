"""``parse``: a mapping checked against a section model (one ConfigError line), for the inputs
that are not a station config (a simulator file, a board mapping of a test or a benchmark, a
lot's store location).

The driver and jig models themselves live in kinds.py and schema.py, where the station schema's
discriminated unions (``device.driver``, ``jig.type``, ``chamber.type``) use them: a station config
is checked once, each driver's and jig type's keys included, and the factories take those typed
sections (drivers/factory.py, fixtures/factory.py, instruments/factory.py).
"""
from __future__ import annotations

from typing import Any, TypeVar

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

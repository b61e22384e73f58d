"""What a flow is given besides its config (``flow.make_flow``'s keywords, issue 52): who runs it and
for what (operator, serial, lot, panel), how the station speaks (echo, progress, the operator's
front end) and the hardware handed in rather than built from the config (the boards' drivers, a jig)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

from ..drivers.base import Driver
from ..fixtures.base import Jig
from ..fixtures.operator_ui import OperatorUI


class FlowOptions(TypedDict, total=False):
    """``make_flow``'s keywords (PEP 692), each optional; ``FlowSetup`` holds them with their defaults."""

    operator: str | None
    serial: str | None
    lot: str | None
    echo: Callable[[str], None]
    progress: Callable[[str, float], None] | None
    drivers: list[Driver] | None
    driver: Driver | None
    panel_id: str | None
    jig: Jig | None
    ui: OperatorUI | None


@dataclass(frozen=True)
class FlowSetup:
    """A flow's options (``FlowOptions``) with their defaults: ``serial`` overrides the one the device
    reports; ``driver`` is a single board's driver (``drivers`` a panel's); ``ui`` is the operator's
    front end (terminal or browser), for an operator jig."""

    operator: str | None = None
    serial: str | None = None
    lot: str | None = None
    echo: Callable[[str], None] = print
    progress: Callable[[str, float], None] | None = None
    drivers: list[Driver] | None = None
    driver: Driver | None = None
    panel_id: str | None = None
    jig: Jig | None = None
    ui: OperatorUI | None = None

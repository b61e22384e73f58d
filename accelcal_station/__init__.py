"""accelcal-station: a production-line calibration station for three-axis MEMS accelerometers.

The library face is ``from accelcal_station import load, fit, simulate, diagnose, Calibration``
(defined in ``accelcal_station.api``, docs/python-api.md). The subpackages are the parts
(docs/architecture.md): ``cli`` on top; the flows ``station``, ``lot``, ``diagnosis``; the parts
``store``, ``nvm``, ``data``, ``fixtures``, ``instruments``, ``drivers``, ``acceptance``; then
``models``, ``sim``, ``config`` and the foundation modules. Which may import which is kept by
import-linter (pyproject.toml). This file imports nothing of its own until a library name is
asked for, so ``accelcal`` and ``import accelcal_station.drivers`` stay light.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from .api import Calibration, Fit, diagnose, fit, load, simulate

# a library adds no handler but this: the command line configures the event log (config/event_log.py)
logging.getLogger(__name__).addHandler(logging.NullHandler())

_API = ("Calibration", "Fit", "diagnose", "fit", "load", "simulate")


def __getattr__(name: str) -> Any:
    """The library names, imported from ``api`` on first use (PEP 562)."""
    if name in _API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'accelcal_station' has no attribute {name!r}")


__all__ = ["Calibration", "Fit", "__version__", "diagnose", "fit", "load", "simulate"]

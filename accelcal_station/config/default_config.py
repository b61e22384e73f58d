"""Where the default station config (configs/sim.yaml) lies; a module of its own so that finding it
imports no schema (pydantic): `accelcal batch LOT --out` names that config's store without
reading it through the schema (issue 51's start-up)."""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def default_config_path() -> Path:
    """configs/sim.yaml, wherever the package is installed (an editable checkout or site-packages).

    Resolved, so a checkout names the file where it lies (``configs/sim.yaml``), not through the
    package's link to that folder.
    """
    return Path(str(files("accelcal_station.configs").joinpath("sim.yaml"))).resolve()

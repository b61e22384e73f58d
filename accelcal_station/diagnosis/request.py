"""What a diagnosis reads and how: ``DiagnoseRequest`` (the files and the options `accelcal diagnose` and
``api.diagnose`` take), and ``DiagnoseOptions``, the same options as keyword arguments (PEP 692).

Light on purpose: no numpy, no loaders, so the CLI and the library face import it without the diagnosis.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict


class DiagnoseOptions(TypedDict, total=False):
    """``api.diagnose``'s keyword arguments: DiagnoseRequest's fields but the files."""

    config: str | Path | None
    raw: bool
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    columns: str | None
    skip_rows: int | None
    rate_hz: float | None
    samples: int | None
    norm_only: bool


@dataclass(frozen=True)
class DiagnoseRequest:
    """The data to diagnose and how to read them: ``files`` are pose tables (raw logs with ``raw``) read as
    `accelcal fit` reads them; ``config`` the station YAML whose simulated device should describe the
    boards (None: configs/sim.yaml); ``rate_hz`` the raw log's sample rate, or for pose tables the rate of
    the samples behind their std; ``samples`` per pose when the data do not say; ``norm_only`` ignores the
    references."""

    files: Sequence[str | Path]
    config: str | Path | None = None
    raw: bool = False
    units: str | None = None
    counts_per_g: float | None = None
    gravity_mps2: float | None = None
    columns: str | None = None
    skip_rows: int | None = None
    rate_hz: float | None = None
    samples: int | None = None
    norm_only: bool = False

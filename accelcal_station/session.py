"""PoseRecord and Session: what the station captured for one board, in input units.

A Session is what every model fits and every file format reads or writes.  Readings
stay in their input units (usually counts) with the scale that turns them into g.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .conventions import check_units, units_per_g
from .errors import DataError


@dataclass(slots=True)  # no per-pose __dict__: a 100,000-pose table stays small
class PoseRecord:
    """One static pose.

    mean: (3,) averaged reading in the session's units; std: (3,) per-sample std;
    n: samples averaged; reference_g: (3,) expected output in g (AN4399 convention:
    positive along gravity), None for reference-free (model 9) data;
    pitch_deg/roll_deg: the commanded AN4399 angles when known.
    """

    name: str
    mean: np.ndarray
    std: np.ndarray | None = None
    n: int | None = None
    reference_g: np.ndarray | None = None
    pitch_deg: float | None = None
    roll_deg: float | None = None
    temp_c: float | None = None
    dropped: int = 0
    t_start: float | None = None
    t_end: float | None = None

    def __post_init__(self) -> None:
        self.mean = _vec3(self.mean)
        if self.std is not None:
            self.std = _vec3(self.std)
        if self.reference_g is not None:
            self.reference_g = _vec3(self.reference_g)


def _vec3(v: Any) -> np.ndarray:
    """A (3,) float array; one already in that form is kept as it is (no view per pose: memory)."""
    a = np.asarray(v, dtype=float)
    return a if a.shape == (3,) else a.reshape(3)


@dataclass
class Session:
    poses: list[PoseRecord]
    units: str = "counts"
    counts_per_g: float | None = None
    gravity_mps2: float | None = None
    device: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_units(self.units)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.poses]

    @property
    def readings(self) -> np.ndarray:
        """(P, 3) means in the session's units."""
        return np.array([p.mean for p in self.poses]).reshape(-1, 3)

    @property
    def input_per_g(self) -> float:
        return units_per_g(self.units, self.counts_per_g, self.gravity_mps2)

    def readings_g(self) -> np.ndarray:
        return self.readings / self.input_per_g

    @property
    def has_references(self) -> bool:
        return len(self.poses) > 0 and all(p.reference_g is not None for p in self.poses)

    @property
    def references_g(self) -> np.ndarray | None:
        if not self.has_references:
            return None
        return np.array([p.reference_g for p in self.poses])

    def noise(self) -> np.ndarray | None:
        """(P, 3) standard error of each pose mean in the session's units, when std and n are known."""
        se = []
        for p in self.poses:
            if p.std is None or not p.n:
                return None
            se.append(p.std / np.sqrt(p.n))
        return np.array(se) if se else None

    def noise_g(self) -> np.ndarray | None:
        """(P, 3) standard error of each pose mean in g, when std and n are known."""
        nz = self.noise()
        return None if nz is None else nz / self.input_per_g

    @property
    def temps_c(self) -> np.ndarray | None:
        if not self.poses or any(p.temp_c is None for p in self.poses):
            return None
        return np.array([p.temp_c for p in self.poses], dtype=float)

    def by_temperature(self, tolerance_c: float = 2.0) -> list[tuple[float, Session]]:
        """Split into sessions of nearly equal temperature (clusters within tolerance)."""
        t = self.temps_c
        if t is None:
            raise DataError("poses have no temperature (temp_c) to group by")
        order = np.argsort(t)
        groups: list[list[int]] = []
        for i in order:
            if groups and t[i] - t[groups[-1][0]] <= tolerance_c:
                groups[-1].append(int(i))
            else:
                groups.append([int(i)])
        out = []
        for g in groups:
            sub = Session([self.poses[i] for i in g], self.units, self.counts_per_g, self.gravity_mps2,
                          self.device, dict(self.metadata))
            out.append((float(np.mean(t[g])), sub))
        return out

    def subset(self, idx: Iterable[int]) -> Session:
        return Session([self.poses[i] for i in idx], self.units, self.counts_per_g, self.gravity_mps2,
                       self.device, dict(self.metadata))

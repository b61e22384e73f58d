"""PoseRecord and Session: what the station captured for one board, in input units.

A Session is what every model fits and every file format reads or writes.  Readings
stay in their input units (usually counts) with the scale that turns them into g.
"""
from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, overload

import numpy as np

from .conventions import STANDARD_GRAVITY_MPS2, check_units, units_per_g
from .errors import DataError


@dataclass(slots=True)  # no per-pose __dict__: a 100,000-pose table stays small
class PoseRecord:
    """One static pose.

    mean: (3,) averaged reading in the session's units; std: (3,) per-sample std;
    n: samples averaged; reference_g: (3,) expected output in g (what the chip
    reads: +1 g on the axis pointing up; AN4399 Eqn 22 of the angles), None for reference-free (model 9) data;
    pitch_deg/roll_deg: the commanded AN4399 angles when known; n_eff: (3,) effective sample count per
    axis (n / tau_int, correlated samples: models/effective_samples.py) when the capture measured it, else n is used.
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
    n_eff: np.ndarray | None = None

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


_NAN3 = (math.nan, math.nan, math.nan)


class PoseColumns(Sequence[PoseRecord]):
    """Many poses of a table held as columns, ~170 bytes a pose instead of ~700 as PoseRecords of
    (3,) arrays (a 100,000-row pose table: 17 MB, not 70).  Filled with :meth:`append` (the fields a
    pose table has: no dropped count or times); indexing makes a PoseRecord (views into the columns),
    so changing that record changes nothing here."""

    # per pose: mean x y z, std x y z, reference x y z, pitch, roll, temp, n (NaN: not given)
    WIDTH = 13

    def __init__(self) -> None:
        self._names: list[str] = []
        self._buf = array("d")
        self._arr: np.ndarray | None = None

    def append(self, p: PoseRecord) -> None:
        if p.dropped or p.t_start is not None or p.t_end is not None:
            raise ValueError("PoseColumns holds pose-table rows (no dropped count, no capture times)")
        if self._arr is not None:  # appending after reading: back to the growable buffer
            self._buf, self._arr = array("d", self._arr.tobytes()), None
        opt = [math.nan if v is None else float(v) for v in (p.pitch_deg, p.roll_deg, p.temp_c, p.n)]
        self._buf.extend((*p.mean.tolist(), *(_NAN3 if p.std is None else p.std.tolist()),
                          *(_NAN3 if p.reference_g is None else p.reference_g.tolist()), *opt))
        self._names.append(p.name)

    @property
    def table(self) -> np.ndarray:
        """(P, 13) the columns (WIDTH); read-only."""
        if self._arr is None:
            self._arr = np.array(self._buf, dtype=float).reshape(-1, self.WIDTH)
            self._arr.flags.writeable = False
            self._buf = array("d")
        return self._arr

    def column(self, start: int, stop: int) -> np.ndarray:
        """A contiguous copy of columns ``start:stop`` (what the per-pose arrays stacked would give)."""
        return np.ascontiguousarray(self.table[:, start:stop])

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def shifted(self, offset: float) -> PoseColumns:
        """These poses with ``offset`` taken from every mean (as ``mean - offset`` per pose)."""
        out = PoseColumns()
        t = self.table.copy()
        t[:, 0:3] = t[:, 0:3] - offset
        t.flags.writeable = False
        out._names, out._arr = list(self._names), t
        return out

    def scaled_references(self, factor: float) -> PoseColumns:
        """These poses with every reference multiplied by ``factor`` (a site's gravity in standard g)."""
        out = PoseColumns()
        t = self.table.copy()
        t[:, 6:9] = t[:, 6:9] * factor
        t.flags.writeable = False
        out._names, out._arr = list(self._names), t
        return out

    def __len__(self) -> int:
        return len(self._names)

    def _record(self, i: int) -> PoseRecord:
        row = self.table[i]
        std, ref = row[3:6], row[6:9]
        pitch, roll, temp, n = row[9:].tolist()
        return PoseRecord(self._names[i], row[0:3], None if math.isnan(std[0]) else std, None if math.isnan(n)
                          else int(n), None if math.isnan(ref[0]) else ref, None if math.isnan(pitch) else pitch,
                          None if math.isnan(roll) else roll, None if math.isnan(temp) else temp)

    @overload
    def __getitem__(self, i: int) -> PoseRecord: ...

    @overload
    def __getitem__(self, i: slice) -> list[PoseRecord]: ...

    def __getitem__(self, i: int | slice) -> PoseRecord | list[PoseRecord]:
        if isinstance(i, slice):
            return [self._record(k) for k in range(*i.indices(len(self)))]
        k = i + len(self) if i < 0 else i
        if not 0 <= k < len(self):
            raise IndexError("pose index out of range")
        return self._record(k)

    def __iter__(self) -> Iterator[PoseRecord]:
        for k in range(len(self)):
            yield self._record(k)


@dataclass
class Session:
    poses: Sequence[PoseRecord]  # a list, or PoseColumns for a large table
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
        if isinstance(self.poses, PoseColumns):
            return self.poses.names
        return [p.name for p in self.poses]

    @property
    def readings(self) -> np.ndarray:
        """(P, 3) means in the session's units."""
        if isinstance(self.poses, PoseColumns):
            return self.poses.column(0, 3)
        return np.array([p.mean for p in self.poses]).reshape(-1, 3)

    @property
    def site_gravity_g(self) -> float:
        """The site's gravity in standard g the references are scaled to (``metadata['site']``, set by
        the loader from --gravity or a file's ``# gravity_mps2:``; config/site.py); 1 without one."""
        site = self.metadata.get("site")
        g = site.get("gravity_mps2") if isinstance(site, dict) else None
        return float(g) / STANDARD_GRAVITY_MPS2 if isinstance(g, (int, float)) else 1.0

    @property
    def input_per_g(self) -> float:
        return units_per_g(self.units, self.counts_per_g, self.gravity_mps2)

    def readings_g(self) -> np.ndarray:
        return self.readings / self.input_per_g

    @property
    def has_references(self) -> bool:
        if isinstance(self.poses, PoseColumns):
            return len(self.poses) > 0 and not np.isnan(self.poses.table[:, 6]).any()
        return len(self.poses) > 0 and all(p.reference_g is not None for p in self.poses)

    @property
    def references_g(self) -> np.ndarray | None:
        if not self.has_references:
            return None
        if isinstance(self.poses, PoseColumns):
            return self.poses.column(6, 9)
        return np.array([p.reference_g for p in self.poses])

    def noise(self) -> np.ndarray | None:
        """(P, 3) standard error of each pose mean in the session's units, when std and n are known."""
        if isinstance(self.poses, PoseColumns):
            t = self.poses.table
            std, n = t[:, 3:6], t[:, 12]
            if not len(t) or np.isnan(std[:, 0]).any() or np.isnan(n).any() or (n == 0).any():
                return None
            return std / np.sqrt(n)[:, None]
        se = []
        for p in self.poses:
            if p.std is None or not p.n:
                return None
            se.append(p.std / np.sqrt(p.n if p.n_eff is None else np.maximum(p.n_eff, 1.0)))
        return np.array(se) if se else None

    def noise_g(self) -> np.ndarray | None:
        """(P, 3) standard error of each pose mean in g, when std and n are known."""
        nz = self.noise()
        return None if nz is None else nz / self.input_per_g

    @property
    def temps_c(self) -> np.ndarray | None:
        if isinstance(self.poses, PoseColumns):
            t = self.poses.column(11, 12).ravel()
            return None if not len(t) or np.isnan(t).any() else t
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

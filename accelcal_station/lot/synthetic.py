"""Simulated lot files: many boards' poses in one long table (lot.py's format), streamed.

Each board is a forward sensor: reading_counts = counts_per_g (K g_ref + b) + noise,
K = I + a random gain / cross-axis matrix (sigma ``gain_sigma``), b a random offset in g
(``offset_sigma_g``), white noise of ``noise_g`` per pose mean; poses are a named design's
(fixtures/designs.py) pitch and roll, the references the station would record.
For benchmarks and tests of the batch pipeline, not for judging a model's physics.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..errors import DataError
from ..fixtures.designs import get_design, references
from ..sim.lot_physics import Conditions, pose_means
from ..sim.population import Population
from ..sim.sensor_model import SensorModel

HEADER = "serial,pose,pitch_deg,roll_deg,x,y,z,n,std_x,std_y,std_z"


@dataclass(frozen=True)
class SimpleBoards:
    """write_lot's boards (module doc): counts per g, the gain / cross-axis spread (sigma of K - I), the
    offset spread in g and the white noise of a pose mean in g."""

    counts_per_g: float = 4096.0
    gain_sigma: float = 0.01
    offset_sigma_g: float = 0.03
    noise_g: float = 1e-3


@dataclass(frozen=True)
class LotSpec:
    """A simulated lot file: ``boards`` boards measured at the poses of ``design``, ``samples`` samples per
    pose at ``range_g``, drawn with ``seed``, written ``chunk`` boards at a time (memory is one chunk's),
    serials ``prefix`` + 8 digits; ``conditions``: the measurement's (sim/lot_physics.py)."""

    boards: int
    design: str = "an4399-8"
    seed: int = 0
    samples: int = 1000
    range_g: int = 2
    chunk: int = 20_000
    prefix: str = "B"
    conditions: Conditions = field(default_factory=Conditions)


@dataclass(frozen=True)
class _DesignColumns:
    """A design's pose names, pitch and roll, as the lot file's columns repeat them per board."""

    names: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray

    @classmethod
    def of(cls, design: str) -> _DesignColumns:
        poses = get_design(design)
        return cls(np.array([p.name for p in poses]), np.array([p.pitch_deg for p in poses]),
                   np.array([p.roll_deg for p in poses]))

    def __len__(self) -> int:
        return len(self.names)


def write_lot(path: str | Path, boards: int, design: str = "an4399-8", *, seed: int = 0,
              spread: SimpleBoards = SimpleBoards(), chunk: int = 20_000, parquet: bool = False) -> Path:
    """Write a lot of ``boards`` simulated boards; memory is one chunk's whatever the size."""
    ref = references(get_design(design))  # (P, 3) g
    cols_of = _DesignColumns.of(design)
    names, pitch, roll, P = cols_of.names, cols_of.pitch, cols_of.roll, len(cols_of)
    counts_per_g = spread.counts_per_g
    rng = np.random.default_rng(seed)
    path = Path(path)
    writer = None
    with open(path, "wb" if parquet else "w") as f:
        if not parquet:
            f.write(f"# units: counts\n# counts_per_g: {counts_per_g:g}\n{HEADER}\n")
        for a in range(0, boards, chunk):
            D = min(chunk, boards - a)
            K = np.eye(3) + rng.normal(0, spread.gain_sigma, (D, 3, 3))
            off = rng.normal(0, spread.offset_sigma_g, (D, 1, 3))
            g = np.einsum("dij,pj->dpi", K, ref) + off + rng.normal(0, spread.noise_g, (D, P, 3))
            x = np.round(g * counts_per_g, 3).reshape(-1, 3)
            serial = np.repeat(np.char.add("B", np.char.zfill(np.arange(a, a + D).astype(str), 8)), P)
            cols = {"serial": serial, "pose": np.tile(names, D), "pitch_deg": np.tile(pitch, D),
                    "roll_deg": np.tile(roll, D), "x": x[:, 0], "y": x[:, 1], "z": x[:, 2],
                    "n": np.full(D * P, 200), "std_x": np.full(D * P, 4.0), "std_y": np.full(D * P, 4.0),
                    "std_z": np.full(D * P, 4.0)}
            if parquet:
                import pyarrow as pa
                import pyarrow.parquet as pq
                t = pa.table(cols).replace_schema_metadata({"units": "counts", "counts_per_g": f"{counts_per_g:g}"})
                if writer is None:
                    writer = pq.ParquetWriter(f, t.schema)
                writer.write_table(t)
                continue
            text = [cols[c] if cols[c].dtype.kind == "U" else cols[c].astype(str) for c in HEADER.split(",")]
            f.write("\n".join(",".join(r) for r in zip(*text, strict=True)) + "\n")
        if writer is not None:
            writer.close()
    return path


def _rows(a: int, design: _DesignColumns, mean: np.ndarray, std: np.ndarray, samples: int, prefix: str) -> str:
    """One chunk's lot-file rows (HEADER's columns), board serials ``prefix`` + 8 digits."""
    D, P = mean.shape[0], len(design)
    x = np.round(mean, 3).reshape(-1, 3)
    s = np.round(std, 3).reshape(-1, 3)
    serial = np.repeat(np.char.add(prefix, np.char.zfill(np.arange(a, a + D).astype(str), 8)), P)
    cols = [serial, np.tile(design.names, D), np.tile(design.pitch, D).astype(str),
            np.tile(design.roll, D).astype(str), x[:, 0].astype(str), x[:, 1].astype(str), x[:, 2].astype(str),
            np.full(D * P, str(samples)), s[:, 0].astype(str), s[:, 1].astype(str), s[:, 2].astype(str)]
    return "\n".join(",".join(r) for r in zip(*cols, strict=True)) + "\n"


def write_population_lot(path: str | Path, lot: LotSpec, model: SensorModel, pop: Population | None, *,
                         draw: Callable[[np.ndarray, np.random.Generator], np.ndarray] | None = None) -> Path:
    """A lot of ``lot.boards`` boards drawn from a population (or all the one fixed board), each
    measured at the design's poses by the vectorised sensor chain (sim/lot_physics.py).

    ``draw(board_indices, rng)``, when given, replaces ``pop.draw`` (a generator of its own);
    ``lot.conditions.forward``: the nonlinearity's physics, None = the model's (``simulator.physics``).
    Written to a temporary file renamed over ``path`` at the end; memory is one chunk's."""
    ref = references(get_design(lot.design))
    cols = _DesignColumns.of(lot.design)
    rng = np.random.default_rng(lot.seed)
    cpg = model.chip.counts_per_g(lot.range_g)

    def write(tmp: str) -> None:
        with open(tmp, "w") as f:
            f.write(f"# units: counts\n# counts_per_g: {cpg:g}\n# design: {lot.design}\n{HEADER}\n")
            for a in range(0, lot.boards, lot.chunk):
                idx = np.arange(a, min(a + lot.chunk, lot.boards))
                x = draw(idx, rng) if draw is not None else None
                mean, std, _ = pose_means(model, pop, idx, ref, lot.samples, rng, range_g=lot.range_g, x=x,
                                          conditions=lot.conditions)
                f.write(_rows(a, cols, mean, std, lot.samples, lot.prefix))

    try:
        atomic_write(path, write)
    except OSError as e:
        raise DataError(f"{path}: cannot write ({e.strerror or e})") from None
    return Path(path)

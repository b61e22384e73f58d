"""Simulated lot files: many boards' poses in one long table (lot.py's format), streamed.

Each board is a forward sensor: reading_counts = counts_per_g (K g_ref + b) + noise,
K = I + a random gain / cross-axis matrix (sigma ``gain_sigma``), b a random offset in g
(``offset_sigma_g``), white noise of ``noise_g`` per pose mean; poses are a named design's
(fixtures/designs.py) pitch and roll, the references the station would record.
For benchmarks and tests of the batch pipeline, not for judging a model's physics.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..errors import DataError
from ..fixtures.designs import get_design, references
from ..sim.lot_physics import pose_means
from ..sim.population import Population
from ..sim.sensor_model import SensorModel

HEADER = "serial,pose,pitch_deg,roll_deg,x,y,z,n,std_x,std_y,std_z"


def write_lot(path: str | Path, boards: int, design: str = "an4399-8", *, counts_per_g: float = 4096.0,
              seed: int = 0, gain_sigma: float = 0.01, offset_sigma_g: float = 0.03, noise_g: float = 1e-3,
              chunk: int = 20_000, parquet: bool = False) -> Path:
    """Write a lot of ``boards`` simulated boards; memory is one chunk's whatever the size."""
    poses = get_design(design)
    ref = references(poses)  # (P, 3) g
    P = len(poses)
    rng = np.random.default_rng(seed)
    path = Path(path)
    names = np.array([p.name for p in poses])
    pitch = np.array([p.pitch_deg for p in poses])
    roll = np.array([p.roll_deg for p in poses])
    writer = None
    with open(path, "wb" if parquet else "w") as f:
        if not parquet:
            f.write(f"# units: counts\n# counts_per_g: {counts_per_g:g}\n{HEADER}\n")
        for a in range(0, boards, chunk):
            D = min(chunk, boards - a)
            K = np.eye(3) + rng.normal(0, gain_sigma, (D, 3, 3))
            off = rng.normal(0, offset_sigma_g, (D, 1, 3))
            g = np.einsum("dij,pj->dpi", K, ref) + off + rng.normal(0, noise_g, (D, P, 3))
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


def _rows(a: int, D: int, P: int, names: np.ndarray, pitch: np.ndarray, roll: np.ndarray, mean: np.ndarray,
          std: np.ndarray, samples: int, prefix: str) -> str:
    """One chunk's lot-file rows (HEADER's columns), board serials ``prefix`` + 8 digits."""
    x = np.round(mean, 3).reshape(-1, 3)
    s = np.round(std, 3).reshape(-1, 3)
    serial = np.repeat(np.char.add(prefix, np.char.zfill(np.arange(a, a + D).astype(str), 8)), P)
    cols = [serial, np.tile(names, D), np.tile(pitch, D).astype(str), np.tile(roll, D).astype(str),
            x[:, 0].astype(str), x[:, 1].astype(str), x[:, 2].astype(str), np.full(D * P, str(samples)),
            s[:, 0].astype(str), s[:, 1].astype(str), s[:, 2].astype(str)]
    return "\n".join(",".join(r) for r in zip(*cols, strict=True)) + "\n"


def write_population_lot(path: str | Path, boards: int, design: str, model: SensorModel,
                         pop: Population | None, *, seed: int = 0, samples: int = 1000, range_g: int = 2,
                         chunk: int = 20_000, forward: bool | None = None, prefix: str = "B",
                         draw: Callable[[np.ndarray, np.random.Generator], np.ndarray] | None = None) -> Path:
    """A lot of ``boards`` boards drawn from a population (or all the one fixed board), each
    measured at the design's poses by the vectorised sensor chain (sim/lot_physics.py).

    ``draw(board_indices, rng)``, when given, replaces ``pop.draw`` (a generator of its own);
    ``forward``: the nonlinearity's physics, None = the model's (``simulator.physics``).
    Written to a temporary file renamed over ``path`` at the end; memory is one chunk's."""
    poses = get_design(design)
    ref = references(poses)
    P = len(poses)
    rng = np.random.default_rng(seed)
    names = np.array([p.name for p in poses])
    pitch = np.array([p.pitch_deg for p in poses])
    roll = np.array([p.roll_deg for p in poses])
    cpg = model.chip.counts_per_g(range_g)

    def write(tmp: str) -> None:
        with open(tmp, "w") as f:
            f.write(f"# units: counts\n# counts_per_g: {cpg:g}\n# design: {design}\n{HEADER}\n")
            for a in range(0, boards, chunk):
                idx = np.arange(a, min(a + chunk, boards))
                x = draw(idx, rng) if draw is not None else None
                mean, std, _ = pose_means(model, pop, idx, ref, samples, rng, range_g=range_g, forward=forward, x=x)
                f.write(_rows(a, len(idx), P, names, pitch, roll, mean, std, samples, prefix))

    try:
        atomic_write(path, write)
    except OSError as e:
        raise DataError(f"{path}: cannot write ({e.strerror or e})") from None
    return Path(path)

"""Shared pieces of the benchmarks: in-class simulated boards, measurements, tables.

Boards are :class:`SimulatedBoard` MMA8451s (99 ug/sqrt(Hz) at 100 Hz: 0.70 mg per
sample, integer counts) whose only effects are noise, quantization and the
calibration model's own class of errors, drawn per board from a fixed seed, so
the simulator truth (``board.truth()``) is exactly what a model can recover.
"""
from __future__ import annotations

import numpy as np

from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.designs import get_design, references

# Which effects each model's class has (DESIGN.md catalog names).
CLASS_EFFECTS = {
    "6": ("offset", "gain"),
    "9": ("offset", "gain", "cross_axis (symmetric: K = K^T)"),
    "12": ("offset", "gain", "cross_axis"),
    "15": ("offset", "gain", "cross_axis", "cubic"),
}
OFFSET_SD_MG, GAIN_SD, COUPLING_SD, ROTATION_SD_DEG, CUBIC_SD = 20.0, 0.01, 0.005, 0.3, 0.003


def board_effects(model: str, rng: np.random.Generator) -> dict:
    """One board's YAML ``effects`` mapping: noise + quantization + the model's class."""
    gain = 1.0 + rng.normal(0.0, GAIN_SD, 3)
    eff: dict = {"noise": {}, "quantization": {"lsb_counts": 1},
                 "offset": {"offset_mg": rng.normal(0.0, OFFSET_SD_MG, 3).tolist()},
                 "gain": {"gain": gain.tolist()}}
    if model in ("12", "15"):
        c = rng.normal(0.0, COUPLING_SD, (3, 3))
        np.fill_diagonal(c, 0.0)
        eff["cross_axis"] = {"coupling": c.tolist(), "rotation_deg": rng.normal(0.0, ROTATION_SD_DEG, 3).tolist()}
    if model == "9":
        # model 9 (A = M (V - B), M symmetric) cannot see a rotation: K = diag(g)(I + C) is made
        # symmetric (g_i C_ij = S_ij with S symmetric) so its truth lies in the model's class
        s = np.triu(rng.normal(0.0, COUPLING_SD, (3, 3)), 1)
        s = s + s.T
        eff["cross_axis"] = {"coupling": (s / gain[:, None]).tolist()}
    if model == "15":
        eff["cubic"] = {"cubic_per_g2": rng.normal(0.0, CUBIC_SD, 3).tolist()}
    return eff


def make_boards(model: str, count: int, seed: int) -> list[SimulatedBoard]:
    """``count`` in-class boards for ``model`` (each with its own noise stream)."""
    ss = np.random.SeedSequence(seed)
    out = []
    for child in ss.spawn(count):
        rng = np.random.default_rng(child)
        out.append(SimulatedBoard.from_config({"chip": "mma8451", "effects": board_effects(model, rng)},
                                              seed=int(rng.integers(2**62))))
    return out


def measure(board: SimulatedBoard, directions: np.ndarray, samples: int) -> np.ndarray:
    """Averaged readings in g (P, 3) with the true output along each direction (P, 3)."""
    out = np.empty((len(directions), 3))
    for i, d in enumerate(directions):
        board.set_gravity_direction(d)
        counts, _ = board.read(samples)
        out[i] = counts.mean(axis=0) / board.counts_per_g
    return out


def measure_raw(board: SimulatedBoard, directions: np.ndarray, samples: int) -> np.ndarray:
    """Raw samples in g (P, samples, 3)."""
    out = np.empty((len(directions), samples, 3))
    for i, d in enumerate(directions):
        board.set_gravity_direction(d)
        counts, _ = board.read(samples)
        out[i] = counts / board.counts_per_g
    return out


def sem_g(board: SimulatedBoard, samples: int) -> float:
    """Standard error of one axis of an averaged reading in g: white noise plus the
    quantization's LSB^2/12 (the per-sample variance the station would measure)."""
    s = float(np.max(board.noise_sigma_counts))
    return float(np.sqrt(s**2 + 1.0 / 12.0) / np.sqrt(samples) / board.counts_per_g)


def design_refs(name: str) -> np.ndarray:
    return references(get_design(name))


def random_directions(shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed unit vectors, shape ``shape + (3,)``."""
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def apply_an4399(W, V, Gamma, gf):
    """G = W G_f + V + Gamma G_f^3 (AN4399 Eqn 67), stacked: W (D,3,3), V, Gamma (D,3), gf (D,H,3)."""
    return np.einsum("dij,dhj->dhi", W, gf) + V[:, None, :] + Gamma[:, None, :] * gf**3


def angle_deg(a, b) -> np.ndarray:
    """Angle between vectors along the last axis, degrees (atan2 form: exact for tiny angles)."""
    c = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.rad2deg(np.arctan2(c, np.sum(a * b, axis=-1)))


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def truth_stack(boards) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulator truth W (D,3,3), V (D,3), Gamma (D,3) at each board's temperature."""
    cals = [b.truth() for b in boards]
    return (np.array([c.W for c in cals]), np.array([c.V for c in cals]), np.array([c.Gamma for c in cals]))


def params_by_name(names: list[str], W, V, Gamma) -> np.ndarray:
    """Truth values (D, k) in a model's parameter order (W_ab, V_a, Gamma_aa; model 9: M_ab, B_a)."""
    ax = "xyz"
    B = -np.linalg.solve(W, V[..., None])[..., 0]  # model 9: A = M (v - B), V = -M B
    cols = []
    for n in names:
        kind, sub = n.split("_")
        idx = [ax.index(c) for c in sub]
        if kind in ("W", "M"):
            cols.append(W[:, idx[0], idx[1]])
        elif kind == "V":
            cols.append(V[:, idx[0]])
        elif kind == "B":
            cols.append(B[:, idx[0]])
        else:
            cols.append(Gamma[:, idx[0]])
    return np.stack(cols, axis=1)


def norm_residual(p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """|M (v - B)| - 1 for p = (M_xx, M_yy, M_zz, M_xy, M_xz, M_yz, B_x, B_y, B_z): the
    nine-position paper's cost, written out independently for scipy's least_squares."""
    M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    return np.linalg.norm((v - p[6:]) @ M, axis=1) - 1.0


def table(headers: list[str], rows: list[list], widths: list[int] | None = None) -> str:
    """A fixed-width text table; the first column left-aligned, the rest right-aligned."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    w = widths or [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = []
    for k, r in enumerate(cells):
        lines.append("  ".join(c.ljust(w[i]) if i == 0 else c.rjust(w[i]) for i, c in enumerate(r)))
        if k == 0:
            lines.append("  ".join("-" * x for x in w))
    return "\n".join(lines)

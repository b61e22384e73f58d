"""Lots with withheld population structure, for the twin's self-check.

The boards' parameters are drawn here, by code of their own (not sim/population.py's draw,
not the twin's mixture), and measured by the simulator's forward physics (sim/lot_physics.py
with ``forward``: G = o + u + c u^3, u = K f -- a sensor's own response, which model 15, the
model the twin fits, only approximates: its fit of a 0.015 1/g^2 cubic reads ~0.013 and leaves
a ~0.4 mg residual at an4399-8's poses).  What is withheld from the twin: a 10 % subpopulation with a
cubic nonlinearity on z drawn *uniformly* in [0.010, 0.020] 1/g^2 (10-20 mg at 1 g), a step
of the x offset's mean by +5 mg at a board index, x offset and x gain correlated (rho 0.7),
and offsets with heavy (Student-t, 4 degrees of freedom) tails.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from accelcal_station.config.checks import load_yaml
from accelcal_station.config.sections import default_config_path
from accelcal_station.lot.synthetic import LotSpec, write_population_lot
from accelcal_station.sim.lot_physics import Conditions
from accelcal_station.sim.population import Component, Population, parse_quantity
from accelcal_station.sim.sensor_model import SensorModel

NAMES = ["offset.offset_mg[0]", "offset.offset_mg[1]", "offset.offset_mg[2]", "gain.gain[0]", "gain.gain[1]",
         "gain.gain[2]", "cross_axis.coupling[0][1]", "cross_axis.coupling[1][2]", "cubic.cubic_per_g2[2]"]
CUBIC_SHARE = 0.10


def default_model() -> SensorModel:
    return SensorModel.from_config(load_yaml(default_config_path())["device"]["simulator"]["effects"])


def line_draw(step_at: int | None, step_mg: float = 5.0):
    """The line's own board generator: (board indices, rng) -> (n, len(NAMES)) parameters."""
    def draw(boards: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        n = len(boards)
        t_scale = np.sqrt(4 / rng.chisquare(4, n))  # Student-t (nu = 4) offsets: heavy tails
        z = rng.standard_normal((n, 2))
        off_x = 18.0 + 8.0 * t_scale * z[:, 0]
        gain_x = 1.012 + 0.004 * (0.7 * z[:, 0] + np.sqrt(1 - 0.49) * z[:, 1])  # rho(offset x, gain x) = 0.7
        x = np.column_stack([
            off_x, -27.0 + 8.0 * t_scale * rng.standard_normal(n), 41.0 + 8.0 * t_scale * rng.standard_normal(n),
            gain_x, 0.987 + 0.004 * rng.standard_normal(n), 1.021 + 0.004 * rng.standard_normal(n),
            0.006 + 0.002 * rng.standard_normal(n), 0.005 + 0.002 * rng.standard_normal(n), np.zeros(n)])
        sub = rng.random(n) < CUBIC_SHARE
        x[sub, -1] = rng.uniform(0.010, 0.020, int(sub.sum()))
        if step_at is not None:
            x[boards >= step_at, 0] += step_mg
        return x
    return draw


def write_line_lot(path: Path, boards: int, step_at: int | None = 12_000, seed: int = 7, samples: int = 1000,
                   forward: bool = True) -> Path:
    model = default_model()
    qs = [parse_quantity(n, "test") for n in NAMES]
    shape = Population(qs, [Component(1.0, np.zeros(len(qs)), np.zeros(len(qs)), np.eye(len(qs)))])
    lot = LotSpec(boards, "an4399-8", seed=seed, samples=samples, conditions=Conditions(forward=forward))
    return write_population_lot(path, lot, model, shape, draw=line_draw(step_at))


# -- lots written by this module's own physics (numpy only; no simulator code) -----------------
# For the issue-38 cases: a structureless lot whose stated per-sample std is rounded to two digits
# (the true spread is not the stated one), a 10 % subpopulation with a cubic applied to the whole
# reading *including the offset* (G = r + c r^3, r = o + K f: neither the simulator's implicit nor
# its forward physics), and cross-axis terms with Student-t (3 dof) tails.
TRUE_SD_COUNTS = 2.8672  # per-sample noise; the lot states it as 2.9 (two digits)
COUNTS_PER_G = 4096.0
OFF = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


def own_draw(n: int, rng: np.random.Generator, cubic_share: float = 0.0, coupling_dof: float | None = None
             ) -> dict[str, np.ndarray]:
    """Board parameters: offsets mg, gains, coupling (3x3, zero diagonal), cubic per axis 1/g^2."""
    off = np.array([18.0, -27.0, 41.0]) + 8.0 * rng.standard_normal((n, 3))
    gain = np.array([1.012, 0.987, 1.021]) + 0.004 * rng.standard_normal((n, 3))
    z = rng.standard_normal((n, 6))
    if coupling_dof is not None:  # Student-t with these dof, scale 0.002: a heavy tail in one block only
        z = z * np.sqrt(coupling_dof / rng.chisquare(coupling_dof, (n, 6)))
    C = np.zeros((n, 3, 3))
    for k, (i, j) in enumerate(OFF):
        C[:, i, j] = 0.004 + 0.002 * z[:, k]
    cubic = np.zeros((n, 3))
    sub = rng.random(n) < cubic_share
    cubic[sub, 2] = rng.uniform(0.010, 0.020, int(sub.sum()))
    return {"offset_mg": off, "gain": gain, "coupling": C, "cubic": cubic, "sub": sub}


def own_readings(p: dict[str, np.ndarray], ref: np.ndarray, samples: int, rng: np.random.Generator) -> np.ndarray:
    """Pose means (n, P, 3) in counts: r = o + diag(g) (I + C) f, G = r + c r^3 (the whole reading),
    plus the mean of ``samples`` samples of white noise TRUE_SD_COUNTS."""
    K = p["gain"][:, :, None] * (np.eye(3) + p["coupling"])
    r = 1e-3 * p["offset_mg"][:, None, :] + np.einsum("nij,pj->npi", K, ref)
    G = r + p["cubic"][:, None, :] * r**3
    return G * COUNTS_PER_G + TRUE_SD_COUNTS / np.sqrt(samples) * rng.standard_normal(G.shape)


def write_own_lot(path: Path, boards: int, seed: int, cubic_share: float = 0.0, coupling_dof: float | None = None,
                  samples: int = 1000, design: str = "an4399-8") -> Path:
    """A lot file (HEADER's columns) of boards drawn and measured by this module; std written as
    two significant digits of TRUE_SD_COUNTS (2.9), as a station's log rounds it."""
    from accelcal_station.fixtures.designs import get_design, references

    poses = get_design(design)
    ref = references(poses)
    rng = np.random.default_rng(seed)
    P = len(poses)
    x = own_readings(own_draw(boards, rng, cubic_share, coupling_dof), ref, samples, rng).reshape(-1, 3)
    std = f"{float(f'{TRUE_SD_COUNTS:.2g}'):g}"
    lines = [f"# units: counts\n# counts_per_g: {COUNTS_PER_G:g}\n# design: {design}\n"
             "serial,pose,pitch_deg,roll_deg,x,y,z,n,std_x,std_y,std_z"]
    for b in range(boards):
        for k, pose in enumerate(poses):
            r = x[b * P + k]
            lines.append(f"B{b:08d},{pose.name},{pose.pitch_deg:g},{pose.roll_deg:g},{r[0]:.3f},{r[1]:.3f},"
                         f"{r[2]:.3f},{samples},{std},{std},{std}")
    path.write_text("\n".join(lines) + "\n")
    return path

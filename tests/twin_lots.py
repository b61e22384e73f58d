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
from accelcal_station.lot.synthetic import write_population_lot
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
    return write_population_lot(path, boards, "an4399-8", model, shape, seed=seed, samples=samples, forward=forward,
                                draw=line_draw(step_at))

"""What a simulated board is built from: its ``device`` section's forward sensor model (the
``simulator`` file or inline mapping, or ``effects`` given directly), whether its physics is forward,
and the board a seed draws from a population (sim/population.py).  A simulator file is another
input, so it is read and validated here, once (config/parts.py)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..config.checks import load_yaml
from ..config.kinds import Effects, PopulationSpec, SimulatedBoardSection, SimulatorSection
from ..config.parts import parse
from ..errors import ConfigError
from ..sim.population import parse_population
from ..sim.sensor_model import SensorModel

POPULATION_STREAM = 0x7091  # the population draw's own random stream (beside noise, drift, pose)


def load_simulator(m: SimulatedBoardSection, path: str) -> tuple[Effects | None, str, PopulationSpec | None]:
    """The ``effects`` mapping, its key path and the ``population`` mapping (or None) of a board
    section: its own ``effects``, or its ``simulator`` (inline, or a YAML file read and validated here)."""
    sim = simulator_of(m, path)
    if m.effects is not None:
        return m.effects, f"{path}.effects", None
    if sim is None:
        return None, f"{path}.simulator", None
    where = f"{path}.simulator" if not isinstance(m.simulator, str) else f"{path}.simulator({m.simulator})"
    return sim.effects or {}, f"{where}.effects", sim.population


def simulator_of(m: SimulatedBoardSection, path: str) -> SimulatorSection | None:
    """A board section's forward sensor model: inline, or the file its ``simulator`` names (read and
    validated once here: a file is another input)."""
    if m.simulator is not None and m.effects is not None:
        raise ConfigError(f"{path}: give either simulator or effects, not both")
    if isinstance(m.simulator, str):
        return parse(load_yaml(m.simulator), SimulatorSection, f"{path}.simulator({m.simulator})")
    return m.simulator


def load_physics(m: SimulatedBoardSection, path: str) -> bool:
    """True when a board section's ``simulator.physics`` is ``forward`` (sensor_model.PHYSICS);
    ``implicit`` (the default, also for ``effects:`` given directly) is False."""
    sim = simulator_of(m, path)
    return sim is not None and sim.physics == "forward"


def draw_board(model: SensorModel, population: Any, seed: int, path: str) -> SensorModel:
    """The board this seed draws from a population (sim/population.py): board index 0 of the lot,
    its parameters from a random stream of its own (the noise streams are unchanged)."""
    pop = parse_population(population, model.effects, path)
    x = pop.draw(np.zeros(1, np.int64), np.random.default_rng([seed, POPULATION_STREAM]))[0]
    return SensorModel(model.chip, pop.apply(model.effects, x), model.path, model.forward)

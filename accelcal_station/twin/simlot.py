"""A simulated lot shaped like a real one: the same poses, samples per pose and size, drawn
from a station config's simulated device (its population, or its one fixed board), handed
over as lot chunks so the real and the simulated lot go through the same fitting and judging."""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..acceptance.rules import Limits
from ..config.checks import load_yaml
from ..config.kinds import SimulatedDevice
from ..config.parts import SimulatedBoardSection, parse
from ..config.schema import StationConfigSchema, validate_station
from ..data.lotfile import LotChunk
from ..drivers.simulated import load_physics, load_simulator
from ..errors import ConfigError
from ..jsontypes import JsonObject, JsonValue
from ..sim.lot_physics import pose_means
from ..sim.population import Population, parse_population
from ..sim.sensor_model import SensorModel, get_chip
from .records import Simulated
from .stream import LotStats, collect


def section(doc: JsonObject, key: str, path: str) -> JsonObject:
    """``doc[key]``, a mapping (created empty when absent): a twin config is edited in place."""
    sub = doc.setdefault(key, {})
    if not isinstance(sub, dict):
        raise ConfigError(f"{path}.{key}".lstrip(".") + f": {type(sub).__name__}; allowed: a mapping")
    return sub


def mapping(doc: JsonObject, key: str, path: str) -> JsonObject:
    """``doc[key]``, which must be a mapping (read only)."""
    sub = doc.get(key)
    if not isinstance(sub, dict):
        raise ConfigError(f"{path}.{key}".lstrip(".") + f": {type(sub).__name__}; allowed: a mapping")
    return sub


def text(doc: JsonObject, key: str, path: str, default: str) -> str:
    """``doc[key]``, a string (``default`` when absent)."""
    v = doc.get(key, default)
    if not isinstance(v, str):
        raise ConfigError(f"{path}.{key}: {v!r}; allowed: a name")
    return v


def scalar(v: JsonValue, path: str) -> float:
    """A config number (bool excluded: YAML's true is not 1)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ConfigError(f"{path}: {v!r}; allowed: a number")
    return float(v)


@dataclass(frozen=True)
class TwinDevice:
    """A twin config read once: its simulated device (fixed effects, the population or None, the
    range) and its acceptance limits; ``path`` names it in the output."""

    path: str
    model: SensorModel
    population: Population | None
    range_g: int
    limits: Limits


def load_device(path: str) -> tuple[SensorModel, Population | None, int, Limits]:
    """The simulated device (fixed effects, population or None, range) and limits of a config."""
    d = twin_device(path)
    return d.model, d.population, d.range_g, d.limits


def twin_device(path: str) -> TwinDevice:
    """The config at ``path`` as a TwinDevice: its YAML read once and validated once against the station
    schema (config/schema.py), then taken from the typed sections."""
    try:
        sc = validate_station(load_yaml(path))
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
    return device_of(sc, path)


def device_of(sc: StationConfigSchema, path: str) -> TwinDevice:
    """A validated station config's simulated device and acceptance limits as a TwinDevice."""
    board = sc.device
    if not isinstance(board, SimulatedDevice):
        raise ConfigError(f"{path}: device.driver must be simulated (a twin simulates the lot)")
    effects, epath, pop_spec = load_simulator(board, f"{path}: device")
    chip = get_chip(board.chip or "mma8451", f"{path}: device.chip")
    model = SensorModel.from_config(effects, chip, epath, forward=load_physics(board, f"{path}: device"))
    pop = None if pop_spec is None else parse_population(pop_spec, model.effects, epath.rsplit(".", 1)[0]
                                                         + ".population")
    range_g = board.range_g or chip.default_range_g
    return TwinDevice(path, model, pop, range_g, Limits.from_section(sc.acceptance))


def lot_chunk(a: int, mean: np.ndarray, std: np.ndarray, samples: int, like: LotStats) -> LotChunk:
    D, P, _ = mean.shape
    cols: dict[str, np.ndarray] = {"x": mean[..., 0].ravel(), "y": mean[..., 1].ravel(), "z": mean[..., 2].ravel(),
                                   "n": np.full(D * P, float(samples)), "std_x": std[..., 0].ravel(),
                                   "std_y": std[..., 1].ravel(), "std_z": std[..., 2].ravel()}
    if like.pose_angles:
        cols.update({k: np.tile(v, D) for k, v in like.pose_angles.items()})
    elif like.refs is not None:
        cols.update({f"ref_{c}": np.tile(like.refs[:, i], D) for i, c in enumerate("xyz")})
    serials = [f"S{a + d:08d}" for d in range(D)]
    return LotChunk(serials, np.arange(D + 1) * P, cols, np.tile([f"p{i + 1}" for i in range(P)], D),
                    [None] * D, np.arange(D) * P + 1)


def sim_chunks(model: SensorModel, pop: Population | None, boards: int, like: LotStats, range_g: int,
               seed: int, chunk: int = 4096, x: np.ndarray | None = None) -> Iterator[LotChunk]:
    """Chunks of a simulated lot of ``boards`` boards at ``like``'s poses and samples per pose
    (``x``: given parameter vectors, e.g. the same boards measured again)."""
    if like.refs is None:
        raise ConfigError("twin: the real lot has no pose references; a simulated lot needs its poses")
    rng = np.random.default_rng(seed)
    samples = int(np.median(like.samples)) if like.samples else 1000
    for a in range(0, boards, chunk):
        idx = np.arange(a, min(a + chunk, boards))
        mean, std, _ = pose_means(model, pop, idx, like.refs, samples, rng, range_g=range_g,
                                  x=None if x is None else x[idx])
        yield lot_chunk(a, mean, std, samples, like)


def simulate_like(device: TwinDevice, like: LotStats, boards: int, seed: int, limits: Limits | None = None
                  ) -> tuple[LotStats, Simulated]:
    """Fit and judge a simulated lot like ``like`` from a twin config; its stats and what was simulated."""
    lim = limits if limits is not None else device.limits
    cpg = device.model.chip.counts_per_g(device.range_g)
    stats = collect(sim_chunks(device.model, device.population, boards, like, device.range_g, seed), like.model,
                    cpg, "counts", lim, reservoir=like.reservoir, seed=seed)
    return stats, {"config": device.path, "boards": boards, "population": device.population is not None}


def twin_model(cfg: JsonObject, forward: bool | None = None) -> tuple[SensorModel, int]:
    """The simulated device of a config mapping and its range (``forward``: override its physics)."""
    board = board_section(cfg.get("device"), "device")
    effects, epath, _ = load_simulator(board, "device")
    chip = get_chip(board.chip or "mma8451")
    fwd = load_physics(board, "device") if forward is None else forward
    return SensorModel.from_config(effects, chip, epath, forward=fwd), board.range_g or chip.default_range_g


def board_section(dev: object, where: str) -> SimulatedBoardSection:
    """A config's simulated device (a YAML mapping) as its board section, validated once (config/kinds.py)."""
    keys = {k: v for k, v in dev.items() if k != "driver"} if isinstance(dev, dict) else dev
    return parse(keys, SimulatedBoardSection, where)


def _population(cfg: JsonObject, model: SensorModel) -> Population:
    """The ``device.simulator.population`` of a twin config mapping, parsed."""
    sim = mapping(mapping(cfg, "device", ""), "simulator", "device")
    return parse_population(sim.get("population"), model.effects)


def fixed_board_stats(cfg: JsonObject, like: LotStats, x: np.ndarray, boards: int, seed: int,
                      columns: tuple[str, ...] | None = None) -> np.ndarray:
    """Effect quantities (boards, Q) fitted from one board with parameters ``x`` (the population's
    quantities) measured ``boards`` times like ``like``: the fit's own scatter.  ``x`` (boards, Q):
    given boards, each measured once; ``columns``: these stats columns instead."""
    model, range_g = twin_model(cfg)
    pop = _population(cfg, model)
    xs = np.broadcast_to(x, (boards, x.shape[-1]))
    stats = collect(sim_chunks(model, pop, boards, like, range_g, seed, x=xs), like.model,
                    model.chip.counts_per_g(range_g), "counts", None, reservoir=boards, seed=seed)
    if columns is not None:
        return stats.rows[:, [stats.columns.index(c) for c in columns]]
    return stats.rows[:, 1:1 + len(like.quantities)]


def simulate_cfg(cfg: JsonObject, like: LotStats, boards: int, seed: int, limits: Limits | None = None
                 ) -> LotStats:
    """A simulated lot like ``like`` from a config mapping (its population), fitted and judged."""
    model, range_g = twin_model(cfg)
    pop = _population(cfg, model)
    return collect(sim_chunks(model, pop, boards, like, range_g, seed), like.model, model.chip.counts_per_g(range_g),
                   "counts", limits, reservoir=boards, seed=seed)

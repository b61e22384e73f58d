"""`twin fit`: a lot's population (mixture + changes along the lot) written as a simulator config.

Steps: one streaming pass (stream.collect); changes of each effect quantity's mean along the
lot (changes.find_changes) on the block sums; the reservoir's quantities with the changes
taken out (each board back to the lot's start); per-quantity Student-t marginals where a
quantity's tail is heavy (tails.fit_tails); a mixture by EM on the quantities at Gaussian
scale, the number of components chosen by BIC (mixture.fit_mixture: Student-t components when
no quantity has a t marginal of its own, Gaussian ones when some do); the default simulator config with its
``population:`` replaced (package rotation folded into the coupling); the noise per axis
fitted to the lot's residual and leave-one-out distributions (noise.fit_noise: the stated
per-sample std is the start); the finished twin's residuals checked against the lot's
(reproduce.residual_check) -- a gap, or BIC stopping at its cap, is a warning.
"""
from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..acceptance.rules import Limits
from ..config.checks import load_yaml
from ..config.sections import default_config_path
from ..data.lotfile import SMALL_BLOCK_BYTES, LotChunk, lot_scale, open_lot
from ..errors import ConfigError, DataError
from ..jsontypes import JsonObject
from ..sim.population import Change, Component, Population, Tail, parse_quantity
from ..sim.sensor_model import PHYSICS, SensorModel
from .changes import Found, find_changes
from .mixture import NU_MAX, Mixture, fit_mixture
from .noise import fit_noise
from .physics import CRITERION, board_rows, choose_physics, population_shape
from .records import (
    ComponentReport,
    DistributionTest,
    EffectSpread,
    NoiseFit,
    PhysicsCandidate,
    TailCandidate,
    TwinReport,
)
from .reproduce import residual_check
from .simlot import fixed_board_stats, scalar, section, text, twin_model
from .stream import LotStats, collect, richest_model
from .tails import fit_tails, slope_at_centre, to_gauss

MIXTURE_ROWS = 8000  # rows EM fits (mixture.fit_mixture's max_rows)
DIFFERS_SD = 3.0  # a component carries an effect when a quantity's mean is this many sd from the main one's


@dataclass
class Twin:
    stats: LotStats
    population: Population
    mixture: Mixture
    criterion: list[dict[str, float]]
    changes: list[Found]
    config: JsonObject  # a station config document (YAML), population: replaced
    physics: str = PHYSICS[0]
    physics_candidates: list[PhysicsCandidate] = field(default_factory=list)
    noise: NoiseFit = field(default_factory=lambda: NoiseFit())
    residual_tests: list[DistributionTest] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    tails: list[TailCandidate] = field(default_factory=list)

    def to_dict(self) -> TwinReport:
        names = self.population.names
        main = self.population.components[0]
        comps: list[ComponentReport] = []
        for c in self.population.components:
            # a t component's sd is its scale times sqrt(nu / (nu - 2)); none (null) for nu <= 2
            k = 1.0 if c.dof is None else (float(np.sqrt(c.dof / (c.dof - 2))) if c.dof > 2 else None)
            eff: dict[str, EffectSpread] = {
                n: {"mean": float(m), "sd": None if k is None else float(s) * k, "scale": float(s)}
                for n, m, s in zip(names, c.mean, c.sd, strict=True)}
            scale = np.maximum(main.sd, 1e-12)
            differs = [n for n, d in zip(names, np.abs(c.mean - main.mean) / scale > DIFFERS_SD, strict=True) if d]
            comps.append({"weight": float(c.weight), "dof": c.dof, "effects": eff,
                          "carries": sorted({n.split(".")[0] for n in differs}), "differs_in": differs})
        return {"source_boards": self.stats.boards, "model": self.stats.model, "skipped": self.stats.skipped,
                "criterion": {"name": "BIC", "candidates": self.criterion},
                "physics": {"chosen": self.physics, "criterion": CRITERION, "candidates": self.physics_candidates},
                "components": comps, "noise": self.noise,
                "tails": {"quantities": self.population.tails_config(), "candidates": self.tails,
                          "note": "a quantity with a tail: components hold it at Gaussian scale "
                                  "(sim/population.py)"},
                "residual_check": [{"quantity": t["quantity"], "p_value": t["p_value"], "detected": t["detected"],
                                    "real": t["real"], "sim": t["sim"], "effect": t["effect"]}
                                   for t in self.residual_tests],
                "warnings": self.warnings,
                "changes": [{"quantity": f.quantity, "kind": f.kind, "at_board": f.at_board,
                             "interval": [f.lo_board, f.hi_board], "size": f.size, "p_value": f.p_value}
                            for f in self.changes]}


def lot_stats(path: str | Path, limits: Limits | None = None, reservoir: int = 50_000, chunk_boards: int = 4096,
              model: str | None = None) -> tuple[LotStats, float | None]:
    """One streaming pass over a lot file; returns the stats and its input units per g."""
    # a CSV lot in small blocks, a chunk per block: twin fit's memory has a stated bound
    meta, chunks = open_lot(path, chunk_boards, SMALL_BLOCK_BYTES, gather=False)
    first = next(chunks, None)
    if first is None:
        raise DataError(f"{path}: no boards (no rows after the header)")
    m = model or richest_model(first)
    units, per_g = lot_scale(meta, path, None, None, None, m)

    def all_chunks() -> Iterator[LotChunk]:
        yield first
        yield from chunks

    return collect(all_chunks(), m, per_g, units, limits, reservoir), per_g


def _unshift(rows: np.ndarray, names: list[str], changes: list[Found]) -> np.ndarray:
    """The quantities with every change taken out (each board as at the lot's start)."""
    q = rows[:, 1:1 + len(names)].copy()
    board = rows[:, 0]
    for f in changes:
        after = board >= f.at_board
        shift = f.size if f.kind == "step" else f.size * (board - f.at_board)
        q[:, names.index(f.quantity)] -= np.where(after, shift, 0.0)
    return q


def _population(names: list[str], mix: Mixture, changes: list[Found], tails: dict[str, Tail]) -> Population:
    comps = []
    for k in range(mix.K):
        sd = np.sqrt(np.clip(np.diag(mix.covs[k]), 0.0, None))
        s = np.where(sd > 0, sd, 1.0)
        R = np.where(np.outer(sd > 0, sd > 0), mix.covs[k] / np.outer(s, s), 0.0)
        np.fill_diagonal(R, 1.0)
        R = _nearest_psd(R)
        d = np.sqrt(np.diag(R))
        R = np.clip(R / np.outer(d, d), -1.0, 1.0)
        nu = float(mix.dof[k])
        # a t component's covariance is Sigma nu / (nu - 2): sd reports the scale matrix's
        comps.append(Component(float(mix.weights[k]), mix.means[k].copy(), sd, R,
                               None if nu >= 0.99 * NU_MAX else round(nu, 3)))
    total = sum(c.weight for c in comps)
    comps = [Component(c.weight / total, c.mean, c.sd, c.correlation, c.dof) for c in comps]
    qs = [parse_quantity(n, "population") for n in names]
    ch = [Change(qs[names.index(f.quantity)], f.kind, f.at_board, f.size) for f in changes]
    return Population(qs, comps, ch, dict(tails))


def stated_noise(stats: LotStats) -> np.ndarray | None:
    """Per-axis per-sample sd in counts the lot states (median of its first chunk's std columns)."""
    if not stats.noise_axes:
        return None
    sd = np.asarray(stats.noise_axes[0], dtype=float)
    return sd if np.all(np.isfinite(sd)) and np.all(sd > 0) else None


def twin_config(pop: Population, stats: LotStats, per_g: float | None, base: JsonObject | None = None,
                physics: str = PHYSICS[0], noise_counts: np.ndarray | None = None) -> JsonObject:
    """The default simulator config with ``population:`` replaced (module docstring); noise:
    ``noise_counts`` (per-axis per-sample sd, counts, quantization included), else the stated."""
    cfg: JsonObject = copy.deepcopy(base if base is not None else load_yaml(default_config_path()))
    dev = section(cfg, "device", "")
    sim = section(dev, "simulator", "device")
    eff = section(sim, "effects", "device.simulator")
    cross = eff.get("cross_axis")
    if isinstance(cross, dict):
        cross["rotation_deg"] = [0.0, 0.0, 0.0]  # K = diag(gain) (I + C): C carries it
    sd = noise_counts if noise_counts is not None else stated_noise(stats)
    if sd is not None and per_g:
        model = SensorModel.from_config(eff, text(dev, "chip", "device", "mma8451"))
        odr = dev.get("odr_hz", model.chip.default_odr_hz)
        enbw = model.chip.enbw_hz(scalar(odr, "device.odr_hz"), model.chip.default_dlpf)
        quant = eff.get("quantization", False)  # absent or false: off; true or null: on at 1 LSB
        lsb = 0.0 if quant is False else \
            scalar(quant.get("lsb_counts", 1) if isinstance(quant, dict) else 1, "quantization.lsb_counts")
        white = np.sqrt(np.clip(np.asarray(sd, dtype=float) ** 2 - lsb**2 / 12.0, 0.0, None))
        eff["noise"] = {"density_ug_per_rthz": [round(float(v / per_g / np.sqrt(enbw) * 1e6), 5) for v in white]}
    sim["population"] = pop.to_config()
    sim["physics"] = physics
    return cfg


def fit_twin(stats: LotStats, per_g: float | None, max_components: int = 4, seed: int = 0,
             base: JsonObject | None = None) -> Twin:
    """The twin of a streamed lot (module docstring)."""
    names = stats.quantities
    good = np.all(np.isfinite(stats.rows[:, 1:1 + len(names)]), axis=1) if stats.rows.size else np.zeros(0, bool)
    need = 5 * (len(names) + 2)  # fit_mixture's smallest sample for one component
    if good.sum() < need:
        raise DataError(f"twin fit: {int(good.sum())} fitted boards; a population of {len(names)} parameters "
                        f"(model {stats.model}) needs at least {need}")
    changes = find_changes(stats.block_stats(), names, stats.block)
    X = _unshift(stats.rows[good, :1 + len(names)], names, changes)  # board and quantities: no copy of the rest
    physics, candidates = choose_physics(twin_config(population_shape(names), stats, per_g, base), stats, seed)
    if physics != PHYSICS[0]:
        if len(X) > MIXTURE_ROWS:  # fit_mixture's own subsample, taken before the (costlier) inversion
            X = X[np.random.default_rng(seed).choice(len(X), MIXTURE_ROWS, replace=False)]
        X = board_rows(twin_config(population_shape(names), stats, per_g, base, physics), physics, stats, X)
    tails, tail_report = fit_tails(X, names, seed)
    mix, table = fit_mixture(to_gauss(X, names, tails), max_components=max_components, seed=seed,
                             heavy=not tails, max_rows=MIXTURE_ROWS)
    pop0 = _population(names, mix, changes, tails)
    sd, noise = _lot_noise(pop0, stats, per_g, base, physics, seed)
    cfg0 = twin_config(pop0, stats, per_g, base, physics, sd)
    J = slope_at_centre(names, tails)  # the fit's noise at Gaussian scale, to first order
    noise_cov = _fit_noise_cov(cfg0, mix, stats, seed, physics) * np.outer(J, J)
    mix.covs = np.array([_nearest_psd(S - noise_cov) for S in mix.covs])
    pop = _population(names, mix, changes, tails)
    cfg = twin_config(pop, stats, per_g, base, physics, sd)
    tests, warnings = ([], []) if stats.refs is None else \
        residual_check(cfg, stats, seed + 1, Limits.from_config(_acceptance(cfg)))
    if len(table) == max_components == mix.K:
        warnings.append(f"mixture: BIC chose {mix.K} components, its cap (--components {max_components}): more "
                        "might fit better, or the components stand in for a shape the mixture cannot express "
                        "(e.g. a heavy tail); BIC per candidate in criterion")
    return Twin(stats, pop, mix, table, changes, cfg, physics, candidates, noise, tests, warnings, tail_report)


def _acceptance(cfg: JsonObject) -> JsonObject | None:
    """The config's ``acceptance:`` mapping (None: absent)."""
    acc = cfg.get("acceptance")
    if acc is not None and not isinstance(acc, dict):
        raise ConfigError(f"acceptance: {type(acc).__name__}; allowed: a mapping of limits")
    return acc


def _lot_noise(pop: Population, stats: LotStats, per_g: float | None, base: JsonObject | None, physics: str,
               seed: int) -> tuple[np.ndarray | None, NoiseFit]:
    """Per-axis noise fitted to the lot's residual and LOO distributions (noise.fit_noise)."""
    if stats.refs is None or not per_g:
        return None, NoiseFit()
    start = stated_noise(stats)
    if start is None:  # no std columns: the base config's noise is the start
        model, _ = twin_model(twin_config(pop, stats, per_g, base, physics))
        start = np.asarray(model.noise_sigma_g(model.chip.default_odr_hz), dtype=float) * per_g
        start = np.sqrt(start**2 + 1.0 / 12.0)

    def config_for(sd: np.ndarray) -> JsonObject:
        return twin_config(pop, stats, per_g, base, physics, sd)

    return fit_noise(config_for, start, stats, seed + 2)



def _nearest_psd(S: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh((S + S.T) / 2)
    return (v * np.clip(w, 0.0, None)) @ v.T


def _fit_noise_cov(cfg: JsonObject, mix: Mixture, stats: LotStats, seed: int, physics: str,
                   boards: int = 2000) -> np.ndarray:
    """The covariance the fit's own noise adds to every board's quantities: one fixed board (the
    main component's mean) measured ``boards`` times at the lot's poses and samples, fitted.
    A component's covariance minus this is the spread of the boards themselves (deconvolution)."""
    names = stats.quantities
    if stats.refs is None:  # no pose references (model 9): nothing to simulate the fit's scatter at
        return np.zeros((len(names), len(names)))
    q = fixed_board_stats(cfg, stats, mix.means[0], boards, seed)
    X = board_rows(cfg, physics, stats, q[np.all(np.isfinite(q), axis=1)])  # in the population's terms
    return np.cov(X.T) if len(X) > len(names) else np.zeros((len(names), len(names)))

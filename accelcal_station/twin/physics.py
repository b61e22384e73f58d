"""Which simulator physics (``simulator.physics``: implicit | forward) a twin simulates with,
chosen from the lot's own residuals, and the forward model's board parameters.

Model 15's effect quantities (stream.effect_quantities) are the implicit chain's parameters
exactly (``f = K^-1 (G - o) - c G^3``).  Under forward physics (``G = o + u + c u^3``,
``u = K f``) the fit only approximates: a noise-free board's fitted quantities are
``phi = h(theta)``, with e.g. a cubic 0.015 1/g^2 fitted as ~0.013 at an4399-8's poses and a
residual of ~0.4 mg.  :func:`invert_forward` solves ``h(theta) = phi`` per board by the fixed
point ``theta <- theta + (phi - h(theta))`` (h is near the identity; the cubic's error shrinks
~8x per step), h evaluated by the simulator's chain without noise and the stacked fitter.

The choice (:func:`choose_physics`): up to ``PLUGIN_BOARDS`` of the lot's own boards, as
fitted, are simulated again under each physics (forward: their inverted parameters) with
the lot's noise and poses; the physics whose residual RMS and leave-one-out RMS distributions
are nearer the lot's (smaller sum of the two Anderson-Darling k-sample statistics) is chosen.
The data decide, not knowledge of the generator: an implicit lot has model-15 residuals of
noise only, which forward physics cannot reproduce on its cubic boards, and vice versa.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..jsontypes import JsonObject
from ..lot.streaming import fit_chunk
from ..sim.lot_physics import board_parameters, enabled_effects, response_g, true_force_g
from ..sim.population import Component, Population, parse_quantity
from ..sim.sensor_model import PHYSICS, SensorModel
from .compare import anderson
from .records import PhysicsCandidate
from .simlot import fixed_board_stats, lot_chunk, mapping, twin_model
from .stream import LotStats, effect_quantities

PLUGIN_BOARDS = 3000  # boards re-simulated per physics: the wrong one measured at p ~ 1e-32 (10 % cubic boards)
INVERT_STEPS = 4


def population_shape(names: list[str]) -> Population:
    """One standard component over these quantities (a placeholder population)."""
    qs = [parse_quantity(n, "twin") for n in names]
    return Population(qs, [Component(1.0, np.zeros(len(qs)), np.zeros(len(qs)), np.eye(len(qs)))])


def fitted_noise_free(model: SensorModel, names: list[str], theta: np.ndarray, like: LotStats, range_g: int,
                      chunk: int = 4096) -> np.ndarray:
    """h(theta): the effect quantities (n, Q) model ``like.model`` fits to noise-free boards with
    parameters ``theta`` (n, Q) at ``like``'s poses, under ``model``'s physics."""
    assert like.refs is not None
    pop, cpg = population_shape(names), model.chip.counts_per_g(range_g)
    on = enabled_effects(model, pop)
    out = np.full_like(theta, np.nan)
    rng = np.random.default_rng(0)  # pose scatter only; the twin's base config has none
    for a in range(0, len(theta), chunk):
        x = theta[a:a + chunk]
        prm = board_parameters(model, pop, x, len(x))
        G = response_g(prm, on, true_force_g(prm, on, like.refs, rng), 25.0, model.forward)
        res = fit_chunk(lot_chunk(a, G * cpg, np.ones_like(G), 1000, like), like.model, cpg, "counts")
        out[a:a + chunk] = effect_quantities(res["W"], res["V"], res["Gamma"], like.model)
    return out


def invert_forward(model: SensorModel, names: list[str], phi: np.ndarray, like: LotStats, range_g: int
                   ) -> np.ndarray:
    """theta with h(theta) = phi per board under forward physics (module docstring); rows that
    do not fit keep phi."""
    theta = phi.copy()
    for _ in range(INVERT_STEPS):
        step = phi - fitted_noise_free(model, names, theta, like, range_g)
        theta = np.where(np.isfinite(step), theta + np.nan_to_num(step), theta)
    return theta


def board_rows(cfg: JsonObject, physics: str, like: LotStats, phi: np.ndarray) -> np.ndarray:
    """The simulator's board parameters of fitted quantities ``phi`` under ``physics``."""
    if physics == PHYSICS[0]:
        return phi
    model, range_g = twin_model(cfg, forward=True)
    return invert_forward(model, like.quantities, phi, like, range_g)


def choose_physics(cfg: JsonObject, like: LotStats, seed: int) -> tuple[str, list[PhysicsCandidate]]:
    """The physics whose re-simulated boards' residuals are nearest the lot's (module docstring),
    and every candidate's statistics."""
    Q = len(like.quantities)
    keep = np.flatnonzero(np.all(np.isfinite(like.rows[:, 1:1 + Q]), axis=1))
    if like.model != "15" or like.refs is None or not len(keep):
        return PHYSICS[0], []  # no cubic term fitted (or no poses to simulate at): the two are one
    rng = np.random.default_rng(seed)
    # the plug-in boards only are copied out of the reservoir (50,000 rows), not every finite row first
    rows = like.rows[keep[rng.choice(len(keep), min(PLUGIN_BOARDS, len(keep)), replace=False)]]
    out: list[PhysicsCandidate] = []
    for physics in PHYSICS:
        theta = board_rows(cfg, physics, like, rows[:, 1:1 + Q])
        sim = fixed_board_stats({**cfg, "device": _with_physics(mapping(cfg, "device", ""), physics)}, like, theta,
                                len(theta), seed, columns=("residual_rms_mg", "crossval_rms_mg"))
        res, loo = (anderson(like.column(name)[np.isfinite(like.column(name))], sim[np.isfinite(sim[:, k]), k])
                    for k, name in enumerate(("residual_rms_mg", "crossval_rms_mg")))
        out.append({"physics": physics, "score": res[0] + loo[0],
                    "residual_rms_mg": {"statistic": res[0], "p_value": res[1]},
                    "crossval_rms_mg": {"statistic": loo[0], "p_value": loo[1]}})
    return str(min(out, key=lambda c: float(c["score"]))["physics"]), out


def _with_physics(dev: JsonObject, physics: str) -> JsonObject:
    sim = dev.get("simulator") or {}
    if not isinstance(sim, dict):
        raise ConfigError(f"device.simulator: {type(sim).__name__}; allowed: a mapping (a twin config's)")
    return {**dev, "simulator": {**sim, "physics": physics}}


CRITERION = ("the lot's own boards (as fitted; forward: their parameters inverted through forward physics) "
             "simulated again under each physics; chosen: the smaller sum of the Anderson-Darling "
             "k-sample statistics of residual RMS and leave-one-out RMS against the lot's")

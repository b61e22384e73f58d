"""Many simulated boards at once: the sensor chain of sensor_model.py, vectorised over boards.

Each board has its own parameters (``(D, ...)`` arrays per effect parameter, from
:func:`board_parameters`); the chain is the same as ``SensorModel.response_g`` (stages
1-4), then the pose mean of ``samples`` noisy samples (stage 7): white noise of
``density * sqrt(ENBW)`` per sample plus the quantization's ``lsb^2 / 12`` (stage 10, as
variance: the mean of many integer samples is not an integer), clipped at the code range
(stage 9).  ``drift`` and ``settling`` need a capture's time line and are refused here
(a board captured by the station, drivers/simulated.py, has them).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from .population import Population
from .sensor_model import CHIP_DEFAULT, EFFECTS, SensorModel, rotation_matrix

TIMED = ("drift", "settling")


def board_parameters(model: SensorModel, pop: Population | None, x: np.ndarray | None, D: int
                     ) -> dict[str, dict[str, np.ndarray]]:
    """Every catalog parameter per board (D, *shape): the fixed value (or the neutral default)
    broadcast, with the population's quantities (columns of ``x``) set per board."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, eff in EFFECTS.items():
        if name in TIMED:
            continue
        out[name] = {}
        for p in eff.params:
            if p.integer:
                continue
            v = model._p(name, p.name)
            # a disabled effect's datasheet default (noise density "chip"): the chip's figure
            v = np.asarray([model.chip.noise_ug_per_rthz] * 3 if isinstance(v, str) and v == CHIP_DEFAULT else v,
                           dtype=float)
            out[name][p.name] = np.broadcast_to(v, (D,) + v.shape).copy()
    if pop is not None and x is not None:
        for k, q in enumerate(pop.quantities):
            out[q.effect][q.param][(slice(None),) + q.index] = x[:, k]
    return out


def enabled_effects(model: SensorModel, pop: Population | None) -> set[str]:
    on = set(model.enabled) | ({q.effect for q in pop.quantities} if pop is not None else set())
    timed = sorted(on & set(TIMED))
    if timed:
        raise ConfigError(f"simulator.effects: {', '.join(timed)} need a capture's time line; a simulated lot "
                          "has pose means only (leave them out, or run boards through the station)")
    return on


def true_force_g(prm: dict[str, dict[str, np.ndarray]], on: set[str], ref: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
    """Stage 1: f = (local_g / g0) R_jig R_scatter ref, (D, P, 3) in standard g."""
    D, P = prm["offset"]["offset_mg"].shape[0], len(ref)
    f = np.broadcast_to(ref, (D, P, 3)).copy()
    if "pose_error" in on:
        R = rotation_matrix(prm["pose_error"]["jig_rotation_deg"])[:, None]  # (D, 1, 3, 3)
        sc = prm["pose_error"]["scatter_deg"][:, None, None] * rng.standard_normal((D, P, 3))
        R = R @ rotation_matrix(sc)
        f = np.einsum("dpij,dpj->dpi", R, f)
    if "gravity" in on:
        f *= (prm["gravity"]["local_mps2"] / 9.80665)[:, None, None]
    return f


def response_g(prm: dict[str, dict[str, np.ndarray]], on: set[str], f: np.ndarray, temp_c: float,
               forward: bool = False) -> np.ndarray:
    """Stages 2-4 per board: G solves f = K^-1 (G - o) - q G^2 - c G^3 (Newton), or with
    ``forward`` the sensor's own response G = o + u + q u^2 + c u^3, u = K f."""
    t = prm["temperature"]
    dt = temp_c - t["t_ref_c"] if "temperature" in on else np.zeros(len(f))
    ppm = t["gain_ppm_per_c"] * dt[:, None] + t["gain_ppm_per_c2"] * dt[:, None] ** 2 \
        if "temperature" in on else 0.0
    gain = (prm["gain"]["gain"] if "gain" in on else 1.0) * (1.0 + 1e-6 * ppm)
    gain = np.broadcast_to(gain, (len(f), 3))
    K = gain[:, :, None] * np.eye(3)
    if "cross_axis" in on:
        c = prm["cross_axis"]
        K = K @ (np.eye(3) + c["coupling"]) @ np.swapaxes(rotation_matrix(c["rotation_deg"]), -1, -2)
    o_mg = prm["offset"]["offset_mg"] if "offset" in on else np.zeros((len(f), 3))
    if "temperature" in on:
        o_mg = o_mg + t["offset_mg_per_c"] * dt[:, None] + t["offset_mg_per_c2"] * dt[:, None] ** 2
    o = 1e-3 * o_mg[:, None, :]
    q = prm["quadratic"]["quadratic_per_g"][:, None, :] if "quadratic" in on else 0.0 * o
    cu = prm["cubic"]["cubic_per_g2"][:, None, :] if "cubic" in on else 0.0 * o
    u = np.einsum("dij,dpj->dpi", K, f)
    if forward:
        return o + u + q * u**2 + cu * u**3
    G = o + u
    if not (np.any(q) or np.any(cu)):
        return G
    for _ in range(60):  # Newton on F(G) = o + K (f + q G^2 + c G^3) - G
        F = o + np.einsum("dij,dpj->dpi", K, f + q * G**2 + cu * G**3) - G
        J = K[:, None] * (2 * q * G + 3 * cu * G**2)[:, :, None, :] - np.eye(3)
        step = np.linalg.solve(J, -F[..., None])[..., 0]
        G = G + step
        if np.max(np.abs(step)) < 1e-14 * max(1.0, float(np.max(np.abs(G)))):
            break
    return G


@dataclass(frozen=True)
class Conditions:
    """How the boards are measured, beyond the samples and range: the output data rate (None: the chip's
    default), the temperature in C, and the nonlinearity's physics (``forward``; None: the model's,
    ``simulator.physics``)."""

    odr_hz: float | None = None
    temp_c: float = 25.0
    forward: bool | None = None


def pose_means(model: SensorModel, pop: Population | None, boards: np.ndarray, ref: np.ndarray, samples: int,
               rng: np.random.Generator, *, range_g: int = 2, x: np.ndarray | None = None,
               conditions: Conditions = Conditions()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose means (D, P, 3) and per-sample std (D, P, 3) in counts of the boards with these lot
    indices, and their parameter vectors (D, Q) (drawn from ``pop`` unless ``x`` is given), measured
    under ``conditions``."""
    odr_hz, temp_c, forward = conditions.odr_hz, conditions.temp_c, conditions.forward
    D = len(boards)
    on = enabled_effects(model, pop)
    if pop is not None and x is None:
        x = pop.draw(boards, rng)
    prm = board_parameters(model, pop, x, D)
    G = response_g(prm, on, true_force_g(prm, on, ref, rng), temp_c, model.forward if forward is None else forward)
    chip = model.chip
    cpg = chip.counts_per_g(range_g)
    enbw = chip.enbw_hz(odr_hz or chip.default_odr_hz, chip.default_dlpf)
    sd = prm["noise"]["density_ug_per_rthz"] * 1e-6 * np.sqrt(enbw) * cpg if "noise" in on else np.zeros((D, 3))
    lsb = float(model.effects["quantization"]["lsb_counts"]) if "quantization" in on else 0.0
    sd = np.sqrt(sd**2 + lsb**2 / 12.0)[:, None, :] * np.ones((1, len(ref), 1))
    mean = G * cpg + sd / np.sqrt(samples) * rng.standard_normal(G.shape)
    if "saturation" in on:
        lo, hi = chip.code_limits
        frac = float(model.effects["saturation"]["full_scale_fraction"])
        mean = np.clip(mean, lo * frac, hi * frac)
    # the sample std of `samples` draws: sd * sqrt(chi2_{n-1} / (n-1))
    s = sd * np.sqrt(rng.chisquare(max(samples - 1, 1), G.shape) / max(samples - 1, 1))
    return mean, s, (np.zeros((D, 0)) if x is None else x)


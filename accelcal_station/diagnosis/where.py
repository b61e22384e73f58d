"""Where the baseline's held-out gap lies (engine's module doc, step 2): by pose, axis, input level,
temperature and acquisition order in the static view, by time in capture in the time view, the noise
against the simulator's, and the Allan deviation of the longest capture."""
from __future__ import annotations

from typing import TypedDict

import numpy as np

from .evaluation import Evaluation
from .gap_data import Capture, GapData, TimeData
from .loading import Simulator
from .noise_floor import Floor, random_var
from .order import order_position

STAND_OUT_ALPHA = 0.01  # a pose stands out when its held-out chi^2 is beyond the 1 - 0.01/P point
LEVEL_EDGES_G = np.array([-1.5, -0.6, -0.2, 0.2, 0.6, 1.5])  # input-level bins of the by_level breakdown


class PoseGap(TypedDict):
    """A pose's held-out residual over its predicted spread (RMS over its components), and whether it
    stands out: its chi^2 on those components beyond the 1 - alpha/P point (Bonferroni over the poses)."""

    pose: str
    z_rms: float
    residual_mg: list[float]
    stands_out: bool
    p_value: float


class LevelBin(TypedDict):
    axis: str
    level_g: list[float]
    poses: int
    mean_residual_mg: float
    gap: float | None


class OrderBlock(TypedDict):
    block: int
    position: list[float]
    poses: int
    gap: float | None
    mean_residual_mg: list[float]


class TemperatureGap(TypedDict):
    temp_c: float
    gap: float | None
    mean_residual_mg: list[float]


class TimeBlock(TypedDict):
    t_s: float
    gap: float | None
    toward_step_mg: float


class NoiseCheck(TypedDict):
    """The data's per-sample sigma per axis against the simulator's, mg."""

    sigma_mg: list[float]
    simulator_sigma_mg: list[float]
    ratio: list[float]
    rate_hz: float


class AllanCheck(TypedDict):
    """Allan deviation per axis of the longest capture against the white level, mg."""

    tau_s: list[float]
    adev_mg: list[list[float]]
    white_mg: list[list[float]]
    ratio_at_longest_tau: list[float]


class Where(TypedDict, total=False):
    """Where the baseline's held-out gap lies (diagnose --json ``where``): each part present when its
    view or data is (gaps: held-out ratio to the floor, None where a part has no variance)."""

    views: dict[str, float | None]
    by_pose: list[PoseGap]
    by_axis: dict[str, float | None]
    by_level: list[LevelBin]
    by_order: list[OrderBlock]
    by_temperature: list[TemperatureGap]
    by_time_in_capture: list[TimeBlock]
    by_axis_time: dict[str, float | None]
    noise: NoiseCheck
    allan: AllanCheck
    max_reading_g: float


def _ratio(r: np.ndarray, v: np.ndarray) -> float | None:
    r, v = np.asarray(r), np.asarray(v)
    return float(np.sqrt(np.sum(r**2) / np.sum(v))) if r.size and np.sum(v) > 0 else None


def allan(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of one axis at octave cluster sizes: (tau_s, adev)."""
    n = len(x)
    c = np.concatenate([[0.0], np.cumsum(x)])
    ms = 2 ** np.arange(0, max(1, int(np.log2(max(n // 4, 1))) + 1))
    out = []
    for m in ms:
        avg = (c[m:] - c[:-m]) / m
        d = avg[m:] - avg[:-m]
        out.append(np.sqrt(0.5 * np.mean(d**2)) if len(d) else np.nan)
    return ms / rate_hz, np.array(out)


def _by_level(data: GapData, r: np.ndarray, v: np.ndarray) -> list[LevelBin]:
    """Mean residual and gap of the poses in each input-level bin, per channel."""
    edges = LEVEL_EDGES_G
    lv: list[LevelBin] = []
    for c, a in enumerate("xyz"):
        rc = r[:, c] if not data.norm_only else r[:, 0]
        vc = v[:, c] if not data.norm_only else v[:, 0]
        b = np.digitize(data.g[:, c], edges[1:-1])
        for k in range(len(edges) - 1):
            m = b == k
            if m.any():
                lv.append({"axis": a, "level_g": [float(edges[k]), float(edges[k + 1])], "poses": int(m.sum()),
                           "mean_residual_mg": float(1e3 * rc[m].mean()), "gap": _ratio(rc[m], vc[m])})
    return lv


ORDER_BLOCKS = 8  # the order view: poses in eight blocks of acquisition order


def _by_order(data: GapData, r: np.ndarray, v: np.ndarray) -> list[OrderBlock]:
    """Gap and mean residual per axis in blocks of acquisition order (row order within each file: a
    pose table's rows are taken in that order, docs/pose-table.md)."""
    s = order_position(data)
    blk = np.minimum(((s + 1) / 2 * ORDER_BLOCKS).astype(int), ORDER_BLOCKS - 1)
    return [{"block": int(k), "position": [float(k / ORDER_BLOCKS), float((k + 1) / ORDER_BLOCKS)],
             "poses": int(np.sum(blk == k)), "gap": _ratio(r[blk == k], v[blk == k]),
             "mean_residual_mg": (1e3 * r[blk == k].mean(axis=0)).tolist()} for k in np.unique(blk)]


def pose_gaps(data: GapData, r: np.ndarray, v: np.ndarray, k: int) -> list[PoseGap]:
    """The k poses of largest standardised held-out residual, each with whether it stands out (PoseGap)."""
    from scipy import stats

    z = np.sqrt(np.mean(r**2 / v, axis=1))
    p = stats.chi2.sf(np.sum(r**2 / v, axis=1), r.shape[1])
    return [{"pose": data.names[i], "z_rms": float(z[i]), "residual_mg": (1e3 * r[i]).tolist(),
             "stands_out": bool(p[i] < STAND_OUT_ALPHA / data.P), "p_value": float(p[i])} for i in np.argsort(-z)[:k]]


def _static_where(data: GapData, r: np.ndarray, v: np.ndarray) -> Where:
    """The static view's gap by pose (the five worst), axis, input level and temperature."""
    w: Where = {}
    w["by_pose"] = pose_gaps(data, r, v, 5)
    if not data.norm_only:
        w["by_axis"] = {a: _ratio(r[:, c], v[:, c]) for c, a in enumerate("xyz")}
    w["by_level"] = _by_level(data, r, v)
    w["by_order"] = _by_order(data, r, v)
    if data.temp_c is not None and data.n_temps >= 2:
        tk = np.round(data.temp_c / 2.0)
        w["by_temperature"] = [{"temp_c": float(np.mean(data.temp_c[tk == t])), "gap": _ratio(r[tk == t], v[tk == t]),
                                "mean_residual_mg": (1e3 * r[tk == t].mean(axis=0)).tolist()}
                               for t in np.unique(tk)]
    return w


def _time_where(td: TimeData, r: np.ndarray, v: np.ndarray) -> Where:
    """The time view's gap by time in capture (eight blocks; the lean toward the last move) and by axis."""
    blk = np.round(td.t_in / max(np.max(td.t_in), 1e-9) * 7).astype(int)
    proj = np.sign(td.step_unit[td.unit, td.axis]) * r
    return {"by_time_in_capture": [{"t_s": float(np.mean(td.t_in[blk == k])), "gap": _ratio(r[blk == k], v[blk == k]),
                                    "toward_step_mg": float(1e3 * np.mean(proj[blk == k]))}
                                   for k in np.unique(blk)],
            "by_axis_time": {a: _ratio(r[td.axis == c], v[td.axis == c]) for c, a in enumerate("xyz")}}


def _noise_where(data: GapData, sim: Simulator, floor: Floor, td: TimeData | None) -> NoiseCheck | None:
    """The data's per-sample sigma against the simulator's (None without a within-pose spread)."""
    sim_rand = np.sqrt(random_var(floor.simulator_sigma_g, floor.q_g))
    if td is not None:
        meas = np.sqrt(np.nanmean(td.diff_var, axis=0))
    elif data.std_g is not None:
        meas = np.sqrt(np.mean(data.std_g**2, axis=0))
    else:
        return None
    return {"sigma_mg": (1e3 * meas).tolist(), "simulator_sigma_mg": (1e3 * sim_rand).tolist(),
            "ratio": (meas / np.where(sim_rand > 0, sim_rand, np.nan)).tolist(), "rate_hz": data.rate_hz or sim.odr_hz}


def _allan_where(captures: list[Capture], td: TimeData, rate_hz: float) -> AllanCheck:
    """Allan deviation of the longest capture against the white level of the within-capture spread."""
    longest = max(captures, key=lambda c: len(c.t))
    x = longest.x / longest.per_g
    taus, ad = zip(*[allan(x[:, a], rate_hz) for a in range(3)], strict=True)
    white = np.sqrt(np.nanmean(td.diff_var, axis=0))[:, None] / np.sqrt(taus[0] * rate_hz)[None]
    return {"tau_s": taus[0].tolist(), "adev_mg": (1e3 * np.array(ad)).tolist(), "white_mg": (1e3 * white).tolist(),
            "ratio_at_longest_tau": (np.array(ad)[:, -1] / white[:, -1]).tolist()}


def breakdown(data: GapData, sim: Simulator, floor: Floor, base: Evaluation, after: Evaluation,
              td: TimeData | None) -> Where:
    """Where the baseline's held-out gap lies (module doc); ``after``: the final model (not broken down)."""
    # held-out RMS over the floor's, as the headline and the text give them (Evaluation.floor_gap)
    w: Where = {"views": {"static": base.floor_gap("static"), "time": base.floor_gap("time")}}
    if base.r_static is not None and base.v_static is not None:
        w.update(_static_where(data, base.r_static, base.v_static))
    if td is not None and base.r_time is not None and base.v_time is not None:
        w.update(_time_where(td, base.r_time, base.v_time))
    noise = _noise_where(data, sim, floor, td)
    if noise is not None:
        w["noise"] = noise
    if data.captures is not None and data.rate_hz and td is not None:  # td: None when captures are too short
        w["allan"] = _allan_where(data.captures, td, data.rate_hz)
    w["max_reading_g"] = float(np.max(np.abs(data.g)))
    return w

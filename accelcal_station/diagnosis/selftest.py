"""The self-check of `accelcal diagnose`: boards made by forward physics, the diagnosis fits its own terms.

Every case builds a simulated board (SimulatedBoard with ``SensorModel.forward``: reading
= S a + c (S a)^3 + b, then quantised; temperature acts on the physical offset and gain),
a configuration without the effect under test, and checks what the diagnosis names:

* catalog effects: the withheld effect named first (deterministic ones with the held-out
  residual RMS at least halved), or nothing when the data cannot reveal it;
* off-catalog effects (a product term between axes, a fixed tilt per face that repeats
  on revisit, 1/f flicker noise on raw data, hysteresis by approach direction):
  ``unexplained`` with nothing selected;
* two-effect cases (cubic + temperature; drift + settling on raw data): both named;
* null cases: nothing named, ``nothing to explain``.
"""
from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import NotRequired, TypedDict

import numpy as np

from ..data.rawlog import RawLog
from ..drivers.simulated import SimulatedBoard
from ..fixtures.base import PoseSpec
from ..fixtures.designs import get_design
from ..fixtures.simulated_jig import SimulatedJig
from ..jsontypes import JsonObject
from ..session import PoseRecord, Session
from ..sim.sensor_model import EFFECT_NAMES, EffectsConfig, rotation_matrix
from .candidates import candidates
from .engine import diagnose
from .gap_data import GapData, time_data
from .loading import Simulator, gap_data, load_simulator, raw_part
from .selection import ALPHA

Effects = EffectsConfig  # effect name -> its parameters (a simulator's effects section)
Case = tuple[str, str, tuple[str, ...], str | None, str]  # (case, data kind, withheld, off-catalog term, expect)

SELFTEST_EFFECTS: Effects = {
    "offset": {"offset_mg": [18.0, -27.0, 41.0]},
    "gain": {"gain": [1.012, 0.987, 1.021]},
    "cross_axis": {"coupling": [[0.0, 0.006, -0.004], [0.008, 0.0, 0.005], [-0.007, 0.003, 0.0]],
                   "rotation_deg": [0.3, -0.5, 0.8]},
    "cubic": {"cubic_per_g2": [0.003, -0.002, 0.004]},
    "quadratic": {"quadratic_per_g": [0.002, -0.003, 0.0025]},
    "temperature": {"offset_mg_per_c": [0.2, -0.15, 0.25], "gain_ppm_per_c": [100.0, -80.0, 120.0]},
    "pose_error": {"jig_rotation_deg": [0.5, -0.3, 0.2], "scatter_deg": 0.1},
    "gravity": {"local_mps2": 9.79},
    "noise": {"density_ug_per_rthz": [300.0, 300.0, 300.0]},
    "quantization": {"lsb_counts": 64},
    "saturation": {"full_scale_fraction": 0.9},
    "drift": {"warmup_mg": [15.0, -10.0, 20.0], "warmup_tau_s": 60.0, "random_walk_ug_per_rts": [5.0, 5.0, 5.0]},
    "settling": {"fraction": 0.02, "tau_s": 1.0},
}
SELFTEST_DATA = {"quantization": "raw", "drift": "raw", "settling": "raw", "temperature": "refs-3T"}
OFF_CATALOG = {"product": "refs-revisit", "face_tilt": "refs-revisit", "flicker": "raw", "hysteresis": "refs-revisit"}
PAIRS = {("cubic", "temperature"): "refs-3T", ("drift", "settling"): "raw"}
PRODUCT_K = 0.02  # z reads k x y (g)
FACE_TILT_DEG = 0.15  # a fixed tilt per orientation, repeated on every visit
FLICKER_MG = 0.6  # RMS of the 1/f noise over the log
HYSTERESIS_MG = 1.0  # each axis reads +-h by the sign of its last input change
SELFTEST_DESIGN = "optimal-24"
SELFTEST_SAMPLES = {"refs": 200, "raw": 1000}
# one case's outcome ("pass" is a keyword: the functional form)
CaseResult = TypedDict("CaseResult", {
    "case": str, "kind": str, "data": str, "named": str | None, "selected": list[str], "verdict": str,
    "left": str | None, "gap_before": float, "gap_after": float, "rms_mg_before": float, "rms_mg_after": float,
    "rms_mg_after_named": float, "revealable": bool, "reason": str | None, "pass": bool})


class SelfTestResult(TypedDict):
    """`accelcal diagnose --selftest --json`: every case, the test's settings, and what each data kind reveals."""

    cases: list[CaseResult]
    alpha: float
    seed: int
    design: str
    samples_per_pose: dict[str, int]
    physics: str
    passed: bool
    coverage: NotRequired[dict[str, dict[str, str]]]  # effect -> data kind -> testable, or why not


KINDS = {"refs": "pose table with references, one temperature", "refs-3T": "pose table with references, 0/25/50 C",
         "refs-revisit": "pose table with references, every pose visited twice (second pass reversed)",
         "norm": "pose table without references", "raw": "raw log (no references)"}
STOCHASTIC_CASES = ("pose_error", "noise", "quantization")


def _scenario(effect: str | None, base: Effects) -> tuple[Effects, Effects]:
    """(board effects, configuration effects) of a self-test case: the board has the effect, the config not."""
    base = {k: dict(v or {}) for k, v in base.items()}
    if effect is None or effect not in SELFTEST_EFFECTS:
        return base, base
    if effect in ("noise", "quantization"):  # enabled in the config; the board's value differs
        board = {**base, effect: {**base.get(effect, {}), **SELFTEST_EFFECTS[effect]}}
        return board, {**base, effect: base.get(effect, {})}
    if effect == "gain":  # a full cross_axis matrix would fit the gains too
        base.pop("cross_axis", None)
    board = {**base, effect: base.get(effect) or SELFTEST_EFFECTS[effect]}
    return board, {k: v for k, v in base.items() if k != effect}


def _board(device: JsonObject, effects: Effects, seed: int = 0, forward: bool = False) -> SimulatedBoard:
    """A board of the configuration's chip, range and rate with these effects."""
    cfg = {k: v for k, v in device.items() if k in ("chip", "range_g", "odr_hz", "dlpf")}
    board = SimulatedBoard.from_config({**cfg, "effects": effects}, seed=seed, path="selftest")
    board.model.forward = forward
    return board


def _flicker(n: int, rms_g: float, rng: np.random.Generator) -> np.ndarray:
    """1/f noise (power spectral density ~ 1/f) by shaping white noise in frequency, (n, 3), in g."""
    spec = np.fft.rfft(rng.standard_normal((n, 3)), axis=0)
    f = np.arange(spec.shape[0], dtype=float)
    f[0] = np.inf
    x = np.fft.irfft(spec / np.sqrt(f)[:, None], n, axis=0)
    return rms_g * (x - x.mean(0)) / x.std(0)


def _extra_g(extra: str | None, pose: PoseSpec, prev_ref: np.ndarray | None, x_g: np.ndarray,
             tilt: dict[tuple[float, ...], np.ndarray], seed: int) -> np.ndarray:
    """An off-catalog term added to one capture's samples (g, before quantization)."""
    if extra == "product":
        return np.broadcast_to(PRODUCT_K * np.array([0.0, 0.0, 1.0]) * x_g[:, :1] * x_g[:, 1:2], x_g.shape)
    if extra == "face_tilt":
        key = tuple(np.round(pose.reference_g, 3))
        if key not in tilt:  # drawn once per orientation: every revisit repeats it exactly
            rng = np.random.default_rng([seed, len(tilt)])
            tilt[key] = rotation_matrix(rng.normal(0.0, FACE_TILT_DEG, 3))
        return np.broadcast_to(tilt[key] @ pose.reference_g - pose.reference_g, x_g.shape)
    if extra == "hysteresis" and prev_ref is not None:
        step = np.round(pose.reference_g - prev_ref, 1)
        return np.broadcast_to(1e-3 * HYSTERESIS_MG * np.sign(step), x_g.shape)
    return np.zeros_like(x_g)


@cache
def _design(name: str) -> tuple[PoseSpec, ...]:
    return tuple(get_design(name))  # an optimal design is searched for: seconds, so once per process


def _poses(kind: str) -> list[PoseSpec]:
    """The design in a fixed shuffled order: optimal-N lists its poses sorted by x, so every x term would
    follow acquisition order and be confounded with a change over the session (diagnosis/order.py)."""
    design = _design(SELFTEST_DESIGN)
    poses = [design[i] for i in np.random.default_rng(0).permutation(len(design))]
    return poses + poses[::-1] if kind == "refs-revisit" else poses


def simulate_data(device: JsonObject, effects: Effects, kind: str, seed: int,
                  extra: str | None = None) -> GapData:
    """Data of one kind from a forward-physics board with ``effects`` and an optional off-catalog term."""
    lsb = effects.get("quantization", {}).get("lsb_counts", 1) if "quantization" in effects else None
    board = _board(device, {k: v for k, v in effects.items() if k != "quantization"}, seed, forward=True)
    jig = SimulatedJig(board, move_time_s=2.0)
    temps = [0.0, 25.0, 50.0] if kind == "refs-3T" else [25.0]
    n = SELFTEST_SAMPLES["raw" if kind == "raw" else "refs"]
    records: list[tuple[PoseSpec, float, np.ndarray]] = []
    chunks: list[tuple[np.ndarray, np.ndarray]] = []
    tilt: dict[tuple[float, ...], np.ndarray] = {}
    prev: np.ndarray | None = None
    for T in temps:
        board.set_temperature(T)
        for pose in _poses(kind):
            jig.present(pose)
            x, t = board.read(n)
            x = np.asarray(x, float) + board.counts_per_g * _extra_g(extra, pose, prev, x / board.counts_per_g,
                                                                    tilt, seed)
            prev = pose.reference_g
            chunks.append((t, x))
            records.append((pose, T, x))
    x_all = np.concatenate([c for _, c in chunks])
    if extra == "flicker":
        x_all = x_all + board.counts_per_g * _flicker(len(x_all), 1e-3 * FLICKER_MG, np.random.default_rng(seed))
    if lsb is not None:
        x_all = np.round(x_all / lsb) * lsb
    if kind == "raw":
        t = np.concatenate([t for t, _ in chunks])
        log = RawLog(t, x_all, np.arange(len(t)), f"selftest-{kind}", ["t", "x", "y", "z"], board.odr_hz, True)
        return gap_data([raw_part(log, "counts", board.counts_per_g)], rate_hz=board.odr_hz)
    return _table(board, records, np.split(x_all, len(records)), kind, temps)


def _table(board: SimulatedBoard, records: list[tuple[PoseSpec, float, np.ndarray]], xs: list[np.ndarray],
           kind: str, temps: list[float]) -> GapData:
    """The pose table of one kind: each capture's mean, std and n (names made unique where poses repeat)."""
    rows = []
    for k, ((pose, T, _), c) in enumerate(zip(records, xs, strict=True)):
        name = pose.name if len(temps) == 1 else f"{pose.name}@{T:g}C"
        if kind == "refs-revisit":
            name = f"{name}#{k}"
        rows.append(PoseRecord(name, c.mean(0), c.std(0, ddof=1), len(c), None if kind == "norm" else pose.reference_g,
                               pose.pitch_deg, pose.roll_deg, T))
    session = Session(rows, "counts", board.counts_per_g, None, board.chip.name)
    return gap_data([(session, None, f"selftest-{kind}")], rate_hz=None)


def _cases() -> list[Case]:
    """(case, kind of data, withheld catalog effects, off-catalog term, expectation)."""
    out: list[Case]
    out = [(e, SELFTEST_DATA.get(e, "refs"), (e,), None, "named") for e in EFFECT_NAMES]
    out += [(e, kind, (), e, "unexplained") for e, kind in OFF_CATALOG.items()]
    out += [("+".join(pair), kind, pair, None, "both") for pair, kind in PAIRS.items()]
    out += [("none", "refs", (), None, "null"), ("none", "raw", (), None, "null")]
    return out


def run_case(device: JsonObject, base: Effects, case: Case, seed: int) -> CaseResult:
    """One self-test case: simulate, diagnose, judge (module doc)."""
    name, kind, withheld, extra, expect = case
    if len(withheld) == 1:
        board_fx, cfg_fx = _scenario(withheld[0], base)
    else:
        board_fx = {**base, **{e: SELFTEST_EFFECTS[e] for e in withheld}}
        cfg_fx = {k: v for k, v in base.items() if k not in withheld}
    data = simulate_data(device, board_fx, kind, seed, extra)
    sim = Simulator.from_board(_board(device, cfg_fx), "selftest", device)
    d = diagnose(data, sim)
    step = d.steps[0] if d.steps else None
    revealable = all(e not in d.untestable for e in withheld)
    if expect == "named" and not revealable:
        ok = not d.selected
    elif expect == "named":
        halved = withheld[0] in STOCHASTIC_CASES or \
            (step is not None and step["rms_mg_after"] <= step["rms_mg_before"] / 2)
        ok = bool(d.selected) and d.selected[0] == withheld[0] and halved
    elif expect == "both":
        ok = set(withheld) <= set(d.selected)
    elif expect == "unexplained":
        ok = not d.selected and d.verdict == "unexplained"
    else:
        ok = not d.selected and d.verdict == "nothing to explain"
    return {"case": name, "kind": expect, "data": KINDS[kind], "named": d.selected[0] if d.selected else None,
            "selected": d.selected, "verdict": d.verdict, "left": d.leftover.get("summary"),
            "gap_before": d.gap_before, "gap_after": d.gap_after,
            "rms_mg_before": 1e3 * d.base.rms_g, "rms_mg_after": 1e3 * d.final.rms_g,
            "rms_mg_after_named": step["rms_mg_after"] if step else 1e3 * d.base.rms_g, "revealable": revealable,
            "reason": None if revealable else "; ".join(d.untestable[e] for e in withheld if e in d.untestable),
            "pass": bool(ok)}


def selftest(config: str | Path | None = None, seed: int = 1, only: list[str] | None = None,
             coverage: bool = True) -> SelfTestResult:
    """Every case of the module doc at one seed; ``only``: a subset of case names."""
    sim0 = load_simulator(config)
    base = sim0.model.to_config()
    cases = [run_case(sim0.device, base, c, seed + k) for k, c in enumerate(_cases()) if not only or c[0] in only]
    out: SelfTestResult = {"cases": cases, "alpha": ALPHA, "seed": seed, "design": SELFTEST_DESIGN,
           "samples_per_pose": SELFTEST_SAMPLES, "physics": "forward (reading = S a + c (S a)^3 + b, then quantised)",
           "passed": all(c["pass"] for c in cases)}
    if coverage:
        out["coverage"] = _coverage(sim0.device, base, seed)
    return out


def _coverage(device: JsonObject, base: Effects, seed: int) -> dict[str, dict[str, str]]:
    """For every effect and data kind: testable, or why not (the same checks the diagnosis makes)."""
    from .effects.catalog import STOCHASTIC

    out: dict[str, dict[str, str]] = {}
    datasets = {kind: simulate_data(device, base, kind, seed + 100 + i)
                for i, kind in enumerate(("refs", "refs-3T", "norm", "raw"))}
    for effect in EFFECT_NAMES:
        _, cfg_fx = _scenario(effect, base)
        sim = Simulator.from_board(_board(device, cfg_fx), "selftest", device)
        row: dict[str, str] = {}
        for kind, data in datasets.items():
            td = time_data(data)
            testable, why, _, _ = candidates(data, sim, td)
            if effect in STOCHASTIC and effect not in testable:
                ok, reason = STOCHASTIC[effect].testable(data, td)
                row[kind] = "testable (signature)" if ok else reason
            else:
                row[kind] = "testable" if effect in testable else why.get(effect, "in the baseline (fitted)")
        out[effect] = row
    return out

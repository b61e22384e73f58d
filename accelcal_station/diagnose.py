"""Sim-to-real gap diagnosis: where real data leave the simulator, which catalog effect explains it.

1. Gap.  The simulator configuration's deterministic effects (offset, gain, cross_axis,
   ...) are fitted to the data (system identification, gap_effects.evaluate); what
   is left on held-out poses is compared with what the simulator says should be left
   (its noise and quantization for a mean of n samples).  The headline is the
   held-out residual RMS over that expected RMS: 1.0 means the simulator explains
   the data.
2. Where.  The baseline's held-out residuals broken down by axis, pose, input level,
   temperature and time within each capture; the noise itself by per-sample sigma
   and Allan deviation.
3. Which.  Every candidate effect (a catalog effect the configuration lacks, or a
   stochastic one it may have wrong) is added, refitted on training folds and
   scored on held-out folds by the Gaussian log predictive density (pose means, time
   blocks and each pose's within-pose variance).  Effects are added greedily while
   the current model leaves a gap outside its chance range (explained()), the best
   candidate passes a one-sided paired test (_p_greater) on per-(pose, axis) score
   differences at ALPHA, Bonferroni-corrected over the candidates of the step, and
   it removes at least MIN_GAP_SHRINK of the remaining log gap.  Candidates whose
   scores the test cannot tell apart go to the one with fewer fitted parameters.
4. How far.  The held-out gap before and after each added effect.

``selftest`` simulates boards with each effect in turn, withholds it from the
configuration and checks that the diagnosis names it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .drivers.simulated import SimulatedBoard
from .errors import ConfigError, DataError, UnderdeterminedError, UnitsError
from .fixtures.designs import get_design
from .fixtures.simulated_jig import SimulatedJig
from .gap_effects import (Capture, Evaluation, Floor, GapData, TimeData, design_rank_ok, evaluate,
                          random_var, static_design, time_data)
from .models import check_plausible_g
from .models.gravity_norm import nominal_scale
from .loader import load
from .rawlog import RawLog, read_raw_log, static_session
from .sensor_model import EFFECT_NAMES, SensorModel
from .session import PoseRecord, Session

ALPHA = 0.01
MIN_GAP_SHRINK = 0.1  # an added effect must remove this fraction of log(gap) too
DEFAULT_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "sim.yaml"
FITTED = ("offset", "gain", "cross_axis", "cubic", "quadratic", "temperature", "drift", "settling")


# -- the simulator's claim ---------------------------------------------------------------------

@dataclass
class Simulator:
    """The simulated board a configuration describes, as the diagnosis needs it."""

    model: SensorModel
    counts_per_g: float
    range_g: int
    odr_hz: float
    dlpf: int | None
    source: str
    device: dict = field(default_factory=dict)  # the board section (for the self-test)

    @classmethod
    def from_board(cls, board: SimulatedBoard, source: str, device: dict | None = None) -> "Simulator":
        return cls(board.model, board.counts_per_g, board.range_g, board.odr_hz, board.dlpf, source, device or {})

    @property
    def enabled(self) -> tuple[str, ...]:
        return self.model.enabled

    @property
    def baseline(self) -> tuple[str, ...]:
        """The deterministic effects the configuration enables: fitted to the data."""
        return tuple(e for e in FITTED if e in self.enabled)

    def sigma_g(self, rate_hz: float | None) -> np.ndarray:
        """Per-sample noise sigma (g) at the data's rate (the configured ODR when unknown)."""
        return self.model.noise_sigma_g(rate_hz or self.odr_hz, self.dlpf)

    def floor(self, rate_hz: float | None) -> Floor:
        m = self.model
        q = m.effects["quantization"]["lsb_counts"] / self.counts_per_g if m.has("quantization") else 0.0
        s = math.radians(m.effects["pose_error"]["scatter_deg"]) if m.has("pose_error") else 0.0
        return Floor(self.sigma_g(rate_hz), q, s, m.gravity_g())

    @property
    def clip_g(self) -> float:
        frac = self.model.effects["saturation"]["full_scale_fraction"] if self.model.has("saturation") else 1.0
        return self.model.chip.code_limits[1] * frac / self.counts_per_g


def load_simulator(path=None) -> Simulator:
    """The simulated board of a station config (default configs/sim.yaml)."""
    from .cli.probe import device_section

    path = Path(path) if path is not None else DEFAULT_CONFIG
    if not path.is_file():
        raise ConfigError(f"{path}: no such simulator configuration (give --config FILE with a device: section, "
                          "driver: simulated)")
    section = device_section(str(path))
    if section.get("driver") != "simulated":
        raise ConfigError(f"{path}: device.driver is {section.get('driver')!r}; accelcal diagnose needs the "
                          "simulated device (driver: simulated) that is supposed to describe the boards")
    section.pop("driver")
    board = SimulatedBoard.from_config(section, seed=0, path=f"{path}: device")
    return Simulator.from_board(board, str(path), section)


# -- data ------------------------------------------------------------------------------------------

def _scale(session: Session, source: str, notes: list[str]) -> float:
    """Input units per nominal g: the data's own, else estimated from the readings' norm."""
    if session.units == "counts" and session.counts_per_g is None:
        est = float(nominal_scale(session.readings[None])[0])
        notes.append(f"{source}: counts with no counts_per_g; {est:.1f} counts/g estimated from the readings' norm")
        return est
    return session.input_per_g


def gap_data(parts: list[tuple[Session, list[Capture] | None, str]], samples: int | None = None,
             norm_only: bool = False, rate_hz: float | None = None) -> GapData:
    """Combine sessions (one per file, with raw captures when read from raw logs) into GapData."""
    notes: list[str] = []
    g, ref, n, std, temp, fid, names, caps, scales = [], [], [], [], [], [], [], [], []
    sources = [src for _, _, src in parts]
    for k, (s, cap, src) in enumerate(parts):
        if len(s) == 0:
            raise DataError(f"{src}: no poses")
        per_g = _scale(s, src, notes)
        try:
            check_plausible_g(s.readings / per_g, s.units)  # e.g. counts given as g
        except UnitsError as e:
            raise UnitsError(f"{src}: {e}") from None
        scales.append(per_g if s.units == "counts" else None)
        g.append(s.readings / per_g)
        ref.append([p.reference_g for p in s.poses])
        n.append([p.n for p in s.poses])
        std.append([None if p.std is None else p.std / per_g for p in s.poses])
        temp.append([p.temp_c for p in s.poses])
        fid += [k] * len(s)
        names += [f"{Path(src).stem}:{p.name}" if len(parts) > 1 else p.name for p in s.poses]
        if cap is not None:
            caps += [Capture(c.t, c.x, per_g) for c in cap]
    g = np.concatenate(g)
    P = len(g)
    ref = [r for part in ref for r in part]
    n = [x for part in n for x in part]
    std = [x for part in std for x in part]
    temp = [x for part in temp for x in part]
    if P < 4:
        raise UnderdeterminedError(f"{P} poses; the diagnosis needs at least 4 (it holds some out of every fit)")
    refs = None
    if not norm_only and all(r is not None for r in ref):
        refs = np.array(ref, float)
    elif not norm_only and any(r is not None for r in ref):
        notes.append("some poses have no reference: the analysis uses the norm only")
    have_t = [t is not None for t in temp]
    if any(have_t) and not all(have_t):
        raise DataError(f"pose {names[have_t.index(False)]!r} has no temp_c while others do; "
                        "give temp_c for every pose or for none")
    n_known = all(x for x in n)
    if n_known:
        n_arr = np.array(n, float)
    else:
        n_arr = np.full(P, float(samples or 1))
        notes.append(f"samples per pose unknown: the floor assumes n = {samples or 1}"
                     + ("" if samples else " (per-sample noise, so the ratio is a lower bound; give --samples N)"))
    std_arr = np.array(std, float) if n_known and all(x is not None for x in std) else None
    return GapData(names, g, refs, n_arr, n_known, std_arr, np.array(temp, float) if all(have_t) else None,
                   np.array(fid), caps if len(caps) == P else None, rate_hz, sources, notes, scales)


def raw_part(log: RawLog, units: str = "counts", counts_per_g=None, gravity=None):
    """Segment a raw log into static poses; returns (Session, captures, source)."""
    session, det = static_session(log, units, counts_per_g, gravity)
    t0 = float(log.t[0])
    caps = None
    if log.rate_hz:
        caps = []
        for s in det.segments:
            idx = np.concatenate([np.arange(a, b) for a, b in s.ranges])
            caps.append(Capture(log.t[idx] - t0, log.xyz[idx], 1.0))
    return session, caps, log.source


def load_data(paths, raw: bool = False, units=None, counts_per_g=None, gravity=None, columns=None,
              skip_rows=None, rate=None, samples=None, norm_only: bool = False) -> GapData:
    """Read pose tables (or, with ``raw``, raw logs) the way `accelcal fit` does."""
    if not paths:
        raise DataError("no data files given; allowed: pose tables, or raw logs with --raw (or use --selftest)")
    parts, rates, inferred = [], set(), []
    for path in paths:
        if raw:
            loaded = load(path, True, units=units, counts_per_g=counts_per_g, gravity_mps2=gravity, columns=columns,
                          skip_rows=skip_rows, rate_hz=rate)
            log = loaded.log
            inferred.append(f"{path}: " + "; ".join(loaded.inferred))
            if not log.rate_hz:
                raise DataError(f"{path}: no time column and no --rate: the diagnosis needs the sample rate "
                                "(noise bandwidth, time within captures)")
            rates.add(round(log.rate_hz, 6))
            parts.append(raw_part(log, loaded.session.units, loaded.session.counts_per_g,
                                  loaded.session.gravity_mps2))
        else:
            for flag, v in (("--columns", columns), ("--skip-rows", skip_rows)):
                if v is not None:
                    raise DataError(f"{flag} is for raw sample logs; add --raw to read {path} as one")
            loaded = load(path, units=units, counts_per_g=counts_per_g, gravity_mps2=gravity)
            inferred.append(f"{path}: " + "; ".join(loaded.inferred))
            parts.append((loaded.session, None, str(path)))
    if len(rates) > 1:
        raise DataError(f"raw logs at different rates ({', '.join(f'{r:g}' for r in sorted(rates))} Hz); "
                        "diagnose logs of one rate together")
    data = gap_data(parts, samples, norm_only, rates.pop() if rates else rate)
    data.notes[:0] = inferred  # what reading the files inferred comes first in the summary
    return data


# -- candidates ------------------------------------------------------------------------------------

DEGENERATE = {
    "gravity": "local gravity scales every static reading alike and the fitted gain absorbs it exactly "
               "(1 g references and the 1 g norm cannot tell gravity from sensitivity); it needs an independent "
               "reference such as a known gain or a second acceleration level",
    "cubic": "each channel reads only near 0 and +-1 g in these poses, where g^3 equals g, so the cubic term "
             "cannot be told from the gain; it needs intermediate tilts (e.g. an4399-8, optimal-N)",
    "quadratic": "these poses do not separate g^2 from the offset and gain; it needs several input levels per channel",
    "gain": "the baseline's cross_axis matrix already fits each axis's sensitivity",
    "temperature": "the poses' temperatures do not separate a temperature term from the rest of the model",
}


def candidates(data: GapData, sim: Simulator, td: TimeData | None) -> tuple[list[str], dict[str, str], bool, str]:
    """(testable candidates, {effect: why not}, static view usable, why not)."""
    base = sim.baseline
    why: dict[str, str] = {}
    static_ok, static_why = True, ""
    ok, cond = design_rank_ok(base, data, data.norm_only)
    p_train = data.P - math.ceil(data.P / data.n_folds)

    def dof(effects) -> int:
        A_cols = len(_labels(effects, data))
        return p_train - (A_cols if data.norm_only else math.ceil(A_cols / 3))

    if not ok:
        static_ok, static_why = False, f"these poses do not determine the baseline ({', '.join(base)}; condition {cond:.3g})"
    elif dof(base) < 0:
        static_ok = False
        static_why = (f"{data.P} poses are too few to fit the baseline ({len(_labels(base, data))} parameters"
                      f"{' on the norm' if data.norm_only else ' over 3 channels'}) with a pose held out")
    testable = []
    for e in EFFECT_NAMES:
        if e in base:
            continue
        if e == "saturation":
            top = float(np.max(np.abs(data.g)))
            clip = sim.clip_g
            if top < 0.95 * clip:
                why[e] = (f"static gravity poses read at most {top:.2f} g on any axis, below the {clip:.2f} g where "
                          "the output clips (range x full_scale_fraction): clipping cannot show; it needs inputs near "
                          "full scale (centrifuge, shaker)")
            else:
                why[e] = (f"readings reach {top:.2f} g, at the {clip:.2f} g clip level: clipped poses are not modelled "
                          "as a fitted term; remove them or measure on a larger range")
            continue
        if e == "noise":
            if data.captures is None and data.std_g is None:
                why[e] = "the data carry no per-pose std and n and no raw samples, so the noise cannot be measured"
            else:
                testable.append(e)
            continue
        if e == "quantization":
            if td is None:
                why[e] = "the LSB shows only in raw samples' value grid (a pose mean hides it): it needs raw logs"
            else:
                testable.append(e)
            continue
        if e == "settling":
            if td is None:
                why[e] = "a transient after each pose change shows only within a capture: it needs raw logs"
            else:
                testable.append(e)
            continue
        if e == "drift":
            if td is None:
                why[e] = "drift over time needs raw time series (raw logs): pose tables carry no capture times"
            else:
                testable.append(e)
            continue
        if not static_ok:
            why[e] = f"the static view is unavailable: {static_why}"
            continue
        if e == "pose_error":
            if data.norm_only:
                why[e] = ("a rotation keeps |f| = 1 g, so a pose's orientation error is invisible without references "
                          "(norm-only data); a fixed jig rotation is absorbed by W even with references")
            else:
                testable.append(e)
            continue
        if e == "temperature" and data.n_temps < 2:
            why[e] = ("the data have no temp_c" if data.temp_c is None else
                      f"all poses at one temperature ({np.mean(data.temp_c):.1f} C)") + \
                ": it needs poses at two or more temperatures"
            continue
        ok, cond = design_rank_ok(base + (e,), data, data.norm_only)
        if not ok:
            why[e] = DEGENERATE.get(e, "these poses do not separate it from the baseline") + f" (condition {cond:.3g})"
        elif dof(base + (e,)) < 0:
            why[e] = f"{data.P} poses are too few to fit its parameters with a pose held out"
        else:
            testable.append(e)
    return testable, why, static_ok, static_why


def _labels(effects, data: GapData):
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    return static_design(set(effects), data.g, data.ref, dT, dh, data.norm_only, data.n_temps)[3]


# -- the diagnosis ---------------------------------------------------------------------------------

@dataclass
class Diagnosis:
    data: GapData
    sim: Simulator
    floor: Floor
    base: Evaluation
    final: Evaluation
    ranking: list[dict]
    steps: list[dict]
    selected: list[str]
    untestable: dict[str, str]
    static_ok: bool
    static_why: str
    where: dict
    alpha: float = ALPHA

    @property
    def gap_before(self) -> float:
        return self.base.gap

    @property
    def gap_after(self) -> float:
        return self.final.gap


def _p_greater(d: np.ndarray) -> float:
    """One-sided paired p-value that per-pose score differences d tend to be > 0.

    The smaller of a t-test (power with few poses and a consistent effect) and a Wilcoxon
    signed-rank test (power with many poses and heavy tails), doubled: a Bonferroni union
    of the two, so the level holds whichever of them the data suit.
    """
    d = np.asarray(d, float)
    if len(d) < 2 or not np.any(d != d[0]):
        return 1.0 if len(d) < 2 or d[0] <= 0 else 0.0
    from scipy import stats  # on first use: scipy.stats costs a second at every command's start-up

    p_t = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue)
    p_w = float(stats.wilcoxon(d, alternative="greater").pvalue)
    return min(1.0, 2 * min(p_t, p_w))


def explained(e: Evaluation, alpha: float = ALPHA) -> bool:
    """Whether every view's held-out gap lies in the two-sided 1 - alpha/views range of sqrt(chi^2_N / N).

    N is the view's number of held-out rows: a model that explains the data leaves
    standardised residuals whose mean square is chi^2_N / N.
    """
    views = [(r, v) for r, v in ((e.r_static, e.v_static), (e.r_time, e.v_time)) if r is not None]
    for r, v in views:
        N = r.size
        a = alpha / len(views)  # Bonferroni over the views
        from scipy import stats

        lo, hi = stats.chi2.ppf([a / 2, 1 - a / 2], N) / N
        g2 = np.sum(r**2) / np.sum(v)
        if not lo <= g2 <= hi:
            return False
    return True


def diagnose(data: GapData, sim: Simulator, alpha: float = ALPHA) -> Diagnosis:
    """Gap, where, which and how far (module doc)."""
    floor = sim.floor(data.rate_hz)
    if floor.q_g <= 0 and np.any(floor.sigma_g <= 0):
        # a zero floor makes every held-out ratio 0/0: there is nothing to compare the data with
        raise ConfigError(f"{sim.source}: the simulator predicts no noise on some axis (no noise density and no "
                          "quantization), so it claims exact readings; enable noise (and quantization) under "
                          "simulator.effects")
    for src, cpg in zip(data.sources, data.counts_per_g):
        if cpg is not None and abs(cpg / sim.counts_per_g - 1) > 0.05:
            data.notes.append(f"{src}: {cpg:.6g} counts/g, the simulator's board has {sim.counts_per_g:g} counts/g "
                              f"({sim.range_g} g range): another range or sensitivity; the analysis works in g, "
                              "so only the simulator's LSB in g may not hold")
    td = time_data(data)
    testable, why, static_ok, static_why = candidates(data, sim, td)
    if not static_ok and td is None:
        raise UnderdeterminedError(f"nothing to diagnose: {static_why}, and there are no raw captures "
                                   "(give references, more poses, or raw logs with --raw)")
    base_fx = sim.baseline

    def ev(added):
        return evaluate(data, floor, base_fx, tuple(added), td, static_ok)

    base = current = ev(())
    # the (pose, axis) units some view scores: a norm-only static view scores one per pose, and its two
    # structural zeros per pose would inflate the paired test's sample size (and dilute its mean)
    units = base.nll_unit != 0
    selected: list[str] = []
    steps: list[dict] = []
    ranking: list[dict] | None = None
    remaining = list(testable)
    while remaining:
        evs = {c: ev(selected + [c]) for c in remaining}
        pv = {c: _p_greater((current.nll_unit - evs[c].nll_unit)[units]) for c in remaining}
        order = sorted(remaining, key=lambda c: evs[c].score)
        best = order[0]
        tied = [c for c in order if c == best or _p_greater((evs[c].nll_unit - evs[best].nll_unit)[units]) >= alpha]
        choice = min(tied, key=lambda c: (evs[c].n_params, evs[c].score))
        order.remove(choice)
        order.insert(0, choice)
        level = alpha / len(remaining)
        lg_cur, lg_new = (abs(math.log(max(x, 1e-300))) for x in (current.gap, evs[choice].gap))  # gap 0: exact data
        accept = (not explained(current, alpha)) and pv[choice] < level and lg_new <= (1 - MIN_GAP_SHRINK) * lg_cur
        if ranking is None:
            ranking = [{"effect": c, "held_out_gap": evs[c].gap, "score": evs[c].score, "p_value": pv[c],
                        "params": evs[c].n_params, "rms_mg": 1e3 * evs[c].rms_g} for c in order]
        if not accept:
            break
        selected.append(choice)
        steps.append({"added": choice, "gap_before": current.gap, "gap_after": evs[choice].gap,
                      "rms_mg_before": 1e3 * current.rms_g, "rms_mg_after": 1e3 * evs[choice].rms_g,
                      "p_value": pv[choice], "level": level, "fitted": _fitted(evs[choice], choice, sim, data)})
        current = evs[choice]
        remaining.remove(choice)
    where = breakdown(data, sim, floor, base, current, td)
    return Diagnosis(data, sim, floor, base, current, ranking or [], steps, selected, why, static_ok, static_why,
                     where, alpha)


def _fitted(e: Evaluation, effect: str, sim: Simulator, data: GapData) -> dict:
    """The fitted values of an added effect, in the configuration's units where there is one."""
    p = e.params
    if effect == "noise":
        enbw = sim.model.chip.enbw_hz(data.rate_hz or sim.odr_hz, sim.dlpf)
        return {"density_ug_per_rthz": [1e6 * s / math.sqrt(enbw) for s in p["sigma_g"]]}
    if effect == "quantization":
        return {"lsb_counts": p["lsb_g"] * sim.counts_per_g, "lsb_mg": 1e3 * p["lsb_g"]}
    if effect == "pose_error":
        return {"scatter_deg": p["scatter_deg"]}
    out = {k.split(":", 1)[1]: v for k, v in p.items() if k.startswith(effect + ":")}
    out.update({k: v for k, v in p.items() if k.startswith(effect)})
    return out


# -- where -----------------------------------------------------------------------------------------

def _ratio(r, v) -> float | None:
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


def breakdown(data: GapData, sim: Simulator, floor: Floor, base: Evaluation, after: Evaluation,
              td: TimeData | None) -> dict:
    """Where the baseline's held-out gap lies (module doc, step 2)."""
    w: dict = {"views": {"static": base.view_gap("static"), "time": base.view_gap("time")}}
    if base.r_static is not None:
        r, v = base.r_static, base.v_static
        z = np.sqrt(np.mean(r**2 / v, axis=1))
        w["by_pose"] = [{"pose": data.names[i], "z_rms": float(z[i]), "residual_mg": (1e3 * r[i]).tolist()}
                        for i in np.argsort(-z)[:5]]
        if not data.norm_only:
            w["by_axis"] = {a: _ratio(r[:, c], v[:, c]) for c, a in enumerate("xyz")}
        edges = np.array([-1.5, -0.6, -0.2, 0.2, 0.6, 1.5])
        lv = []
        for c, a in enumerate("xyz"):
            rc = r[:, c] if not data.norm_only else r[:, 0]
            vc = v[:, c] if not data.norm_only else v[:, 0]
            b = np.digitize(data.g[:, c], edges[1:-1])
            for k in range(len(edges) - 1):
                m = b == k
                if m.any():
                    lv.append({"axis": a, "level_g": [float(edges[k]), float(edges[k + 1])], "poses": int(m.sum()),
                               "mean_residual_mg": float(1e3 * rc[m].mean()), "gap": _ratio(rc[m], vc[m])})
        w["by_level"] = lv
        if data.temp_c is not None and data.n_temps >= 2:
            tk = np.round(data.temp_c / 2.0)
            w["by_temperature"] = [{"temp_c": float(np.mean(data.temp_c[tk == t])), "gap": _ratio(r[tk == t], v[tk == t]),
                                    "mean_residual_mg": (1e3 * r[tk == t].mean(axis=0)).tolist()}
                                   for t in np.unique(tk)]
    if td is not None and base.r_time is not None:
        blk = np.round(td.t_in / max(np.max(td.t_in), 1e-9) * 7).astype(int)
        proj = np.sign(td.step_unit[td.unit, td.axis]) * base.r_time
        w["by_time_in_capture"] = [{"t_s": float(np.mean(td.t_in[blk == k])), "gap": _ratio(base.r_time[blk == k],
                                    base.v_time[blk == k]), "toward_step_mg": float(1e3 * np.mean(proj[blk == k]))}
                                   for k in np.unique(blk)]
        w["by_axis_time"] = {a: _ratio(base.r_time[td.axis == c], base.v_time[td.axis == c])
                             for c, a in enumerate("xyz")}
    sim_sig = floor.sigma_g
    sim_rand = np.sqrt(random_var(sim_sig, floor.q_g))
    meas = None
    if td is not None:
        meas = np.sqrt(np.nanmean(td.diff_var, axis=0))
    elif data.std_g is not None:
        meas = np.sqrt(np.mean(data.std_g**2, axis=0))
    if meas is not None:
        w["noise"] = {"sigma_mg": (1e3 * meas).tolist(), "simulator_sigma_mg": (1e3 * sim_rand).tolist(),
                      "ratio": (meas / np.where(sim_rand > 0, sim_rand, np.nan)).tolist(),
                      "rate_hz": data.rate_hz or sim.odr_hz}
    if data.captures is not None and data.rate_hz and td is not None:  # td: None when captures are too short
        longest = max(data.captures, key=lambda c: len(c.t))
        x = longest.x / longest.per_g
        taus, ad = zip(*[allan(x[:, a], data.rate_hz) for a in range(3)])
        white = np.sqrt(np.nanmean(td.diff_var, axis=0))[:, None] / np.sqrt(taus[0] * data.rate_hz)[None]
        w["allan"] = {"tau_s": taus[0].tolist(), "adev_mg": (1e3 * np.array(ad)).tolist(),
                      "white_mg": (1e3 * white).tolist(),
                      "ratio_at_longest_tau": (np.array(ad)[:, -1] / white[:, -1]).tolist()}
    w["max_reading_g"] = float(np.max(np.abs(data.g)))
    return w


# -- JSON --------------------------------------------------------------------------------------------

def to_json(d: Diagnosis) -> dict:
    data = d.data
    return {
        "gap_before": d.gap_before, "gap_after": d.gap_after,
        "rms_mg_before": 1e3 * d.base.rms_g, "rms_mg_after": 1e3 * d.final.rms_g,
        "expected_rms_mg": 1e3 * d.base.expected_rms_g,
        "floor_mg": 1e3 * float(np.sqrt(np.mean(d.base.floor_static))) if d.base.floor_static is not None else None,
        "ranking": d.ranking, "selected": d.selected, "steps": d.steps,
        "untestable": [{"effect": e, "reason": r} for e, r in d.untestable.items()],
        "baseline": list(d.sim.baseline), "config": d.sim.source, "config_effects": list(d.sim.enabled),
        "test": {"name": "one-sided paired test (min of t-test and Wilcoxon signed-rank, doubled) on per-pose "
                         "held-out log predictive density, Bonferroni over the candidates of each step; stop when "
                         "every view's gap lies in the two-sided 1-alpha range of sqrt(chi2_N/N)",
                 "alpha": d.alpha, "min_gap_shrink": MIN_GAP_SHRINK},
        "data": {"sources": data.sources, "poses": data.P, "references": not data.norm_only,
                 "samples_per_pose_known": data.n_known, "temperatures": data.n_temps,
                 "raw_captures": data.captures is not None, "rate_hz": data.rate_hz,
                 "counts_per_g": data.counts_per_g,
                 "static_view": d.static_ok, "static_view_note": d.static_why or None, "notes": data.notes},
        "where": d.where,
    }


# -- self-test ---------------------------------------------------------------------------------------

SELFTEST_EFFECTS = {
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
SELFTEST_DESIGN = "optimal-24"
SELFTEST_SAMPLES = {"refs": 200, "raw": 1000}
KINDS = {"refs": "pose table with references, one temperature", "refs-3T": "pose table with references, 0/25/50 C",
         "norm": "pose table without references", "raw": "raw log (no references)"}


def _scenario(effect: str | None, base: dict) -> tuple[dict, dict]:
    """(board effects, configuration effects) of a self-test case: the board has the effect, the config not."""
    base = {k: dict(v or {}) for k, v in base.items()}
    if effect is None:
        return base, base
    if effect in ("noise", "quantization"):  # enabled in the config; the board's value differs
        return {**base, effect: {**base.get(effect, {}), **SELFTEST_EFFECTS[effect]}}, {**base, effect: base.get(effect, {})}
    if effect == "gain":  # a full cross_axis matrix would fit the gains too
        base.pop("cross_axis", None)
    board = {**base, effect: base.get(effect) or SELFTEST_EFFECTS[effect]}
    return board, {k: v for k, v in base.items() if k != effect}


def _board(device: dict, effects: dict, seed: int = 0) -> SimulatedBoard:
    """A board of the configuration's chip, range and rate with these effects."""
    cfg = {k: v for k, v in device.items() if k in ("chip", "range_g", "odr_hz", "dlpf")}
    return SimulatedBoard.from_config({**cfg, "effects": effects}, seed=seed, path="selftest")


def simulate_data(device: dict, effects: dict, kind: str, seed: int) -> GapData:
    """Data of one kind from a simulated board with ``effects`` (the self-test's real boards)."""
    board = _board(device, effects, seed)
    jig = SimulatedJig(board, move_time_s=2.0)
    poses = get_design(SELFTEST_DESIGN)
    temps = [0.0, 25.0, 50.0] if kind == "refs-3T" else [25.0]
    n = SELFTEST_SAMPLES["raw" if kind == "raw" else "refs"]
    records, chunks = [], []
    for T in temps:
        board.set_temperature(T)
        for pose in poses:
            jig.present(pose)
            counts, t = board.read(n)
            c = np.asarray(counts, float)
            chunks.append((t, c))
            records.append(PoseRecord(pose.name if len(temps) == 1 else f"{pose.name}@{T:g}C", c.mean(0),
                                      c.std(0, ddof=1), n, None if kind in ("norm", "raw") else pose.reference_g,
                                      pose.pitch_deg, pose.roll_deg, board.temperature_c))
    if kind == "raw":
        t = np.concatenate([t for t, _ in chunks])
        x = np.concatenate([c for _, c in chunks])
        log = RawLog(t, x, np.arange(len(t)), f"selftest-{kind}", ["t", "x", "y", "z"], board.odr_hz, True)
        return gap_data([raw_part(log, "counts", board.counts_per_g)], rate_hz=board.odr_hz)
    session = Session(records, "counts", board.counts_per_g, None, board.chip.name)
    return gap_data([(session, None, f"selftest-{kind}")], rate_hz=None)


def selftest(config=None, seed: int = 1) -> dict:
    """For each catalog effect: boards that have it, a configuration without it, the diagnosis (module doc)."""
    sim0 = load_simulator(config)
    base = sim0.model.to_config()
    device = sim0.device
    cases = []
    for k, effect in enumerate(list(EFFECT_NAMES) + [None, None]):
        kind = "raw" if (effect is None and k == len(EFFECT_NAMES) + 1) else SELFTEST_DATA.get(effect, "refs")
        board_fx, cfg_fx = _scenario(effect, base)
        data = simulate_data(device, board_fx, kind, seed + k)
        sim = Simulator.from_board(_board(device, cfg_fx), "selftest", device)
        d = diagnose(data, sim)
        revealable = effect is None or effect not in d.untestable
        first_gap = d.steps[0]["gap_after"] if d.steps else d.gap_before
        if effect is None or not revealable:
            ok = not d.selected
        else:
            ok = bool(d.selected) and d.selected[0] == effect and first_gap <= d.gap_before / 2
        cases.append({"withheld": effect or "none", "data": KINDS[kind], "named": d.selected[0] if d.selected else None,
                      "selected": d.selected, "gap_before": d.gap_before, "gap_after": d.gap_after,
                      "gap_after_named": first_gap, "revealable": revealable,
                      "reason": None if revealable else d.untestable[effect], "pass": ok})
    coverage = _coverage(device, base, seed)
    return {"cases": cases, "coverage": coverage, "alpha": ALPHA, "seed": seed, "design": SELFTEST_DESIGN,
            "samples_per_pose": SELFTEST_SAMPLES, "passed": all(c["pass"] for c in cases)}


def _coverage(device: dict, base: dict, seed: int) -> dict:
    """For every effect and data kind: testable, or why not (the same checks the diagnosis makes)."""
    out: dict = {}
    datasets = {kind: simulate_data(device, base, kind, seed + 100 + i) for i, kind in enumerate(KINDS)}
    for effect in EFFECT_NAMES:
        _, cfg_fx = _scenario(effect, base)
        sim = Simulator.from_board(_board(device, cfg_fx), "selftest", device)
        row = {}
        for kind, data in datasets.items():
            testable, why, _, _ = candidates(data, sim, time_data(data))
            row[kind] = "testable" if effect in testable else why.get(effect, "in the baseline (fitted)")
        out[effect] = row
    return out

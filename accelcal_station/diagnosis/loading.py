"""Loading for `accelcal diagnose`: the simulator a configuration describes, and the data as GapData."""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.kinds import SimulatedDevice
from ..config.sections import default_config_path, device_section
from ..data.loader import load
from ..data.rawlog import RawLog
from ..data.sample_grid import distinct_samples
from ..data.static_poses import StaticDetection, static_session
from ..drivers.simulated import SimulatedBoard
from ..errors import AccelcalError, ConfigError, DataError, UnderdeterminedError, UnitsError
from ..jsontypes import JsonObject
from ..models.choice import ModelChoice, choose_model
from ..models.fitting import check_plausible_g
from ..models.gravity_norm import nominal_scale
from ..session import Session
from ..sim.sensor_model import SensorModel
from .gap_data import Capture, GapData
from .noise_floor import Floor
from .request import DiagnoseRequest
from .site import stated_site_g

Part = tuple[Session, list[Capture] | None, str]  # one file: its poses, their raw captures (raw logs), its name
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
    device: JsonObject = field(default_factory=dict)  # the config's device: section, as read (for the self-test)
    exclude: tuple[str, ...] = ()  # effects left out of the baseline: fit's model has no terms for them

    @classmethod
    def from_board(cls, board: SimulatedBoard, source: str, device: JsonObject | None = None) -> Simulator:
        return cls(board.model, board.counts_per_g, board.range_g, board.odr_hz, board.dlpf, source, device or {})

    @property
    def enabled(self) -> tuple[str, ...]:
        return self.model.enabled

    @property
    def baseline(self) -> tuple[str, ...]:
        """The deterministic effects the configuration enables: fitted to the data."""
        return tuple(e for e in FITTED if e in self.enabled and e not in self.exclude)

    def sigma_g(self, rate_hz: float | None) -> np.ndarray:
        """Per-sample noise sigma (g) at the data's rate (the configured ODR when unknown)."""
        return self.model.noise_sigma_g(rate_hz or self.odr_hz, self.dlpf)

    def floor(self, rate_hz: float | None) -> Floor:
        m = self.model
        q = float(m.effects["quantization"]["lsb_counts"]) / self.counts_per_g if m.has("quantization") else 0.0
        s = math.radians(m.effects["pose_error"]["scatter_deg"]) if m.has("pose_error") else 0.0
        return Floor(self.sigma_g(rate_hz), q, s, m.gravity_g())

    @property
    def clip_g(self) -> float:
        frac = float(self.model.effects["saturation"]["full_scale_fraction"]) if self.model.has("saturation") else 1.0
        return self.model.chip.code_limits[1] * frac / self.counts_per_g


def load_simulator(path: str | Path | None = None) -> Simulator:
    """The simulated board of a station config (default configs/sim.yaml)."""
    path = Path(path) if path is not None else default_config_path()
    if not path.is_file():
        raise ConfigError(f"{path}: no such simulator configuration (give --config FILE with a device: section, "
                          "driver: simulated)")
    section = device_section(str(path))
    if not isinstance(section, SimulatedDevice):
        raise ConfigError(f"{path}: device.driver is {section.driver!r}; accelcal diagnose needs the "
                          "simulated device (driver: simulated) that is supposed to describe the boards")
    board = SimulatedBoard.from_section(section, seed=0, path=f"{path}: device")
    # the self-test draws its boards from the board keys the file gave (diagnosis/selftest.py)
    return Simulator.from_board(board, str(path), section.model_dump(exclude_unset=True, exclude={"driver"}))


# -- data ------------------------------------------------------------------------------------------

def _scale(session: Session, source: str, notes: list[str]) -> float:
    """Input units per nominal g: the data's own, else estimated from the readings' norm."""
    if session.units == "counts" and session.counts_per_g is None:
        est = float(nominal_scale(session.readings[None])[0])
        notes.append(f"{source}: counts with no counts_per_g; {est:.1f} counts/g estimated from the readings' norm")
        return est
    return session.input_per_g


def _checked_scale(session: Session, source: str, notes: list[str]) -> float:
    """Input units per nominal g (_scale); refused when the readings are not near 1 g (e.g. counts given as g)."""
    per_g = _scale(session, source, notes)
    try:
        check_plausible_g(session.readings / per_g, session.units)
    except UnitsError as e:
        raise UnitsError(f"{source}: {e}") from None
    return per_g


def _samples_per_pose(n: list[int | None], samples: int | None, notes: list[str]) -> tuple[np.ndarray, bool]:
    """Samples behind every pose mean, and whether every pose says (else ``samples``, or 1, assumed)."""
    if all(x for x in n):
        return np.array(n, float), True
    notes.append(f"samples per pose unknown: the floor assumes n = {samples or 1}"
                 + ("" if samples else " (per-sample noise, so the ratio is a lower bound; give --samples N)"))
    return np.full(len(n), float(samples or 1)), False


def gap_data(parts: Sequence[Part], samples: int | None = None, norm_only: bool = False,
             rate_hz: float | None = None) -> GapData:
    """Combine sessions (one per file, with raw captures when read from raw logs) into GapData."""
    notes: list[str] = []
    gs: list[np.ndarray] = []
    ref: list[np.ndarray | None] = []
    n: list[int | None] = []
    std: list[np.ndarray | None] = []
    temp: list[float | None] = []
    fid: list[int] = []
    names: list[str] = []
    caps: list[Capture] = []
    scales: list[float | None] = []
    sources = [src for _, _, src in parts]
    for k, (s, cap, src) in enumerate(parts):
        if len(s) == 0:
            raise DataError(f"{src}: no poses")
        per_g = _checked_scale(s, src, notes)
        scales.append(per_g if s.units == "counts" else None)
        gs.append(s.readings / per_g)
        ref += [p.reference_g for p in s.poses]
        n += [p.n for p in s.poses]
        std += [None if p.std is None else p.std / per_g for p in s.poses]
        temp += [p.temp_c for p in s.poses]
        fid += [k] * len(s)
        names += [f"{Path(src).stem}:{p.name}" if len(parts) > 1 else p.name for p in s.poses]
        if cap is not None:
            caps += [Capture(c.t, c.x, per_g, c.decimals) for c in cap]
    g = np.concatenate(gs)
    P = len(g)
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
    n_arr, n_known = _samples_per_pose(n, samples, notes)
    std_arr = np.array(std, float) if n_known and all(x is not None for x in std) else None
    return GapData(names, g, refs, n_arr, n_known, std_arr, np.array(temp, float) if all(have_t) else None,
                   np.array(fid), caps if len(caps) == P else None, rate_hz, sources, notes, scales)


def raw_part(log: RawLog, units: str = "counts", counts_per_g: float | None = None,
             gravity: float | None = None) -> Part:
    """Segment a raw log into static poses; returns (Session, captures, source)."""
    session, det = static_session(log, units, counts_per_g, gravity)
    return _captures(log, session, det)


def _captures(log: RawLog, session: Session, det: StaticDetection) -> Part:
    """The Part of a segmented raw log: its poses' samples as captures (none without a sample rate)."""
    t0 = float(log.t[0])
    caps: list[Capture] | None = None
    if log.rate_hz:
        caps = []
        decimals = max(log.info.decimals.values()) if log.info.decimals else None
        for s in det.segments:
            idx = np.concatenate([np.arange(a, b) for a, b in s.ranges])
            caps.append(Capture(log.t[idx] - t0, log.xyz[idx], 1.0, decimals))
    return session, caps, log.source


# effects of the baseline the chosen model has no terms for (the sim's baseline is offset, gain, cross_axis, ...)
NOT_IN_MODEL = {"hand-placed norm fit": ("cross_axis", "cubic", "quadratic"), "6": ("cross_axis", "cubic", "quadratic"),
                "9": ("cubic", "quadratic"), "12": ("cubic", "quadratic"), "15": ("quadratic",)}


def fit_ground(parts: Sequence[Part]) -> tuple[ModelChoice | None, str]:
    """The model `accelcal fit` chooses for the data (models/choice.py; the first file's for several
    files), or fit's words refusing them ("" when none refuses)."""
    choice = None
    for session, _, src in parts:
        try:
            c = choose_model(session)
        except AccelcalError as e:
            return None, f"{src}: {e}"
        choice = choice or c
    return choice, ""


def chip_rate_hz(log: RawLog, notes: list[str], path: str) -> float:
    """The rate the chip updated at: the log's, less the repeats of a host polling faster than the chip
    (data/sample_grid.py), so the simulator's noise floor is taken at the rate the samples really have."""
    assert log.rate_hz, "a raw log with a sample rate"
    distinct = distinct_samples(log.xyz)
    kept = float(np.mean(distinct))
    span_s = float(log.t[-1] - log.t[0])
    if kept < 1.0 and span_s > 0:
        # distinct samples over the log's span: the host's own (printed, rounded) intervals would bias it
        rate = float(np.sum(distinct) - 1) / span_s
        notes.append(f"{path}: {1 - kept:.0%} of the samples repeat the one before (the host read faster than the "
                     f"chip updates): the chip's rate is taken as {rate:.4g} Hz (distinct samples over the log's "
                     "span), and the noise and the value grid are judged on the distinct samples")
        return rate
    return float(log.rate_hz)


def load_data(request: DiagnoseRequest) -> GapData:
    """Read pose tables (or, with ``request.raw``, raw logs) with the loader `accelcal fit` uses (loader.load).

    ``request.rate_hz`` is the raw log's sample rate, or for pose tables the rate of the samples behind
    their std.
    """
    paths, raw, rate = request.files, request.raw, request.rate_hz
    if not paths:
        raise DataError("no data files given; allowed: pose tables, or raw logs with --raw (or use --selftest)")
    parts: list[Part] = []
    rates: set[float] = set()
    inferred: list[str] = []
    for path in paths:
        loaded = load(str(path), raw, units=request.units, counts_per_g=request.counts_per_g,
                      gravity_mps2=request.gravity_mps2, columns=request.columns, skip_rows=request.skip_rows,
                      rate_hz=rate if raw else None, references=False)
        inferred.append(f"{path}: " + "; ".join(loaded.inferred))
        if loaded.log is None:
            parts.append((loaded.session, None, str(path)))
            continue
        assert loaded.detection is not None, "a raw log is loaded with its segmentation"
        if not loaded.log.rate_hz:  # as fit reads it: the poses' means, std and n; no time view without times
            inferred.append(f"{path}: no sample rate (no time column, no --rate): the poses' means, std and n "
                            "are analysed; the time view (within captures) needs --rate HZ")
            parts.append((loaded.session, None, str(path)))
            continue
        rates.add(round(chip_rate_hz(loaded.log, inferred, str(path)), 6))
        parts.append(_captures(loaded.log, loaded.session, loaded.detection))
    choice, refused = fit_ground(parts)
    if refused and not any(cap is not None for _, cap, _ in parts):
        raise UnderdeterminedError(f"nothing to diagnose: {refused} (`accelcal fit` refuses these poses, so "
                                   "there is no baseline to judge a gap by; raw logs with a rate add a time view)")
    if len(rates) > 1:
        raise DataError(f"raw logs at different rates ({', '.join(f'{r:g}' for r in sorted(rates))} Hz); "
                        "diagnose logs of one rate together")
    data = gap_data(parts, request.samples, request.norm_only, rates.pop() if rates else rate)
    data.fit_refused = refused
    data.sessions = [s for s, _, _ in parts]
    data.site_g = stated_site_g(data.sessions, [src for _, _, src in parts])
    if data.site_g is not None and data.ref is not None:  # unit references: gamma carries the site (site.py)
        data.ref = data.ref / data.site_g
    if choice is not None and not request.norm_only:
        data.fit_model, data.fit_faces = choice.model, choice.faces is not None
        data.exclude = NOT_IN_MODEL[choice.method if choice.faces is not None else choice.model]
        data.notes.append(f"baseline on fit's ground: {choice.method} as `accelcal fit` chooses it ({choice.reason})"
                          + (f"; not fitted: {', '.join(data.exclude)}" if data.exclude else ""))
    data.notes[:0] = inferred  # what reading the files inferred comes first in the summary
    return data


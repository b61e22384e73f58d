"""Loading for `accelcal diagnose`: the simulator a configuration describes, and the data as GapData."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .drivers.simulated import SimulatedBoard
from .errors import ConfigError, DataError, UnderdeterminedError, UnitsError
from .gap_data import Capture, GapData
from .noise_floor import Floor
from .loader import load
from .loading import device_section
from .models import check_plausible_g
from .models.gravity_norm import nominal_scale
from .rawlog import RawLog, static_session
from .sensor_model import SensorModel
from .session import Session

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


def _default_config() -> Path:
    """configs/sim.yaml, wherever the package is installed (an editable checkout or site-packages)."""
    from . import configs

    return Path(configs.__file__).parent / "sim.yaml"


def load_simulator(path=None) -> Simulator:
    """The simulated board of a station config (default configs/sim.yaml)."""
    path = Path(path) if path is not None else _default_config()
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
    return _captures(log, session, det)


def _captures(log: RawLog, session: Session, det):
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
    """Read pose tables (or, with ``raw``, raw logs) with the loader `accelcal fit` uses (loader.load).

    ``rate`` is the raw log's sample rate, or for pose tables the rate of the samples behind their std.
    """
    if not paths:
        raise DataError("no data files given; allowed: pose tables, or raw logs with --raw (or use --selftest)")
    parts, rates, inferred = [], set(), []
    for path in paths:
        loaded = load(str(path), raw, units=units, counts_per_g=counts_per_g, gravity_mps2=gravity,
                      columns=columns, skip_rows=skip_rows, rate_hz=rate if raw else None, references=False)
        inferred.append(f"{path}: " + "; ".join(loaded.inferred))
        if loaded.log is None:
            parts.append((loaded.session, None, str(path)))
            continue
        if not loaded.log.rate_hz:
            raise DataError(f"{path}: no time column and no --rate: the diagnosis needs the sample rate "
                            "(noise bandwidth, time within captures)")
        rates.add(round(loaded.log.rate_hz, 6))
        parts.append(_captures(loaded.log, loaded.session, loaded.detection))
    if len(rates) > 1:
        raise DataError(f"raw logs at different rates ({', '.join(f'{r:g}' for r in sorted(rates))} Hz); "
                        "diagnose logs of one rate together")
    data = gap_data(parts, samples, norm_only, rates.pop() if rates else rate)
    data.notes[:0] = inferred  # what reading the files inferred comes first in the summary
    return data


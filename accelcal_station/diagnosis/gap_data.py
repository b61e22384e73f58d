"""The data the diagnosis works on: pose means in nominal g (GapData), raw captures, and the
time view's block rows cut from the captures (TimeData; see gap_effects' module doc)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..data.sample_grid import distinct_samples, value_grid
from ..session import Session

TAU_DRIFT_S = np.geomspace(10.0, 1000.0, 13)
TAU_SETTLE_S = np.geomspace(0.02, 3.0, 19)
MAX_FOLDS = 8


# -- data ----------------------------------------------------------------------------------

@dataclass
class Capture:
    """Raw samples of one static pose: t (n,) seconds since its file started, x (n, 3) in data units."""

    t: np.ndarray
    x: np.ndarray
    per_g: float  # data units per nominal g
    decimals: int | None = None  # most decimals the log printed (the value grid allows their rounding)


@dataclass
class GapData:
    """Real (or simulated) data in nominal g, ready for the diagnosis.

    g: (P, 3) pose means; ref: (P, 3) expected output in g or None (norm-only);
    n: (P,) samples per mean (``n_known`` False: assumed); std_g: (P, 3) per-sample std or None;
    temp_c: (P,) or None; file: (P,) index into ``sources``; captures: one per pose (raw logs) or None.
    """

    names: list[str]
    g: np.ndarray
    ref: np.ndarray | None
    n: np.ndarray
    n_known: bool
    std_g: np.ndarray | None
    temp_c: np.ndarray | None
    file: np.ndarray
    captures: list[Capture] | None
    rate_hz: float | None
    sources: list[str]
    notes: list[str] = field(default_factory=list)
    counts_per_g: list = field(default_factory=list)  # per file: counts per g used (None: not counts)
    zero_g: np.ndarray | None = None  # (3,) the zero-g reading of the baseline fit (centres cubic and square)
    fit_model: str | None = None  # the model `accelcal fit` chooses for these data ("6" with fit_faces: hand-placed)
    fit_faces: bool = False  # fit's choice is the hand-placed faces' norm fit (gain and offset per axis)
    exclude: tuple[str, ...] = ()  # baseline effects fit's model has no terms for (loading.fit_ground)
    drop_terms: frozenset[str] = frozenset()  # "effect:term" columns left out (confounding.py)
    fit_refused: str = ""  # fit's words refusing these poses: no static view (loading.fit_ground)
    sessions: list[Session] = field(default_factory=list)  # per file, as fit reads it (headline.py)
    site_g: float | None = None  # the stated site's gravity in standard g (site.py); None: not stated

    @property
    def P(self) -> int:
        return len(self.g)

    @property
    def norm_only(self) -> bool:
        return self.ref is None

    @property
    def n_temps(self) -> int:
        return 0 if self.temp_c is None else len(np.unique(np.round(self.temp_c / 2.0)))

    def folds(self) -> np.ndarray:
        """Fold of every pose: round-robin over the recorded order (spreads designs, temperatures, time)."""
        return np.arange(self.P) % self.n_folds

    @property
    def n_folds(self) -> int:
        """Leave-one-out up to 12 poses (every pose counts), else MAX_FOLDS folds."""
        return self.P if self.P <= 12 else MAX_FOLDS


def value_step(x: np.ndarray, decimals: int | None = None) -> float:
    """The grid the values sit on (their LSB) in data units, allowing the rounding of ``decimals``
    printed decimals (data/sample_grid.value_grid); 0 when they are not on one."""
    return value_grid(x, decimals)


# -- time view data --------------------------------------------------------------------------

@dataclass
class TimeData:
    """Block rows of the raw captures (see module doc); every array is per row unless noted."""

    e: np.ndarray  # (R,) block mean minus capture mean, g
    axis: np.ndarray  # (R,)
    unit: np.ndarray  # (R,) pose index
    inv_m: np.ndarray  # (R,) 1/m_b - 1/n_k
    t_in: np.ndarray  # (R,) block mid time since the capture started, s
    drift1: np.ndarray  # (Gw, R) block-minus-capture mean of 1 - exp(-t/tau)
    drift2: np.ndarray  # (R,) same of t / T
    settle: np.ndarray  # (Gs, R) same of exp(-(t - t0)/tau)
    step_unit: np.ndarray  # (P, 3) direction of the last move: mean reading minus the previous capture's
    cap_drift1: np.ndarray  # (Gw, P) capture mean of 1 - exp(-t/tau)
    cap_drift2: np.ndarray  # (P,)
    cap_settle: np.ndarray  # (Gs, P) capture mean of exp(-(t - t0)/tau)
    diff_var: np.ndarray  # (P, 3) half the variance of first differences (white-noise variance), g^2
    step_units: np.ndarray  # (P,) value grid (LSB) of each capture, data units (0: none found)
    per_g: np.ndarray  # (P,) data units per g of each capture

    def lsb_g(self, use: np.ndarray) -> float:
        """The LSB of the captures selected by ``use``: gcd of their integer value grids, in g."""
        st = self.step_units[use]
        st = st[st > 0]
        if not st.size:
            return 0.0
        step = float(np.gcd.reduce(st.astype(np.int64))) if np.all(st == np.round(st)) else float(st.min())
        return step / float(np.median(self.per_g[use]))


def time_data(data: GapData) -> TimeData | None:
    """Cut every capture into blocks (at most 8, at least 12 samples each)."""
    caps = data.captures
    if caps is None:
        return None
    P = data.P
    span = np.zeros(len(data.sources))
    for k, c in enumerate(caps):
        span[data.file[k]] = max(span[data.file[k]], float(c.t[-1]))
    rows: dict[str, list] = {k: [] for k in ("e", "axis", "unit", "inv_m", "t_in", "d1", "d2", "s")}
    cap_d1 = np.zeros((len(TAU_DRIFT_S), P))
    cap_d2 = np.zeros(P)
    cap_s = np.zeros((len(TAU_SETTLE_S), P))
    diff_var = np.zeros((P, 3))
    step_units = np.zeros(P)
    means = np.array([c.x.mean(axis=0) / c.per_g for c in caps])
    step = np.zeros((P, 3))
    for k in range(1, P):
        if data.file[k] == data.file[k - 1]:
            step[k] = means[k] - means[k - 1]
    nrm = np.linalg.norm(step, axis=1, keepdims=True)
    step_unit = np.where(nrm > 0, step / np.where(nrm > 0, nrm, 1.0), 0.0)
    for k, c in enumerate(caps):
        # judged on distinct samples: a host polling faster than the chip updates repeats samples, and the
        # repeats would halve the noise of first differences and of block means (data/sample_grid.py)
        keep = distinct_samples(c.x)
        raw = c.x[keep]
        x = raw / c.per_g
        t = np.asarray(c.t, float)[keep]
        T = max(span[data.file[k]], 1e-9)
        h1 = 1.0 - np.exp(-t[None, :] / TAU_DRIFT_S[:, None])  # (Gw, n)
        h2 = t / T
        hs = np.exp(-(t[None, :] - t[0]) / TAU_SETTLE_S[:, None])  # (Gs, n)
        cap_d1[:, k], cap_d2[k], cap_s[:, k] = h1.mean(1), h2.mean(), hs.mean(1)
        diff_var[k] = 0.5 * np.var(np.diff(x, axis=0), axis=0, ddof=1) if len(x) > 2 else np.nan
        step_units[k] = value_step(raw, c.decimals)
        n = len(x)
        B = min(8, n // 12)
        if B < 2:
            continue
        xm = x.mean(axis=0)
        for idx in np.array_split(np.arange(n), B):
            m = len(idx)
            for a in range(3):
                rows["e"].append(x[idx, a].mean() - xm[a])
                rows["axis"].append(a)
                rows["unit"].append(k)
                rows["inv_m"].append(1.0 / m - 1.0 / n)
                rows["t_in"].append(float(t[idx].mean() - t[0]))
                rows["d1"].append(h1[:, idx].mean(1) - cap_d1[:, k])
                rows["d2"].append(h2[idx].mean() - cap_d2[k])
                rows["s"].append(hs[:, idx].mean(1) - cap_s[:, k])
    if not rows["e"]:
        return None
    return TimeData(np.array(rows["e"]), np.array(rows["axis"]), np.array(rows["unit"]), np.array(rows["inv_m"]),
                    np.array(rows["t_in"]), np.array(rows["d1"]).T, np.array(rows["d2"]), np.array(rows["s"]).T,
                    step_unit, cap_d1, cap_d2, cap_s, diff_var, step_units,
                    np.array([c.per_g for c in caps], float))

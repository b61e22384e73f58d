"""Evaluation: the held-out residuals and variances of one model, and the gaps they give (gap_effects)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

# a whole-data fit's parameters: label -> value (g, s, deg; ``sigma_g`` one per axis, ``_settling_a_g``
# each capture's held-out transient amplitude, (P, 3))
FitParams: TypeAlias = dict[str, float | list[float] | np.ndarray]

@dataclass
class Evaluation:
    """Held-out residuals and variances of one model (see module doc)."""

    added: tuple[str, ...]
    n_params: int
    r_static: np.ndarray | None  # (P, m) held-out residuals (m = 3 with references, 1 norm-only), g
    v_static: np.ndarray | None  # (P, m) their predicted variance (floor + fit), g^2
    floor_static: np.ndarray | None  # (P, m) floor alone
    r_time: np.ndarray | None  # (R,) held-out block residuals, g
    v_time: np.ndarray | None
    nll_unit: np.ndarray  # (P, 3) held-out negative log predictive density per pose and axis
    params: FitParams  # whole-data fit: label -> value
    fitted_static: np.ndarray | None = None  # (P, m) in-sample residuals of the whole-data fit
    r_spread: np.ndarray | None = None  # (P, 3) within-pose variance minus predicted, g^2 (scored, not in gap)
    v_spread: np.ndarray | None = None
    floor_time: np.ndarray | None = None  # (R,) the floor alone of the time view's rows
    pv_static: np.ndarray | None = None  # (P, m) the fit's own prediction variance of the held-out residuals

    def _rows(self) -> tuple[np.ndarray, np.ndarray]:
        r = [x.ravel() for x in (self.r_static, self.r_time) if x is not None]
        v = [x.ravel() for x in (self.v_static, self.v_time) if x is not None]
        return np.concatenate(r), np.concatenate(v)

    @property
    def gap(self) -> float:
        """Held-out residual RMS over the floor's RMS, the floor fixed before any candidate (1.0: at the floor).

        Only the residuals move it: the floor is the same for every model.  With raw captures
        both views count alike: the RMS of the static and time views' ratios.
        """
        gaps = [g for g in (self.floor_gap("static"), self.floor_gap("time")) if g is not None]
        return float(np.sqrt(np.mean(np.square(gaps))))

    def floor_gap(self, view: str) -> float | None:
        r, f = {"static": (self.r_static, self.floor_static), "time": (self.r_time, self.floor_time)}[view]
        return None if r is None or f is None else float(np.sqrt(np.sum(r**2) / np.sum(f)))

    def view_gap(self, view: str) -> float | None:
        r, v = {"static": (self.r_static, self.v_static), "time": (self.r_time, self.v_time),
                "spread": (self.r_spread, self.v_spread)}[view]
        return None if r is None or v is None else float(np.sqrt(np.sum(r**2) / np.sum(v)))

    @property
    def rms_g(self) -> float:
        r, _ = self._rows()
        return float(np.sqrt(np.mean(r**2)))

    @property
    def score(self) -> float:
        return float(np.mean(np.sum(self.nll_unit, axis=1)))


def nll(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Gaussian negative log predictive density of residual r with variance v."""
    return 0.5 * (np.log(2 * np.pi * v) + r**2 / v)

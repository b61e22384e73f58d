"""The twin's measurement noise, fitted to the lot's own residual and leave-one-out distributions.

A lot's stated per-sample std (std_x/y/z) is only where the fit starts: a station rounds it
(2.9 counts for a true 2.8672), and jig repeatability or thermal wander add scatter it does
not state.  What the check compares -- each board's residual RMS and leave-one-out RMS -- is
the noise measurement.  For boards whose residual is noise (most of a lot), both scale
linearly with the per-sample sd ``s``: ``r(s) = s r(1)``.  So the per-axis sds (their ratios
from the stated std, the level from the residuals) are scaled by

    k = exp(mean over q of log(Q_lot(q) / Q_twin(q)))

with Q the 25th, 50th and 75th percentiles of residual RMS and leave-one-out RMS (the lower
and middle of the distributions: a subpopulation's tail does not move them) of the lot and
of a lot simulated by the twin; two steps with the same simulated boards (common random
numbers), the second absorbing what is not linear (quantization, a residual that is not
noise).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..jsontypes import JsonObject
from .records import NoiseFit
from .simlot import simulate_cfg
from .stream import LotStats

QUANTILES = (25, 50, 75)
COLUMNS = ("residual_rms_mg", "crossval_rms_mg")
STEPS = 2
MIN_BOARDS, MAX_BOARDS = 2000, 20_000


def _quantiles(stats: LotStats) -> np.ndarray:
    out = []
    for c in COLUMNS:
        v = stats.column(c)
        v = v[np.isfinite(v) & (v > 0)]
        out.append(np.percentile(v, QUANTILES) if len(v) else np.full(len(QUANTILES), np.nan))
    return np.concatenate(out)


def fit_noise(config_for: Callable[[np.ndarray], JsonObject], start: np.ndarray, like: LotStats, seed: int
              ) -> tuple[np.ndarray, NoiseFit]:
    """Per-axis per-sample sd (counts) whose simulated residuals match the lot's (module
    docstring), and a report (start, fitted, scale, the quantiles matched)."""
    real = _quantiles(like)
    sd = np.asarray(start, dtype=float)
    boards = int(np.clip(like.boards, MIN_BOARDS, MAX_BOARDS))
    sim = real
    for _ in range(STEPS):
        sim = _quantiles(simulate_cfg(config_for(sd), like, boards, seed))
        ok = np.isfinite(real) & np.isfinite(sim) & (sim > 0)
        if not ok.any():
            break
        sd = sd * float(np.exp(np.mean(np.log(real[ok] / sim[ok]))))
    return sd, {"stated_sd_counts": [float(v) for v in start], "fitted_sd_counts": [float(v) for v in sd],
                "scale": float(sd[0] / start[0]) if start[0] > 0 else None,
                "matched": {f"{c} p{q}": {"lot": float(real[i * len(QUANTILES) + j]),
                                          "twin_before_last_step": float(sim[i * len(QUANTILES) + j])}
                            for i, c in enumerate(COLUMNS) for j, q in enumerate(QUANTILES)},
                "method": "per-axis sd from the stated std, scaled so the twin's residual and leave-one-out "
                          f"RMS percentiles {QUANTILES} match the lot's"}

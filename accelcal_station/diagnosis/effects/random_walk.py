"""drift as a random walk: Allan deviation within captures rising as sqrt(tau) above the white level."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .base import Signature, StochasticEffect

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import Capture, GapData, TimeData
    from ..noise_floor import Floor

N_PERM = 199  # permutations: smallest attainable p is 1/200 = 0.005
SKIP_START = 0.3  # fraction of each capture left out: a transient after the move is settling's, not drift's
MIN_SLOPE = 0.25  # Allan-deviation slope of the excess: 0.5 for a random walk, 0 for flicker (1/f)


def _detrended(captures: list[Capture]) -> list[np.ndarray]:
    """Each capture in g, its first SKIP_START left out and its own straight line removed (a warm-up or
    trend is drift's deterministic part)."""
    out = []
    for c in captures:
        keep = slice(int(SKIP_START * len(c.t)), None)  # a settling transient lives at the start
        x = c.x[keep] / c.per_g
        t = np.asarray(c.t[keep], float) - c.t[0]
        A = np.stack([np.ones_like(t), t], axis=1)
        out.append(x - A @ np.linalg.lstsq(A, x, rcond=None)[0])
    return out


def _avar(x: np.ndarray, m: int) -> np.ndarray:
    """Overlapping Allan variance at cluster size m (IEEE 952 Eqn C.2) of x (..., n, 3), averaged over axes."""
    c = np.concatenate([np.zeros(x.shape[:-2] + (1, x.shape[-1])), np.cumsum(x, axis=-2)], axis=-2)
    avg = (c[..., m:, :] - c[..., :-m, :]) / m
    d = avg[..., m:, :] - avg[..., :-m, :]
    return 0.5 * np.mean(d**2, axis=(-2, -1))


class RandomWalk(StochasticEffect):
    name = "drift"
    static_columns = False
    time_columns = False

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if td is None or data.captures is None:
            return False, "a random walk shows only within raw captures: it needs raw logs"
        if min(len(c.t) for c in data.captures) < 96:
            return False, "captures shorter than 96 samples are too short for an Allan deviation"
        return True, ""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float, seed: int = 0) -> Signature:
        """Permutation test: Allan variance at the longest cluster against the same samples shuffled in time.

        Shuffling within a capture keeps its white level and destroys time structure; a random walk
        leaves an excess whose Allan deviation rises as tau^0.5 (flicker: tau^0).
        """
        assert data.captures is not None, "testable: raw captures"
        caps = _detrended(data.captures)
        n = min(len(x) for x in caps)
        m2 = max(2, n // 4)
        m1 = max(1, m2 // 4)
        obs = np.array([[_avar(x, m) for m in (m1, m2)] for x in caps]).mean(axis=0)
        rng = np.random.default_rng(seed)
        perm = np.zeros((N_PERM, 2))
        for x in caps:  # all permutations of one capture at once
            xp = x[np.argsort(rng.random((N_PERM, len(x))), axis=1)]
            perm += np.stack([_avar(xp, m) for m in (m1, m2)], axis=1) / len(caps)
        white = perm.mean(axis=0)
        p = float((1 + np.sum(perm[:, 1] >= obs[1])) / (1 + N_PERM))
        ex = obs - white
        slope = float(0.5 * np.log(ex[1] / ex[0]) / np.log(m2 / m1)) if np.all(ex > 0) else None
        ratio = float(np.sqrt(obs[1] / white[1]))
        rw = p < alpha and slope is not None and slope > MIN_SLOPE
        if rw:
            reason = (f"Allan deviation at {m2} samples is {ratio:.2f} x the white level and its excess rises as "
                      f"tau^{slope:.2f}: a random walk")
        elif p < alpha:
            reason = (f"Allan deviation at {m2} samples is {ratio:.2f} x the white level but its excess is flat in tau "
                      f"(slope {slope if slope is None else round(slope, 2)}): time-varying, not a random walk")
        else:
            reason = f"Allan deviation at {m2} samples is at the white level ({ratio:.2f} x)"
        return Signature(self.name, bool(rw), p if rw else 1.0,
                         f"permutation test ({N_PERM} shuffles within captures) of the Allan variance at the longest "
                         f"cluster, and an excess slope above {MIN_SLOPE}", reason,
                         {"kind": "random walk", "adev_ratio": ratio, "excess_slope": slope, "p_excess": p,
                          "tau_s": [m1 / (data.rate_hz or 1.0), m2 / (data.rate_hz or 1.0)]})

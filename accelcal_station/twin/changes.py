"""Changes of a quantity's mean along the lot: binary segmentation with a CUSUM test.

On block sums (stream.LotStats: boards in order, blocks of B boards), for a segment of n
boards with total S and per-board standard deviation sigma (pooled within blocks), the
standardised CUSUM ``T = max_k |S_k - (k / n) S| / (sigma sqrt(n))`` tends under "no change"
to the supremum of a Brownian bridge, ``P(T > t) = kstwobign.sf(t)``: the p-value.  A
change is kept when ``p < alpha / m`` (Bonferroni over the m tests made).  At the
maximising k the step's log likelihood ratio is ``LR(k) = (S_k - k S / n)^2 n / (k (n - k)
sigma^2) / 2``; the boards whose ``LR`` is within ``chi2_1(0.95) / 2`` of the maximum give
the location's interval.  A step and a linear trend are both fitted to the segment's block
means; the one with the smaller residual sum of squares names the kind.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ALPHA = 1e-3  # family-wise false-alarm rate of the change search (per lot, over all quantities)
HALF_CHI2_95 = 3.841 / 2
MIN_BLOCKS = 8


@dataclass(frozen=True)
class Found:
    quantity: str
    kind: str  # step | trend
    at_board: int
    lo_board: int
    hi_board: int
    size: float  # step: jump; trend: change per board
    p_value: float


def _sigma(stats: np.ndarray) -> np.ndarray:
    """Pooled within-block standard deviation per quantity."""
    n, s, ss = stats[:, 0], stats[:, 1], stats[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        within = ss - np.where(n > 0, s * s / np.maximum(n, 1), 0.0)
    dof = np.clip(n - 1, 0, None).sum(axis=0)
    return np.sqrt(np.where(dof > 0, within.sum(axis=0) / np.maximum(dof, 1), np.nan))


def _cusum(n: np.ndarray, s: np.ndarray, sigma: float) -> tuple[int, float, np.ndarray]:
    """Best split (block index k: blocks [0, k) vs [k, end)), p-value and LR per split."""
    N, S = n.sum(), s.sum()
    cn, cs = np.cumsum(n)[:-1], np.cumsum(s)[:-1]
    dev = cs - cn / N * S
    T = np.max(np.abs(dev)) / (sigma * np.sqrt(N))
    with np.errstate(divide="ignore", invalid="ignore"):
        lr = np.where((cn > 0) & (cn < N), dev**2 * N / (cn * (N - cn)) / sigma**2 / 2, 0.0)
    from scipy.stats import kstwobign  # on first use: scipy.stats is ~50 MB and a second at start-up

    return int(np.argmax(lr)) + 1, float(kstwobign.sf(T)), lr


def _kind(n: np.ndarray, s: np.ndarray, k: int, start_board: int, block: int) -> tuple[str, float]:
    """Step (jump at block k) or trend (slope per board): the smaller weighted RSS, and its size."""
    m = s / np.maximum(n, 1)
    w = n.astype(float)
    left, right = slice(0, k), slice(k, len(m))
    mu_l = (s[left].sum() / max(n[left].sum(), 1))
    mu_r = (s[right].sum() / max(n[right].sum(), 1))
    rss_step = (w[left] * (m[left] - mu_l) ** 2).sum() + (w[right] * (m[right] - mu_r) ** 2).sum()
    t = start_board + block * (np.arange(len(m)) + 0.5)
    A = np.stack([np.ones_like(t), t], axis=1) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(A, m * np.sqrt(w), rcond=None)
    rss_trend = float(((A @ coef - m * np.sqrt(w)) ** 2).sum())
    if rss_trend < rss_step:
        return "trend", float(coef[1])
    return "step", float(mu_r - mu_l)


def find_changes(stats: np.ndarray, names: list[str], block: int, alpha: float = ALPHA,
                 max_depth: int = 3) -> list[Found]:
    """Changes of each quantity's mean along the lot (module docstring)."""
    sigma = _sigma(stats)
    tests = len(names) * (2**max_depth - 1)  # every segment binary segmentation may test
    out: list[Found] = []
    for q, name in enumerate(names):
        if not np.isfinite(sigma[q]) or sigma[q] <= 0:
            continue
        segs = [(0, len(stats), 0)]
        while segs:
            a, b, depth = segs.pop()
            n, s = stats[a:b, 0, q], stats[a:b, 1, q]
            if b - a < MIN_BLOCKS or depth >= max_depth:
                continue
            k, p, lr = _cusum(n, s, sigma[q])
            if p >= alpha / tests:
                continue
            inside = np.flatnonzero(lr >= lr.max() - HALF_CHI2_95) + 1
            kind, size = _kind(n, s, k, a * block, block)
            at = (a + k) * block if kind == "step" else a * block
            lo, hi = ((a + inside.min() - 1) * block, (a + inside.max() + 1) * block) if kind == "step" else (at, at)
            out.append(Found(name, kind, at, int(lo), int(hi), size, p))
            if kind == "step":
                segs += [(a, a + k, depth + 1), (a + k, b, depth + 1)]
    return out

"""Static poses of a raw log: the intervals where the board is held still, found automatically.

Static intervals are found relative to the log's own noise floor, so the same
code works on counts (signed or 16-bit unsigned), g or m/s^2 with no tuning:

1. moving standard deviation per axis over a window of about 0.1 s;
2. noise floor per axis: the 10th percentile of that moving std, scaled to a
   per-sample sigma with the chi distribution of a ``w``-sample std (so it holds
   as long as a tenth of the log is still), and never below the quantisation
   step / sqrt(12);
3. a window is still when every axis stays within ``STILL_FACTOR`` sigma; a
   sample is still when every window covering it is (which trims the edges next
   to motion), and edge windows whose mean is off the run's median by more than
   ``EDGE_FACTOR`` standard errors (a slow start or end of a move) are trimmed;
4. neighbouring still runs whose means agree within ``MERGE_FACTOR`` sigma are
   one pose (a glitch split it, or the board was only bumped), and poses held
   shorter than ``min_duration_s`` (about 1 s) are dropped.

Reading the log itself is rawlog.py.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import AccelcalError, DataError
from ..session import PoseRecord, Session
from .rawlog import RawLog
from .sample_grid import distinct_samples

STILL_FACTOR = 3.0  # windows whose std exceeds this many noise sigmas are motion
MERGE_FACTOR = 4.0  # neighbouring still runs closer than this many sigmas are the same pose
EDGE_FACTOR = 4.0  # edge windows whose mean is off by this many standard errors are trimmed
FLOOR_QUANTILE = 0.10
WINDOW_S = 0.1
MIN_DURATION_S = 1.0
WINDOW_NO_RATE = 16  # samples, when the rate is unknown
MIN_SAMPLES_NO_RATE = 64


@dataclass
class Segment:
    """One static pose: samples ``start``..``stop`` (stop exclusive) of the log, of which the
    ``n`` in ``ranges`` were used for the per-axis ``mean`` and ``std`` (log units)."""

    start: int
    stop: int
    mean: np.ndarray
    std: np.ndarray
    n: int
    ranges: list[tuple[int, int]] = field(default_factory=list)


@dataclass
class StaticDetection:
    """What segmentation found and the figures it used (per-axis sigma in log units)."""

    segments: list[Segment]
    window: int
    noise_sigma: np.ndarray
    threshold: np.ndarray
    min_samples: int
    still: np.ndarray  # (N,) bool, samples used


def moving_std(x: np.ndarray, w: int, chunk: int = 1 << 15) -> np.ndarray:
    """Std of every ``w``-sample window of each column: (N - w + 1, 3)."""
    x = x - np.median(x, axis=0)  # keeps 16-bit offsets from costing precision
    out = np.empty((len(x) - w + 1, x.shape[1]))
    for s in range(0, len(out), chunk):
        e = min(s + chunk, len(out))
        win = np.lib.stride_tricks.sliding_window_view(x[s:e + w - 1], w, axis=0)
        out[s:e] = win.std(axis=-1)
    return out


def _quantum(x: np.ndarray) -> np.ndarray:
    """Smallest step between distinct values per axis (the LSB of integer data)."""
    out = np.empty(x.shape[1])
    for a in range(x.shape[1]):
        d = np.diff(np.unique(x[:, a]))
        out[a] = d.min() if d.size else 0.0
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of every run of True in ``mask`` (stop exclusive)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def _segment(xyz: np.ndarray, ranges: list[tuple[int, int]]) -> Segment:
    """The pose made of the samples in ``ranges``: their mean and std (ddof 1)."""
    s = np.concatenate([xyz[a:b] for a, b in ranges])
    return Segment(ranges[0][0], ranges[-1][1], s.mean(axis=0), s.std(axis=0, ddof=1), len(s), list(ranges))


def detect_static(xyz: ArrayLike, rate_hz: float | None = None,
                  min_duration_s: float = MIN_DURATION_S) -> StaticDetection:
    """Find the static intervals of a log (steps 1-4 of the module doc)."""
    x = np.asarray(xyz, dtype=float)
    N = len(x)
    if rate_hz:
        w = int(np.clip(round(WINDOW_S * rate_hz), 5, 64))
        min_n = max(3 * w, int(round(min_duration_s * rate_hz)))
    else:
        w, min_n = WINDOW_NO_RATE, MIN_SAMPLES_NO_RATE
    if max(2 * w, min_n) > N:
        raise DataError(f"the log has {N} samples; finding static poses needs at least {max(2 * w, min_n)}")
    ms = moving_std(x, w)
    dof = w - 1
    from scipy.stats import chi2  # on first use: scipy.stats costs a second at start-up

    low = np.sqrt(chi2.ppf(FLOOR_QUANTILE, dof) / dof)  # 10th percentile of s / sigma
    med = np.median(x, axis=0)
    sigma = np.maximum(np.quantile(ms, FLOOR_QUANTILE, axis=0) / low, _quantum(x) / np.sqrt(12.0))
    # noiseless (simulated) data: a floor far below any motion, relative to the data's span
    sigma = np.maximum(sigma, 1e-9 * max(float(np.max(np.abs(x - med))), 1e-300))
    thr = STILL_FACTOR * sigma
    still_win = np.all(ms <= thr, axis=1)
    # a sample is still only when every window covering it is: erosion by w - 1
    cover = np.convolve((~still_win).astype(np.int64), np.ones(w, dtype=np.int64))
    still = cover == 0
    # trim edges whose window mean still leans toward the neighbouring motion (the slow
    # start and end of a move pass the std test but would bias the pose mean)
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(x - med, axis=0)])
    wmean = (c[w:] - c[:-w]) / w + med  # (N - w + 1, 3)
    tol = EDGE_FACTOR * sigma / np.sqrt(w)
    runs = []
    for a, b in _runs(still):
        if b - a < 2 * w:  # a pause inside a move, not a pose
            continue
        ok = np.flatnonzero(np.all(np.abs(wmean[a:b - w + 1] - np.median(x[a:b], axis=0)) <= tol, axis=1))
        if ok.size:
            runs.append((a + int(ok[0]), a + int(ok[-1]) + w))
    merged: list[list[tuple[int, int]]] = []
    for r in runs:
        if merged:
            prev = _segment(x, merged[-1])
            cur = x[r[0]:r[1]].mean(axis=0)
            if np.all(np.abs(cur - prev.mean) <= MERGE_FACTOR * sigma):
                merged[-1].append(r)
                continue
        merged.append([r])
    segs = [_segment(x, m) for m in merged]
    segs = [s for s in segs if s.n >= min_n]
    used = np.zeros(N, dtype=bool)
    for s in segs:
        for a, b in s.ranges:
            used[a:b] = True
    return StaticDetection(segs, w, sigma, thr, min_n, used)


def segment_static(t: ArrayLike | None, xyz: np.ndarray, rate_hz: float | None = None,
                   min_duration_s: float = MIN_DURATION_S) -> list[Segment]:
    """Static poses of a log (see detect_static).

    ``t``: sample times in seconds (they give the rate when ``rate_hz`` is None), or None
    for a log with no time and unknown rate (windows are then counted in samples).
    """
    if t is not None and rate_hz is None:
        t = np.asarray(t, dtype=float)
        if len(t) != len(xyz):
            raise DataError(f"t has {len(t)} samples and xyz {len(xyz)}; they must match")
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        rate_hz = 1.0 / dt if dt > 0 else None
    return detect_static(xyz, rate_hz, min_duration_s).segments


def to_session(log: RawLog, segments: list[Segment], units: str = "counts", counts_per_g: float | None = None,
               gravity_mps2: float | None = None, device: str | None = None) -> Session:
    """One PoseRecord per static segment (no references: such a session fits model 9).  A log that
    repeats samples (sample_grid.distinct_samples: a host polling faster than the chip updates)
    gives each pose its distinct samples as ``n``, so std / sqrt(n) is the noise of its mean."""
    distinct = distinct_samples(log.xyz)
    repeats = not distinct.all()
    poses = [PoseRecord(f"s{i + 1:02d}", s.mean, s.std,
                        sum(int(distinct[a:b].sum()) for a, b in s.ranges) if repeats else s.n,
                        t_start=float(log.t[s.start]), t_end=float(log.t[s.stop - 1])) for i, s in enumerate(segments)]
    return Session(poses, units, counts_per_g, gravity_mps2, device, {"source": log.source})


def static_session(log: RawLog, units: str = "counts", counts_per_g: float | None = None,
                   gravity_mps2: float | None = None) -> tuple[Session, StaticDetection]:
    """Find the static poses of a raw log and make them a Session; no pose is one clear error."""
    try:
        det = detect_static(log.xyz, log.rate_hz)
    except AccelcalError as e:
        raise type(e)(f"{log.source}: {e}") from None
    if not det.segments:
        sigma = " ".join(f"{x:.3g}" for x in det.noise_sigma)
        raise DataError(f"{log.source}: no static interval of {det.min_samples} samples or more found "
                        f"(noise floor [{sigma}]); hold each pose still for about 1 s")
    return to_session(log, det.segments, units, counts_per_g, gravity_mps2), det


__all__ = ["Segment", "StaticDetection", "detect_static", "moving_std", "segment_static", "static_session",
           "to_session"]

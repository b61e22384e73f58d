"""Gated capture: wait until the board is still, then average until precise enough.

Stillness is judged per block of samples against the measured noise floor (the
smallest per-axis block standard deviation seen so far, seeded from the first
blocks), with a hold time before averaging starts and hysteresis so a board at
the edge of the threshold does not flicker between still and moving:

  enter still:  block std <= k_enter * floor  and  |block mean - previous| <= k_enter * jump_floor
                for hold_s seconds (k_enter = 4.5: a still board of 3 axes fails a block ~2e-5 of the time)
  leave still:  either quantity beyond k_leave * (same bound)     (k_leave > k_enter)

``jump_floor`` is floor * sqrt(2 / n_block) for independent samples.  A chip's low-pass filter
(``Driver.noise_lag1``: rho_k = a^k) widens it: a block mean's variance is sigma^2 F / n with
F = 1 + 2 sum_k (1 - k/n) a^k, and the within-block std reads sigma sqrt((n - F) / (n - 1)), so
jump_floor = floor sqrt((n - 1) / (n - F)) sqrt(2 F / n) (the positive correlation of adjacent
block means is left out: the bound errs wide).  From the configured filter, not from the data,
so steady motion cannot widen it.

Averaging is adaptive.  A pose of the design with parameter targets (``target_offset_u_mg``,
``target_gain_u``) stops when it holds the samples the board's sequential plan allocates it
(station/sequential_capture.py: re-asked each time the count is reached) and, when
``target_sem_mg`` is set, also every axis's standard error is below it (a floor).  Any other
capture (or every one when no parameter target is set) stops once every axis's standard error of
the mean, std / sqrt(n_eff) with n_eff = n / tau_int from the samples' own autocorrelation
(models/effective_samples.py: Sokal's window, c = 5), is below ``target_sem_mg`` (0.05 mg when
unset); both rules need at least ``min_samples``, or stop at ``max_s``.
Motion while averaging discards the average and starts over (a re-capture).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike

from ..conventions import angle_deg, fit_mount, mount_hint, nearest_face
from ..drivers.base import Capture, Driver
from ..errors import DeviceError
from ..models.effective_samples import effective_n

log = logging.getLogger(__name__)


@dataclass
class CaptureSettings:
    block_s: float = 0.1
    k_enter: float = 4.5
    k_leave: float = 7.0
    hold_s: float = 0.3
    target_sem_mg: float | None = None  # per-pose SEM, mg: the compat rule, else a floor (module docstring)
    target_offset_u_mg: float | None = 0.018  # the fitted offsets' standard uncertainty target, mg
    target_gain_u: float | None = 1e-4  # the fitted gains' standard uncertainty target, fraction (100 ppm)
    min_samples: int = 32
    max_s: float = 20.0
    settle_timeout_s: float = 30.0
    pose_tolerance_deg: float = 12.0
    max_recaptures: int = 3
    self_test_samples: int = 64  # averaged in each self-test state (station/board.py _self_test)
    warmup: dict[str, object] | None = None  # config.schema WarmupSection's fields (station/warmup.py)
    powered_ahead_s: float = 60.0  # how long a board has been powered when placed (station/warmup.py)


@dataclass
class GatedCapture:
    """A capture plus how it was gated."""

    capture: Capture
    recaptures: int
    waited_s: float
    reached_target: bool
    floor_counts: np.ndarray
    samples_read: int = 0
    events: list[str] = field(default_factory=list)


DEFAULT_SEM_MG = 0.05  # a capture's per-axis SEM target when capture.target_sem_mg is unset
MIN_TAUS = 50  # samples a capture spans, in integrated autocorrelation times, before it may stop


def jump_factor(n: int, a: float) -> float:
    """jump_floor / floor for blocks of n samples with lag-1 correlation a (module docstring)."""
    if a <= 0.0 or n < 2:
        return float(np.sqrt(2.0 / max(n, 1)))
    k = np.arange(1, n)
    F = 1.0 + 2.0 * float(np.sum((1.0 - k / n) * a**k))
    return float(np.sqrt((n - 1) / max(n - F, 1.0)) * np.sqrt(2.0 * F / n))


@lru_cache(maxsize=64)
def _chi_quartile(n: int) -> float:
    """25th percentile of s / sigma for n samples: chi with n - 1 dof, by the
    Wilson-Hilferty cube-root approximation (within 0.7 % for n >= 4; no scipy import in the capture loop)."""
    k = n - 1
    z = -0.6744897501960817  # standard normal 25th percentile
    return float(np.sqrt((1.0 - 2.0 / (9 * k) + z * np.sqrt(2.0 / (9 * k))) ** 3))


class StillnessGate:
    """Tracks the noise floor and the still/moving state block by block (with hysteresis).

    The floor is the 25th percentile of the last 64 blocks' per-axis std, divided by
    that percentile of the chi distribution for the block size: unbiased on still data
    and unmoved by motion in up to three blocks of four.  A floor carried over from the
    previous pose is used until eight blocks of this one are in.
    """

    def __init__(self, settings: CaptureSettings, floor_counts: np.ndarray | None = None, lag1: float = 0.0):
        self.s = settings
        self.lag1 = float(lag1)
        self.seed = None if floor_counts is None else np.asarray(floor_counts, dtype=float)
        # counts per axis; without a seed it is measured from the first block on (nan until then)
        self.floor: np.ndarray = self.seed if self.seed is not None else np.full(3, np.nan)
        self.history: list[np.ndarray] = []
        self.prev_mean: np.ndarray | None = None
        self.still = False
        self.still_since: float | None = None

    def update(self, block: np.ndarray, t_end: float) -> bool:
        n = len(block)
        std = block.std(axis=0, ddof=1)
        mean = block.mean(axis=0)
        self.history = (self.history + [std])[-64:]
        q = _chi_quartile(n)
        est = np.percentile(np.array(self.history), 25, axis=0) / q
        if self.seed is None or len(self.history) >= 8:
            # quantisation can make a quiet axis read std 0: never let the floor reach zero
            self.floor = np.maximum(est, 0.3)
        jump = np.zeros(3) if self.prev_mean is None else np.abs(mean - self.prev_mean)
        self.prev_mean = mean
        k = self.s.k_leave if self.still else self.s.k_enter
        jump_floor = self.floor * jump_factor(n, self.lag1)
        ok = bool(np.all(std <= k * self.floor) and np.all(jump <= k * jump_floor + 1.0))
        if ok and not self.still:
            if self.still_since is None:
                self.still_since = t_end
            if t_end - self.still_since >= self.s.hold_s:
                self.still = True
        elif not ok:
            self.still = False
            self.still_since = None
        return self.still


def gated_capture(driver: Driver, settings: CaptureSettings, expected_g: np.ndarray | None = None,
                  floor_counts: np.ndarray | None = None, keep: bool = False,
                  progress: Callable[[float], None] | None = None,
                  needed: Callable[[np.ndarray], int] | None = None) -> GatedCapture:
    """Capture one pose: wait for stillness, average adaptively, re-capture on motion.

    expected_g: the planned pose's expected output; a measured direction further than
    ``pose_tolerance_deg`` from it is refused, naming the face the board is actually on.
    needed: the samples this pose needs given its samples so far (a sequential plan); None: the SEM rule.
    """
    s = settings
    block_n = max(4, int(round(s.block_s * driver.odr_hz)))
    gate = StillnessGate(s, floor_counts, driver.noise_lag1())
    sem_rule = needed is None or s.target_sem_mg is not None  # the SEM rule alone, or a plan's floor
    target = (DEFAULT_SEM_MG if s.target_sem_mg is None else s.target_sem_mg) * 1e-3 * driver.counts_per_g
    want = s.min_samples  # the plan is first asked once this many samples are in
    events: list[str] = []
    recaptures = 0
    waited = 0.0
    t_first = None
    acc: list[np.ndarray] = []
    ts: list[np.ndarray] = []
    dropped = 0
    read = 0
    while True:
        counts, t, d = driver.read_samples(block_n)
        read += len(counts)
        if t_first is None:
            t_first = float(t[0])
        still = gate.update(counts.astype(float), float(t[-1]))
        if not still:
            if acc:
                recaptures = _discarded(s, events, recaptures + 1, float(t[-1]) - t_first)
                acc, ts, dropped = [], [], 0
            waited = float(t[-1]) - t_first
            if waited > s.settle_timeout_s:
                raise NotStill(f"board not still after {s.settle_timeout_s:g} s "
                                  f"(noise floor {np.round(gate.floor, 1).tolist()} counts)")
            continue
        acc.append(counts)
        ts.append(t)
        dropped += d
        n = sum(len(a) for a in acc)
        allc = np.concatenate(acc)
        n_eff = effective_n(allc)
        sem = allc.std(axis=0, ddof=1) / np.sqrt(n_eff)
        elapsed = float(ts[-1][-1] - ts[0][0])
        if needed is not None and n >= want:
            want = max(s.min_samples, needed(allc))
        sem_ok = not sem_rule or bool(np.all(sem <= target))
        if progress is not None:
            done = n / want if needed is not None else float(np.min(target / np.maximum(sem, 1e-12))) ** 2
            progress(min(1.0, max(elapsed / s.max_s, done)))
        # tau_int from a capture of a few tau reads low (Sokal's window bias ~ tau / n): at least MIN_TAUS x tau
        reached = sem_ok and n >= max(want, MIN_TAUS * float(np.max(n / n_eff)))
        if reached or elapsed >= s.max_s:
            cap = _on_pose(Capture.from_samples(allc, np.concatenate(ts), dropped, driver.temperature_c(), keep),
                           expected_g, s.pose_tolerance_deg)
            return GatedCapture(cap, recaptures, waited, reached, gate.floor.copy(), read, events)


def _discarded(s: CaptureSettings, events: list[str], recaptures: int, at_s: float) -> int:
    """The board moved during a capture: its average is discarded (``recaptures`` so far, this one
    included); NotStill once more than ``capture.max_recaptures`` were."""
    events.append(f"moved during capture at t={at_s:.2f} s: average discarded")
    log.info("capture retried (%d of %d): %s", recaptures, s.max_recaptures, events[-1])
    if recaptures > s.max_recaptures:
        raise NotStill(f"board kept moving: {recaptures} captures discarded (max {s.max_recaptures})")
    return recaptures


def _on_pose(cap: Capture, expected_g: np.ndarray | None, tolerance_deg: float) -> Capture:
    """The capture, unless its measured direction is further than ``tolerance_deg`` from the planned
    pose's (WrongPose names the face the board is actually on)."""
    if expected_g is not None:
        ang = angle_deg(cap.mean_counts, expected_g)
        if ang > tolerance_deg:
            raise WrongPose(expected_g, cap.mean_counts, ang)
    return cap


def wait_still(driver: Driver, settings: CaptureSettings) -> int:
    """Read blocks until the board has been still for ``hold_s`` (the capture's stillness gate); the samples
    read.  A board not still after ``settle_timeout_s`` is a DeviceError naming its noise floor."""
    s = settings
    block_n = max(4, int(round(s.block_s * driver.odr_hz)))
    gate = StillnessGate(s, lag1=driver.noise_lag1())
    read = 0
    t_first = None
    while True:
        counts, t, _ = driver.read_samples(block_n)
        read += len(counts)
        t_first = float(t[0]) if t_first is None else t_first
        if gate.update(counts.astype(float), float(t[-1])):
            return read
        if float(t[-1]) - t_first > s.settle_timeout_s:
            raise NotStill(f"board not still after {s.settle_timeout_s:g} s "
                              f"(noise floor {np.round(gate.floor, 1).tolist()} counts)")


class NotStill(DeviceError):
    """The board did not hold still long enough to be captured: judged at the capture (a board, a hand
    or the room), not an instrument's fault."""


class WrongPose(DeviceError):
    """The board is not in the planned pose; names the face it is actually on (the face whose
    axis points up: a chip reads +1 g on the axis pointing away from the Earth).  ``mount``: the
    mounting the hint names (None without one)."""

    def __init__(self, expected_g: ArrayLike, measured: ArrayLike, angle: float, hint: str | None = None,
                 mount: np.ndarray | None = None) -> None:
        self.expected_g = np.asarray(expected_g, dtype=float)
        self.measured = np.asarray(measured, dtype=float)
        self.angle = angle
        self.hint = hint
        self.mount = mount
        super().__init__(
            f"board is {angle:.0f} deg from the planned pose: it is on '{nearest_face(measured)}', "
            f"the plan wants '{nearest_face(expected_g)}'" + (f"; {hint}" if hint else ""))


class MountMismatch(WrongPose):
    """The readings of the first poses fit one other mounting of the chip (device.mount) exactly."""


# what a board has read so far: (the pose's expected output in board axes, the mean reading)
Seen = list[tuple[np.ndarray, np.ndarray]]


def with_mounting(seen: Seen, reference_g: np.ndarray, e: WrongPose, mount: np.ndarray, tolerance_deg: float,
                  key: str = "device.mount") -> WrongPose:
    """A wrong pose, with the mounting that fits this and the poses captured so far (``seen``: their
    expected and measured readings) when it is not device.mount: a MountMismatch once the readings
    single it out."""
    return named_mounting([*seen, (reference_g, e.measured)], e, mount, tolerance_deg, key)


def named_mounting(seen: Seen, e: WrongPose, mount: np.ndarray, tolerance_deg: float,
                   key: str = "device.mount") -> WrongPose:
    """``e`` with the mounting that fits every reading of ``seen`` (``e``'s own among them) when it is
    not ``mount``, and ``key``, the config line that sets it; ``e`` itself when none of the 24 fits."""
    r = np.array([o[0] for o in seen])
    m = np.array([o[1] for o in seen])
    hint = mount_hint(r, m, mount, tolerance_deg, key)
    if hint is None:
        return e
    P, _, unique = fit_mount(r, m)
    return (MountMismatch if unique else WrongPose)(e.expected_g, e.measured, e.angle, hint, P)

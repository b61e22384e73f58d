"""The warm-up hold (issue 48; docs/warm-up.md): a freshly powered board heats itself and its offset
settles (data sheets: 0.5-0.9 mg/K offset tempco); the station holds it before the self-test and the
poses, until the mean of one window differs from the previous window's by less than
``drift_limit_mg`` on every axis (mode ``settled``, at most ``max_s``), or for ``time_s`` (mode ``time``).
What it did goes in the run record as ``warmup``."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..drivers.base import Driver
from ..i18n import language_of, translator
from .report import RunReport, WarmupRecord
from .settings import StationConfig


def warmup_step(driver: Driver, cfg: StationConfig, rep: RunReport, echo: Callable[[str], None]) -> int:
    """Hold the board as ``capture.warmup`` says (nothing without it); the samples read."""
    w = cfg.capture.warmup
    if not w:
        return 0
    tr = translator(language_of(cfg.schema.station))
    if w["mode"] == "time":
        echo(tr("warm-up: holding the board for {s} s").format(s=f"{float(w['time_s']):g}"))  # type: ignore[arg-type]
        held, read = _hold(driver, float(w["time_s"]))  # type: ignore[arg-type]
        rep.warmup = WarmupRecord(mode="time", held_s=held, settled=None, drift_mg=None, window_s=None,
                                  drift_limit_mg=None)
        return read
    window, limit, max_s = (float(w[k]) for k in ("window_s", "drift_limit_mg", "max_s"))  # type: ignore[arg-type]
    echo(tr("warm-up: holding the board until its offset settles (below {limit} mg per {window} s)")
         .format(limit=f"{limit:g}", window=f"{window:g}"))
    settled, held, drift, read = _settle(driver, window, limit, max_s)
    rep.warmup = WarmupRecord(mode="settled", held_s=held, settled=settled, drift_mg=drift, window_s=window,
                              drift_limit_mg=limit)
    if settled:
        echo(tr("warm-up: settled after {s} s").format(s=f"{held:.0f}"))
    else:
        echo(tr("warm-up: not settled after {s} s; calibrating anyway").format(s=f"{held:.0f}"))
        rep.events.append(f"warm-up: offset not settled after {held:.0f} s "
                          f"(drift {max(drift):.3f} mg per {window:g} s, limit {limit:g})")
    return read


def _hold(driver: Driver, seconds: float) -> tuple[float, int]:
    """Read (and drop) samples for ``seconds`` of board time: the board's clock runs on its samples."""
    n = max(1, int(round(driver.odr_hz)))
    t0: float | None = None
    read = 0
    while True:
        counts, t, _ = driver.read_samples(n)
        read += len(counts)
        t0 = float(t[0]) if t0 is None else t0
        if float(t[-1]) - t0 >= seconds:
            return float(t[-1]) - t0, read


def _settle(driver: Driver, window_s: float, limit_mg: float, max_s: float
            ) -> tuple[bool, float, list[float], int]:
    """Window means until two in a row differ by at most limit_mg on every axis, or max_s."""
    n = max(2, int(round(window_s * driver.odr_hz)))
    prev: np.ndarray | None = None
    t0: float | None = None
    read = 0
    drift = [float("inf")] * 3
    while True:
        counts, t, _ = driver.read_samples(n)
        read += len(counts)
        t0 = float(t[0]) if t0 is None else t0
        mean_mg = counts.mean(axis=0) / driver.counts_per_g * 1e3
        held = float(t[-1]) - t0
        if prev is not None:
            d = np.abs(mean_mg - prev)
            drift = [round(float(v), 4) for v in d]
            if np.all(d <= limit_mg):
                return True, held, drift, read
        if held >= max_s:
            return False, held, drift, read
        prev = mean_mg

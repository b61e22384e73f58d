"""The warm-up hold (issue 48; docs/warm-up.md): a freshly powered board heats itself and its offset
settles (data sheets: 0.5-0.9 mg/K offset tempco); the station holds it before the self-test and the
poses, until the mean of one window differs from the previous window's by less than
``drift_limit_mg`` on every axis (mode ``settled``, at most ``max_s``), or for ``time_s`` (mode ``time``).

A panel (or a thermal plan's boards) is held at once: every board still held reads one window in
turn, each judged by the same rule on its own windows, until every board has settled or reached
``max_s``; the panel then waits for its slowest board.  What each board did goes in its run record
as ``warmup`` and its hold in ``timing.warmup_s``.

A line hides the warm-up by powering boards ahead (``capture.powered_ahead_s``: the next board sits
powered while the previous one is measured); the simulated station models it by starting each
simulated board's warm-up clock that long before it is opened (``power_ahead``)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..drivers.base import Driver
from ..errors import AccelcalError
from ..fixtures.factory import board_of
from ..i18n import language_of, translator
from .report import RunReport, WarmupRecord
from .settings import StationConfig


@dataclass
class Held:
    """One board's hold: its driver, its report, and what the hold has seen so far."""

    driver: Driver
    rep: RunReport
    echo: Callable[[str], None]
    read: int = 0
    t0: float | None = None
    held_s: float = 0.0
    prev_mg: np.ndarray | None = None
    drift_mg: list[float] = field(default_factory=lambda: [float("inf")] * 3)
    done: bool = False
    settled: bool = False
    error: AccelcalError | None = None


def power_ahead(driver: Driver, seconds: float) -> None:
    """A simulated board placed after waiting ``seconds`` powered: its warm-up clock starts that long
    before now (drivers/simulated.py ``powered_for``).  Real hardware is powered by the line, not here."""
    board = board_of(driver)
    if board is not None and seconds > 0:
        board.powered_for(seconds)


def warmup_step(driver: Driver, cfg: StationConfig, rep: RunReport, echo: Callable[[str], None]) -> int:
    """Hold one board as ``capture.warmup`` says (nothing without it); the samples read.  Device
    errors propagate."""
    (h,) = hold_boards([(driver, rep, echo)], cfg)
    if h.error is not None:
        raise h.error
    return h.read


def hold_boards(boards: Sequence[tuple[Driver, RunReport, Callable[[str], None]]], cfg: StationConfig
                ) -> list[Held]:
    """Hold every board at once (module doc); a board whose device errs stops being held and keeps
    its error in ``Held.error`` for the flow to judge.  Each board speaks through its own echo."""
    w = cfg.capture.warmup
    held = [Held(d, r, e) for d, r, e in boards]
    if not w:
        return held
    tr = translator(language_of(cfg.schema.station))
    settled_mode = w["mode"] == "settled"
    window = float(w["window_s"]) if settled_mode else 1.0  # type: ignore[arg-type]
    limit = float(w["drift_limit_mg"])  # type: ignore[arg-type]
    max_s = float(w["max_s"] if settled_mode else w["time_s"])  # type: ignore[arg-type]
    for h in held:
        h.echo(tr("warm-up: holding the board until its offset settles (below {limit} mg per {window} s)")
               .format(limit=f"{limit:g}", window=f"{window:g}") if settled_mode else
               tr("warm-up: holding the board for {s} s").format(s=f"{max_s:g}"))
    while not all(h.done for h in held):
        for h in (h for h in held if not h.done):
            try:
                _window(h, window, limit if settled_mode else None, max_s)
            except AccelcalError as e:
                h.error, h.done = e, True
    for h in held:
        if h.error is None:
            _record(h, cfg, tr, settled_mode, window, limit)
    return held


def _window(h: Held, window_s: float, limit_mg: float | None, max_s: float) -> None:
    """One window of board ``h``: read it, compare its mean with the previous window's (mode settled:
    ``limit_mg`` given), and say whether the board is done."""
    n = max(2, int(round(window_s * h.driver.odr_hz)))
    counts, t, _ = h.driver.read_samples(n)
    h.read += len(counts)
    h.t0 = float(t[0]) if h.t0 is None else h.t0
    h.held_s = float(t[-1]) - h.t0  # board time: its clock runs on its samples
    mean_mg = counts.mean(axis=0) / h.driver.counts_per_g * 1e3
    if limit_mg is not None and h.prev_mg is not None:
        d = np.abs(mean_mg - h.prev_mg)
        h.drift_mg = [round(float(v), 4) for v in d]
        if np.all(d <= limit_mg):
            h.done = h.settled = True
            return
    h.prev_mg = mean_mg
    if h.held_s >= max_s:
        h.done = True


def _record(h: Held, cfg: StationConfig, tr: Callable[[str], str], settled_mode: bool, window: float,
            limit: float) -> None:
    """The board's ``warmup`` record and what it says on screen."""
    ahead = float(cfg.capture.powered_ahead_s)
    if not settled_mode:
        h.rep.warmup = WarmupRecord(mode="time", held_s=h.held_s, settled=None, drift_mg=None, window_s=None,
                                    drift_limit_mg=None, powered_ahead_s=ahead)
        return
    h.rep.warmup = WarmupRecord(mode="settled", held_s=h.held_s, settled=h.settled, drift_mg=h.drift_mg,
                                window_s=window, drift_limit_mg=limit, powered_ahead_s=ahead)
    if h.settled:
        h.echo(tr("warm-up: settled after {s} s").format(s=f"{h.held_s:.0f}"))
        return
    h.echo(tr("warm-up: not settled after {s} s; calibrating anyway").format(s=f"{h.held_s:.0f}"))
    h.rep.events.append(f"warm-up: offset not settled after {h.held_s:.0f} s "
                        f"(drift {max(h.drift_mg):.3f} mg per {window:g} s, limit {limit:g})")

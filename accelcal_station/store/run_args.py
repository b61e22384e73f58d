"""What a station hands the store about one run: ``RunStart`` (who, where, what, when it began:
``Store.start_run``) and ``RunResult`` (the poses, calibration, verdict and NVM outcome it ended with:
``Store.finish_run``), and the same fields as keyword arguments (``RunStartFields``, ``RunResultFields``,
PEP 692), the form the store's callers have always used."""
from __future__ import annotations

import hashlib
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol, TypedDict, TypeVar

from ..acceptance.reasons import Reason
from ..calibration import Calibration
from ..session import Session


class _HasDict(Protocol):
    def to_dict(self) -> Mapping[str, object]: ...


Outcome = _HasDict | Mapping[str, object]  # an NVM burn's outcome: nvm.writer.BurnOutcome or its dict


class RunStartFields(TypedDict, total=False):
    """``Store.start_run``'s keyword arguments: RunStart's fields."""

    device_serial: str | None  # required when no RunStart is given (the constructor says so)
    chip: str | None
    station_id: str | None
    operator: str | None
    lot: str | None
    config_text: str | None
    config_hash: str | None
    model: str | None
    units: str | None
    counts_per_g: float | None
    gravity_mps2: float | None
    started_at: float | None
    panel_id: str | None


@dataclass(frozen=True)
class RunStart:
    """A run as it starts: the board, station, operator and lot, the config it runs (``config_hash``: the
    SHA-256 of ``config_text`` when not given), the model and units, and ``started_at`` (unix s; None: when
    the store commits it).  ``panel_id`` ties the runs of the boards calibrated together on one jig."""

    device_serial: str | None
    chip: str | None = None
    station_id: str | None = None
    operator: str | None = None
    lot: str | None = None
    config_text: str | None = None
    config_hash: str | None = None
    model: str | None = None
    units: str | None = None
    counts_per_g: float | None = None
    gravity_mps2: float | None = None
    started_at: float | None = None
    panel_id: str | None = None

    def __post_init__(self) -> None:
        if self.config_hash is None and self.config_text is not None:
            object.__setattr__(self, "config_hash", hashlib.sha256(self.config_text.encode()).hexdigest())

    def stamped(self, now: float | None = None) -> RunStart:
        """This start with its time fixed (now, unless it has one): a run started again elsewhere (the
        outbox) keeps it."""
        if self.started_at is not None:
            return self
        return replace(self, started_at=time.time() if now is None else float(now))


class RunResultFields(TypedDict, total=False):
    """``Store.finish_run``'s keyword arguments: RunResult's fields."""

    session: Session  # these three required when no RunResult is given
    calibration: Calibration | None
    verdict: str | None
    reasons: Iterable[Reason]
    nvm_outcome: Outcome | None
    fit_summary: Mapping[str, object] | None
    model: str | None
    retries: Sequence[int] | None
    finished_at: float | None
    limits: Mapping[str, float] | None
    site: Mapping[str, object] | None
    uncertainty: Mapping[str, object] | None


@dataclass(frozen=True)
class RunResult:
    """How a run ended: its poses (``session``, with ``retries`` per pose), the calibration and verdict
    (None: not judged), the reasons (Reason objects; a plain string is kept with code ""), the NVM
    outcome (a writer.BurnOutcome, its dict, or None when nothing was burned), the fit summary, the
    acceptance ``limits`` the verdict was judged by ({key: number}), the ``site``'s gravity (config/site.py
    Site.to_json) and the ``uncertainty`` budget and decision rule (schema 6)."""

    session: Session
    calibration: Calibration | None
    verdict: str | None
    reasons: Iterable[Reason] = ()
    nvm_outcome: Outcome | None = None
    fit_summary: Mapping[str, object] | None = None
    model: str | None = None
    retries: Sequence[int] | None = None
    finished_at: float | None = None
    limits: Mapping[str, float] | None = None
    site: Mapping[str, object] | None = None
    uncertainty: Mapping[str, object] | None = None


_Args = TypeVar("_Args", RunStart, RunResult)


def one_of(given: _Args | None, fields: Mapping[str, Any], kind: type[_Args]) -> _Args:
    """The parameter object, or one built from its fields given as keywords (not both)."""
    if given is None:
        return kind(**fields)
    if fields:
        raise TypeError(f"give a {kind.__name__} or its fields as keywords, not both")
    return given

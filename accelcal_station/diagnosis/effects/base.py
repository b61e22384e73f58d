"""The GapEffect protocol of the diagnosis: one small class per catalog effect.

Deterministic effects contribute design columns to the static view (pose means) or the
time view (block means within raw captures) and are judged by held-out residuals
(gap_effects.evaluate).  Stochastic effects change only the variance
of what is left; they are judged by their own signature (``signature``) and never move
the headline gap.  Every effect is one class derived from DeterministicEffect or
StochasticEffect, so adding an effect is one file plus its entry in effects/catalog.py.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from ...jsontypes import JsonObject

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import GapData, TimeData
    from ..noise_floor import Floor
    from .columns import StaticView


@dataclass
class Signature:
    """The outcome of a stochastic effect's own test: passed at level alpha, its p-value and the evidence."""

    effect: str
    passed: bool
    p_value: float
    test: str
    reason: str
    evidence: JsonObject = field(default_factory=dict)  # each effect's own figures (an open JSON object)

    def to_json(self) -> JsonObject:
        return {"effect": self.effect, "passed": self.passed, "p_value": self.p_value, "test": self.test,
                "reason": self.reason, **self.evidence}


class GapEffect(Protocol):
    """One catalog effect as the diagnosis sees it."""

    name: str
    kind: str  # "deterministic" (design columns, judged by held-out residuals) or "stochastic" (signature)
    static_columns: bool  # contributes columns to the static view's design
    time_columns: bool  # contributes columns to the time view's design (fitted in time_view)

    def columns(self, view: StaticView) -> None:
        """Append this effect's static design columns to ``view`` (nothing for a stochastic effect)."""

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        """Whether these data can reveal the effect, and why not."""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature | None:
        """The stochastic signature test (None for deterministic effects)."""


class DeterministicEffect:
    """A parametric term of the measurement model: design columns, judged by held-out residuals."""

    name = ""
    kind = "deterministic"
    static_columns = True
    time_columns = False
    # why the design rank check fails for it (candidates.candidates adds the design's own words)
    degenerate = "these poses do not separate it from the baseline"

    def columns(self, view: StaticView) -> None:
        return None

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        """Effect-specific conditions only; the design's rank and degrees of freedom are candidates.candidates'."""
        return True, ""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature | None:
        return None  # never judged by a variance signature


class StochasticEffect(ABC):
    """A change of the residuals' variance only: judged by ``signature``, never by the headline gap."""

    name = ""
    kind = "stochastic"
    static_columns = False
    time_columns = False

    def columns(self, view: StaticView) -> None:
        return None  # no design columns: it cannot move the held-out residuals

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        return True, ""

    @abstractmethod
    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature:
        """The effect's signature test on the held-out residuals (each stochastic effect has its own)."""

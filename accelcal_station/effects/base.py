"""The Effect protocol of the diagnosis: one small class per catalog effect.

Deterministic effects contribute design columns to the static view (pose means) or the
time view (block means within raw captures) and are judged by held-out residuals
(accelcal_station.gap_effects.evaluate).  Stochastic effects change only the variance
of what is left; they are judged by their own signature (``signature``) and never move
the headline gap.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from ..gap_effects import Evaluation, Floor, GapData, TimeData


@dataclass
class Signature:
    """The outcome of a stochastic effect's own test: passed at level alpha, its p-value and the evidence."""

    effect: str
    passed: bool
    p_value: float
    test: str
    reason: str
    evidence: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"effect": self.effect, "passed": self.passed, "p_value": self.p_value, "test": self.test,
                "reason": self.reason, **self.evidence}


class Effect(Protocol):
    """One catalog effect as the diagnosis sees it."""

    name: str
    kind: str  # "deterministic" (design columns, judged by held-out residuals) or "stochastic" (signature)
    static_columns: bool  # contributes columns to the static view's design
    time_columns: bool  # contributes columns to the time view's design

    def testable(self, data: "GapData", td: "TimeData | None") -> tuple[bool, str]:
        """Whether these data can reveal the effect, and why not."""

    def signature(self, data: "GapData", floor: "Floor", ev: "Evaluation", td: "TimeData | None",
                  alpha: float) -> Signature | None:
        """The stochastic signature test (None for deterministic effects)."""

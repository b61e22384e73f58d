"""settling: a transient a_k exp(-(t - t0_k) / tau) at the start of each capture.

No static columns: the time view fits it (time_view, shared tau, per-capture amplitude as a
random effect) and removes its mean from the pose means."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .base import DeterministicEffect

if TYPE_CHECKING:
    from ..gap_data import GapData, TimeData


class Settling(DeterministicEffect):
    name = "settling"
    static_columns = False
    time_columns = True

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if td is None:
            return False, "a transient after each pose change shows only within a capture: it needs raw logs"
        return True, ""

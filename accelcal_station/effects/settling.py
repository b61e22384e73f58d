"""settling: a transient a_k exp(-(t - t0_k) / tau) at the start of each capture.

No static columns: the time view fits it (gap_effects, shared tau, per-capture amplitude as a
random effect) and removes its mean from the pose means."""
from __future__ import annotations

from .base import DeterministicEffect


class Settling(DeterministicEffect):
    name = "settling"
    static_columns = False
    time_columns = True

    def testable(self, data, td) -> tuple[bool, str]:
        if td is None:
            return False, "a transient after each pose change shows only within a capture: it needs raw logs"
        return True, ""

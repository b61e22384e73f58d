"""drift: a warm-up exponential plus a linear trend of the offset over the session.

Static view: the pose means move by the capture's mean of each shape (drift_h); the time view's
block-mean columns are built in time_view (shared tau grid, held out by capture)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .base import DeterministicEffect
from .columns import AX, StaticView

if TYPE_CHECKING:
    from ..gap_data import GapData, TimeData


class Drift(DeterministicEffect):
    name = "drift"
    static_columns = True
    time_columns = True

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if td is None:
            return False, "drift over time needs raw time series (raw logs): pose tables carry no capture times"
        return True, ""

    def columns(self, view: StaticView) -> None:
        if view.drift_h is None:
            return
        for c in range(3):
            view.add("drift", f"warmup_{AX[c]}", {c: -view.drift_h[..., 0]})
            view.add("drift", f"trend_{AX[c]}", {c: -view.drift_h[..., 1]})

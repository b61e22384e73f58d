"""gain: a sensitivity per axis, the diagonal of W (AN4399 Eqn 46); with cross_axis, W's diagonal."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView


class Gain(DeterministicEffect):
    name = "gain"
    static_columns = True
    time_columns = False
    degenerate = "the baseline's cross_axis matrix already fits each axis's sensitivity"

    def columns(self, view: StaticView) -> None:
        if "cross_axis" in view.E:
            return  # the full W of cross_axis carries the diagonal
        for c in range(3):
            view.add("gain", f"W_{AX[c]}{AX[c]}", {c: view.g[..., c]})

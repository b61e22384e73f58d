"""offset: a constant per axis, reading = ... + V (AN4399 Eqn 46's offset vector)."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView


class Offset(DeterministicEffect):
    name = "offset"
    static_columns = True
    time_columns = False

    def columns(self, view: StaticView) -> None:
        for c in range(3):
            view.add("offset", f"V_{AX[c]}", {c: 1.0})

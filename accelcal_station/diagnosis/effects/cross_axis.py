"""cross_axis: the full matrix W (AN4399 Eqn 46); symmetric (6 terms) on norm-only data, where a
rotation of W is invisible."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView

_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


class CrossAxis(DeterministicEffect):
    name = "cross_axis"
    static_columns = True
    time_columns = False

    def columns(self, view: StaticView) -> None:
        g = view.g
        if view.norm:
            for i, j in _SYM:
                view.add("cross_axis" if i != j else "gain", f"W_{AX[i]}{AX[j]}",
                         {i: g[..., j]} if i == j else {i: g[..., j], j: g[..., i]})
            return
        for i in range(3):
            for j in range(3):
                view.add("cross_axis" if i != j else "gain", f"W_{AX[i]}{AX[j]}", {i: g[..., j]})

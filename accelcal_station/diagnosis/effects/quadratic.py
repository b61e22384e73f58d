"""quadratic: Q_c (g_c - g0_c)^2 per axis, centred at the zero-g reading."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView


class Quadratic(DeterministicEffect):
    name = "quadratic"
    static_columns = True
    time_columns = False
    degenerate = ("these poses do not separate g^2 from the offset and gain; it needs several input levels "
                  "per channel")

    def columns(self, view: StaticView) -> None:
        for c in range(3):
            view.add("quadratic", f"Q_{AX[c]}", {c: (view.g[..., c] - view.z0[c]) ** 2})

"""cubic: Gamma_c (g_c - g0_c)^3 per axis, centred at the zero-g reading (reading = S a + c (S a)^3 + b)."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView


class Cubic(DeterministicEffect):
    name = "cubic"
    static_columns = True
    time_columns = False
    degenerate = ("each channel reads only near 0 and +-1 g in these poses, where g^3 equals g, so the "
                  "cubic term cannot be told from the gain; it needs intermediate tilts (e.g. an4399-8, "
                  "optimal-N)")

    def columns(self, view: StaticView) -> None:
        for c in range(3):
            view.add("cubic", f"Gamma_{AX[c]}", {c: (view.g[..., c] - view.z0[c]) ** 3})

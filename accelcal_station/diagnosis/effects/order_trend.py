"""order_trend: an offset per channel that changes smoothly over the session, u_c += sum_k t_ck B_k(order).

Not a catalog effect of the simulator: the competitor every static candidate must beat in the held-out
test (diagnosis/order.py's module doc), because a change over the session (relaxation after mounting,
warm-up) moves the readings as a smooth function of acquisition order, and a candidate whose columns
follow that order could be it."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import AX, StaticView

NAME = "order_trend"


class OrderTrend(DeterministicEffect):
    name = NAME
    static_columns = True
    time_columns = False
    degenerate = "these poses do not separate a change over the session from the baseline"

    def columns(self, view: StaticView) -> None:
        if view.order is None:
            return
        B, names = view.order
        for c in range(3):
            for k, name in enumerate(names):
                view.add(NAME, f"{name}_{AX[c]}", {c: B[:, k]})

"""order_trend: an offset per channel that changes smoothly over the session, u_c += sum_k t_ck B_k(order).

Not a catalog effect of the simulator: the competitor every static candidate must beat in the held-out
test (diagnosis/order.py's module doc), because a change over the session (relaxation after mounting,
warm-up) moves the readings as a smooth function of acquisition order, and a candidate whose columns
follow that order could be it."""
from __future__ import annotations

import numpy as np

from .base import DeterministicEffect
from .columns import AX, StaticView

NAME = "order_trend"


class OrderTrend(DeterministicEffect):
    name = NAME
    static_columns = True
    time_columns = False
    degenerate = "these poses do not separate a change over the session from the baseline"

    def columns(self, view: StaticView) -> None:
        B, names = view.order if view.order is not None else _one_file(view.g.shape[-2])
        for c in range(3):
            for k, name in enumerate(names):
                view.add(NAME, f"{name}_{AX[c]}", {c: B[:, k]})


def _one_file(P: int) -> tuple[np.ndarray, list[str]]:
    """Without the data's basis (order.trend_basis): the rows as one file in acquisition order, P1..P3 of
    the position (the caller's design has its offset)."""
    s = np.linspace(-1.0, 1.0, P) if P > 1 else np.zeros(P)
    d = min(3, P // 4)
    return np.polynomial.legendre.legvander(s, d)[:, 1:], [f"P{j}" for j in range(1, d + 1)]

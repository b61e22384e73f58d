"""The static view's design columns: what each deterministic effect's ``static_columns`` builds on.

``StaticView`` holds the readings and their context; ``add`` appends one column (per channel values)
with its label and norm-shift flag.  design.static_design walks DETERMINISTIC in order.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AX = "xyz"


@dataclass
class StaticView:
    """g: (..., P, 3) readings; ref: (P, 3) or None; dT: (P,) or None; drift_h: (..., P, 2) or None;
    z0: (3,) the zero-g reading the nonlinear columns are centred at; E: the effects of the model;
    order: the order trend's basis (order.trend_basis), when the model has it."""

    g: np.ndarray
    ref: np.ndarray | None
    dT: np.ndarray | None
    drift_h: np.ndarray | None
    norm: bool
    n_temps: int
    z0: np.ndarray
    E: frozenset[str]
    order: tuple[np.ndarray, list[str]] | None = None  # the order trend's basis (P, k) and names (order.trend_basis)
    drop: frozenset[str] = frozenset()  # "effect:detail" columns left out
    cols: list[np.ndarray] = field(default_factory=list)
    labels: list[tuple[str, str]] = field(default_factory=list)
    shifts: list[float] = field(default_factory=list)

    def add(self, effect: str, detail: str, per_channel: dict[int, np.ndarray | float], shift: float = 0.0) -> None:
        if f"{effect}:{detail}" in self.drop:
            return
        col = np.zeros(self.g.shape)
        for c, val in per_channel.items():
            col[..., c] = val
        self.cols.append(col)
        self.labels.append((effect, detail))
        self.shifts.append(shift)

"""temperature: gain and offset linear in dT (per 25 C), and quadratic from three temperatures on."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .base import DeterministicEffect
from .columns import AX, StaticView

if TYPE_CHECKING:
    from ..gap_data import GapData, TimeData

T_SCALE_C = 25.0  # dT in units of 25 C keeps the design well scaled


class Temperature(DeterministicEffect):
    name = "temperature"
    static_columns = True
    time_columns = False
    degenerate = "the poses' temperatures do not separate a temperature term from the rest of the model"

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if data.n_temps >= 2:
            return True, ""
        where = "the data have no temp_c" if data.temp_c is None else \
            f"all poses at one temperature ({np.mean(data.temp_c):.1f} C)"
        return False, where + ": it needs poses at two or more temperatures"

    def columns(self, view: StaticView) -> None:
        if view.dT is None:
            return
        x, g = view.dT / T_SCALE_C, view.g
        for c in range(3):
            view.add("temperature", f"gain_{AX[c]}_per_25C", {c: x * g[..., c]})
            view.add("temperature", f"offset_{AX[c]}_per_25C", {c: x})
            if view.n_temps >= 3:
                view.add("temperature", f"gain_{AX[c]}_per_25C2", {c: x**2 * g[..., c]})
                view.add("temperature", f"offset_{AX[c]}_per_25C2", {c: x**2})

"""saturation: readings clip at the full-scale range.

Clipped poses are not modelled as a fitted term, so no columns: it is never testable, and
``reason`` says why for the data at hand (clip_g: the configured range x full_scale_fraction).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .base import DeterministicEffect

if TYPE_CHECKING:
    from ..gap_data import GapData, TimeData


class Saturation(DeterministicEffect):
    name = "saturation"
    static_columns = False
    time_columns = False

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        return False, "clipped poses are not modelled as a fitted term"

    @staticmethod
    def reason(data: GapData, clip_g: float) -> str:
        """Why clipping cannot be revealed here: the readings stay below clip_g, or reach it."""
        top = float(np.max(np.abs(data.g)))
        if top < 0.95 * clip_g:
            return (f"static gravity poses read at most {top:.2f} g on any axis, below the {clip_g:.2f} g where "
                    "the output clips (range x full_scale_fraction): clipping cannot show; it needs inputs near "
                    "full scale (centrifuge, shaker)")
        return (f"readings reach {top:.2f} g, at the {clip_g:.2f} g clip level: clipped poses are not modelled "
                "as a fitted term; remove them or measure on a larger range")

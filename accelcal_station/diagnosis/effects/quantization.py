"""quantization: the raw samples' value grid against the simulator's LSB."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .base import Signature, StochasticEffect

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import GapData, TimeData
    from ..noise_floor import Floor


class Quantization(StochasticEffect):
    name = "quantization"
    static_columns = False
    time_columns = False

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if td is None:
            return False, "the LSB shows only in raw samples' value grid (a pose mean hides it): it needs raw logs"
        return True, ""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature:
        """The gcd of the captures' integer value grids, in g, against the configured LSB (an exact test)."""
        import numpy as np

        assert td is not None, "testable: raw samples"
        lsb = td.lsb_g(np.ones(data.P, bool))
        sim = floor.sim_q_g if floor.sim_q_g is not None else floor.q_g
        passed = bool(lsb > 0 and sim > 0 and abs(lsb / sim - 1) > 0.01) or bool(lsb > 0 and sim == 0)
        reason = (f"the samples sit on a {1e3 * lsb:.4g} mg grid, the simulator's LSB is {1e3 * sim:.4g} mg"
                  if lsb > 0 else "the samples sit on no common value grid")
        return Signature(self.name, passed, 0.0 if passed else 1.0, "value grid of the raw samples (exact)", reason,
                         {"lsb_mg": 1e3 * lsb, "simulator_lsb_mg": 1e3 * sim})

"""noise: within-pose spread against the simulator's, per axis."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..noise_floor import Floor, random_var
from .base import Signature, StochasticEffect

if TYPE_CHECKING:
    from ..evaluation import Evaluation
    from ..gap_data import GapData, TimeData

MIN_RATIO_CHANGE = 0.1  # a sigma within 10 % of the simulator's is not a finding, however many samples


class Noise(StochasticEffect):
    name = "noise"
    static_columns = False
    time_columns = False

    def testable(self, data: GapData, td: TimeData | None) -> tuple[bool, str]:
        if td is None and data.std_g is None:
            return False, "the data carry no per-pose std and n and no raw samples, so the noise cannot be measured"
        return True, ""

    def signature(self, data: GapData, floor: Floor, ev: Evaluation, td: TimeData | None,
                  alpha: float) -> Signature:
        """Pooled within-pose variance w2 per axis against the simulator's sigma^2 + q^2/12 - B.

        dof*w2/s2 ~ chi2(dof): dof = sum(n - 1) for sample variances, 2/3 of it for half the mean
        squared first difference (raw samples; its variance is 3 s^4/(n-1), not 2 s^4/(n-1)).
        """
        from scipy import stats

        n1 = np.maximum(data.n - 1.0, 1.0)
        if td is not None:
            ok = np.isfinite(td.diff_var)
            w2 = np.array([np.sum(n1[ok[:, a]] * td.diff_var[ok[:, a], a]) / np.sum(n1[ok[:, a]]) for a in range(3)])
            dof = 2.0 / 3.0 * np.array([np.sum(n1[ok[:, a]]) for a in range(3)])
            how = "raw samples' first differences"
        else:
            assert data.std_g is not None, "testable: per-pose std and n without raw samples"
            w2 = np.sum(n1[:, None] * data.std_g**2, axis=0) / np.sum(n1)
            dof = np.full(3, np.sum(n1))
            how = "poses' std and n"
        sim = random_var(floor.simulator_sigma_g, floor.q_g)
        x = dof * w2 / sim
        p_axis = 2 * np.minimum(stats.chi2.sf(x, dof), stats.chi2.cdf(x, dof))
        ratio = np.sqrt(w2 / sim)
        p = float(min(1.0, 3 * p_axis.min()))  # Bonferroni over the axes
        big = np.abs(ratio - 1) > MIN_RATIO_CHANGE
        passed = bool(p < alpha and np.any(big & (3 * p_axis < alpha)))
        reason = (f"within-pose sigma is {', '.join(f'{r:.2f}' for r in ratio)} x the simulator's on x, y, z ({how})"
                  + ("" if passed else "; within chance or within 10 % of it"))
        return Signature(self.name, passed, p, "two-sided chi-square test of the pooled within-pose variance per "
                         "axis, Bonferroni over 3 axes, and |sigma ratio - 1| > 0.1", reason,
                         {"sigma_mg": (1e3 * np.sqrt(w2)).tolist(), "simulator_sigma_mg": (1e3 * np.sqrt(sim)).tolist(),
                          "ratio": ratio.tolist(), "p_axis": p_axis.tolist()})

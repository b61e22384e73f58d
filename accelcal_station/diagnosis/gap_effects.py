"""The effects catalog as fitted measurement-model terms, and their held-out evaluation.

This is the held-out evaluation behind `accelcal diagnose` (engine.py); the static design is
effects/design.py, its fits least_squares.py, the views static_view.py and time_view.py, the
held-out split and the noise model per fold folds.py, the floor noise_floor.py.  A model is
the simulator configuration's enabled effects plus the candidates added to them; every
effect is a parametric term in one of two views of the data, and the noise floor is
the variance the simulator predicts for every residual.

Static view (pose means).  The calibrated output of pose i is linear in the
parameters, ``u_i = A_i theta + b_i`` (AN4399 Eqns 46 and 67 extended):

  with references     r_i = gamma ref_i - u_i         3 rows, weighted least squares
  without (norm only) r_i = |u_i| - gamma - d_i theta 1 row, Levenberg-Marquardt (nine-position paper)

where ``gamma`` is the configured local gravity in standard g.  Terms, per channel c
(g the reading in nominal g, dT = T - T_mid, t the capture time):

  gain         W diagonal: u_c += w_c g_c
  cross_axis   W full (norm only: symmetric -- a rotation keeps the norm, so its
               antisymmetric part is invisible)
  offset       u_c += v_c
  cubic        u_c += Gamma_c g_c^3                       (AN4399 Eqn 67: inverts the sim exactly)
  quadratic    u_c += q_c g_c^2                           (inverts the sim's square term exactly)
  temperature  u_c += (a_c g_c + b_c) dT  (+ (a2_c g_c + b2_c) dT^2 at three or more temperatures)
  drift        u_c -= a_c (1 - exp(-t / tau)) + b_c t / T (warm-up and trend; tau on a grid; raw only)
  gravity      gamma -> gamma (1 + delta)                 (degenerate whenever a gain is fitted)

Time view (raw captures only).  Each capture is cut into blocks; a block's mean minus
its capture's mean is ``e_kb = F_kb theta`` plus noise (3 rows per block):

  drift        the same d(t) as above, within the capture
  settling     x(t) += a_k exp(-(t - t0_k) / tau): tau shared, the amplitude a_k a random
               effect per capture and axis (a ~ N(0, psi^2)), because automatic segmentation
               trims each capture's transient by a different amount; the transient's mean
               is removed from the static view too (see evaluate)

Spread view (std and n, or raw samples).  Each pose's within-pose variance against the
per-sample variance the model predicts; scored, not part of the headline gap.

Floor.  The variance of a pose mean of n samples with white noise sigma and
quantization step q is ``B + (sigma^2 + q^2/12 - B) / n`` per axis, where
``B = sum_k q^2 / (2 pi^2 k^2) exp(-4 pi^2 k^2 sigma^2 / q^2)`` is the part of the
quantization error that averaging cannot remove (the Fourier series of the
rounding error smoothed by the noise; B = q^2/12 without noise, 0 when the noise
dithers).  Pose scatter s (rad, per rotation axis) adds ``s^2 (1 - ref_c^2)``.
Stochastic candidates refit these from the data instead of taking them from the
configuration: ``noise`` (sigma from the poses' std or raw first differences),
``quantization`` (q from the raw samples' value grid), ``pose_error`` (s by maximum
likelihood on training residuals).

Held-out evaluation.  Poses (captures) are split into K folds; each fold's
residuals come from a fit on the others, and their variance is the floor plus the
fit's own prediction variance ``a^T (A^T V^-1 A)^-1 a``, so a model that explains
the data scores a held-out gap of 1 (with raw captures: the RMS of the static and time
views' gaps).  The score of a model is its Gaussian log predictive density per
(pose, axis) -- a proper score: it rewards neither inflated nor shrunken variance.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evaluation import Evaluation, FitParams
from .evaluation import nll as _nll
from .folds import Folds, NoiseModel, heldout, make_folds, noise_model
from .gap_data import GapData, TimeData
from .noise_floor import Floor, random_var, within_spread
from .static_view import StaticFit, static_view
from .time_view import TimeFit, time_view


@dataclass
class SpreadFit:
    """Each pose's within-pose variance against the predicted one: residual and variance (P, 3), g^2."""

    r: np.ndarray
    v: np.ndarray
    nll: np.ndarray  # (P, 3)


def _spread_view(data: GapData, td: TimeData | None, nm: NoiseModel, fo: Folds) -> SpreadFit | None:
    """Within-pose variance against the per-sample variance predicted (sample variance: var 2 s^4/(n-1);
    half the mean squared first difference: 3 s^4/(n-1)); scored, not part of the gap."""
    w2_obs, c_var = (td.diff_var, 3.0) if td is not None else \
        (data.std_g**2 if data.std_g is not None else None, 2.0)
    if w2_obs is None:
        return None
    F, P = fo.F, data.P
    sigma, q = nm.sigma[:, None, :], nm.q[:, None, None]
    pred = np.broadcast_to(random_var(sigma, q), (F, P, 3))
    vs = c_var * pred**2 / np.maximum(data.n[None, :, None] - 1.0, 1.0) \
        + np.broadcast_to(within_spread(sigma, q), (F, P, 3))
    ok = np.isfinite(w2_obs)
    r = heldout(np.where(ok, w2_obs - pred, 0.0), fo.fold)
    v = heldout(vs, fo.fold)
    return SpreadFit(r, v, np.where(ok, _nll(r, v), 0.0))


def evaluate(data: GapData, floor: Floor, baseline: tuple[str, ...], added: tuple[str, ...] = (),
             td: TimeData | None = None, static_ok: bool = True) -> Evaluation:
    """Held-out evaluation of the model ``baseline + added`` (module doc).

    ``baseline``: the configuration's deterministic effects (fitted); ``added``: candidates.
    Fold K (the last) is the whole-data fit whose parameters are reported.  The score is summed
    per test unit (pose, axis): spread view, then time view, then static view.
    """
    E = set(baseline) | set(added)
    P = data.P
    fo = make_folds(data)
    params: FitParams = {}
    nm = noise_model(data, floor, added, td, fo, params)
    nll = np.zeros((P, 3))
    sp = _spread_view(data, td, nm, fo)
    if sp is not None:
        nll += sp.nll
    tv: TimeFit | None = None
    if td is not None:
        tv = time_view(td, E, nm, fo, P)
        params.update(tv.params)
        np.add.at(nll, (td.unit, td.axis), tv.nll_rows)
        if tv.nll_gain is not None:
            nll -= tv.nll_gain
    sv: StaticFit | None = None
    if static_ok:
        zero = np.zeros((fo.F, P, 3))
        sv = static_view(data, floor, E, added, td, nm, fo, zero if tv is None else tv.corr,
                         zero if tv is None else tv.extra)
        params.update(sv.params)
        nll += sv.nll
    n_var = {"pose_error": 1}  # noise and quantization are measured within poses, not fitted to residuals
    n_params = (sv.n_params if sv else 0) + (tv.n_params if tv else 0) + sum(n_var.get(a, 0) for a in added)
    return Evaluation(tuple(added), n_params, _part(sv, "r"), _part(sv, "v"), _part(sv, "floor"), _part(tv, "r"),
                      _part(tv, "v"), nll, params, _part(sv, "fitted"), _part(sp, "r"), _part(sp, "v"),
                      _part(tv, "floor"), _part(sv, "pv"))


def _part(view: StaticFit | TimeFit | SpreadFit | None, name: str) -> np.ndarray | None:
    """A view's array, or None when the view was not evaluated."""
    return None if view is None else getattr(view, name)

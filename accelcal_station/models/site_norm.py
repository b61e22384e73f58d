"""Model 9's gravity norm at the site: ``|M (v - B)| = g_local / g_standard`` in standard g.

The norm fit of gravity_norm.py makes every calibrated static reading 1 g long.  At a site of
local gravity g_local the board feels k = g_local / g_standard standard g (config/site.py), so the
calibration that maps counts to standard g makes the readings k long.  The objective
``sum (|M (v - B)| - k)^2 = k^2 sum (|(M / k) (v - B)| - 1)^2`` has the unit-norm minimiser
scaled by k: ``M_site = k M_1``, ``B_site = B_1``, hence ``W = k W_1``, ``V = k V_1``, and every
residual, norm error and standard error of the calibrated output scales by k (the covariance of
(M, B) by diag(k..k, 1, 1, 1) on both sides).  Exact, not a first-order correction.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .result import BatchFit
from .stacked_norm import ScaledCovariance

# the six M parameters scale with k, the three B (the bias, in input g) do not (gravity_norm.PARAM_NAMES)
_M_PARAMS = 6


def _scale_vector(k: float) -> np.ndarray:
    s = np.ones(9)
    s[:_M_PARAMS] = k
    return s


def at_site_norm(res: BatchFit, k: float) -> BatchFit:
    """A model-9 BatchFit fitted at the unit norm, restated at the norm ``k`` (module doc)."""
    if res.model != "9" or k == 1.0:
        return res
    s = _scale_vector(k)
    outer = s[:, None] * s[None, :]
    cov = res.covariance
    if isinstance(cov, ScaledCovariance):
        cov = ScaledCovariance(cov.Ainv * outer, cov.s2)
    elif isinstance(cov, np.ndarray):
        cov = cov * outer
    cvo = res.crossval_by_orientation_rms_g
    return replace(res, W=res.W * k, V=res.V * k, residuals_g=res.residuals_g * k, norm_error_g=res.norm_error_g * k,
                   P=res.P * k * k, residual_rms_g=res.residual_rms_g * k, crossval_rms_g=res.crossval_rms_g * k,
                   stderr_W=res.stderr_W * k, stderr_V=res.stderr_V * k, covariance=cov,
                   params=res.params * s if res.params.shape[-1] == 9 else res.params,
                   crossval_by_orientation_rms_g=None if cvo is None else cvo * k)


__all__ = ["at_site_norm"]

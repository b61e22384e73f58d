"""Gage R&R statistics (AIAG "Measurement Systems Analysis", 4th edition, 2010, chapter III section B).

A balanced crossed study: ``x[i, j, m]`` is part i measured by appraiser j in trial m.

* ANOVA method with the part x appraiser interaction (MSA 4th ed. III-B "Analysis of Variance (ANOVA)
  Method", tables III-B 6/7 and Appendix A): two-way crossed random-effects ANOVA; the interaction is
  pooled into repeatability when its F test's p-value exceeds 0.25 (Appendix A).
* Average-and-range method (III-B, figure III-B 15 "Gage Repeatability and Reproducibility Report"):
  EV = R-double-bar K1, AV = sqrt((X_diff K2)^2 - EV^2 / (n r)), PV = R_p K3, with K1, K2, K3 the
  manual's tabulated constants (1/d2*).

Every figure is a standard deviation (the 4th edition's convention, not 5.15 sigma); %GRR = 100 GRR/TV,
%tolerance = 100 * 6 GRR / tolerance, ndc = floor(1.41 PV/GRR); bands: %GRR < 10 acceptable,
10-30 conditional, > 30 not acceptable; ndc >= 5.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from ..errors import DataError

POOL_P = 0.25  # AIAG MSA 4th ed. Appendix A: pool the interaction into the error term when p > 0.25
NDC_FACTOR = 1.41  # sqrt(2): ndc = 1.41 PV/GRR (MSA 4th ed. III-B)
SPREAD = 6.0  # %tolerance compares 6 GRR (the 4th edition's 99.73 % spread) with the tolerance
# AIAG MSA 4th ed. figure III-B 15 (Gage R&R report form): K1 by trials, K2 by appraisers, K3 by parts
K1 = {2: 0.8862, 3: 0.5908}
K2 = {2: 0.7071, 3: 0.5231}
K3 = {2: 0.7071, 3: 0.5231, 4: 0.4467, 5: 0.4030, 6: 0.3742, 7: 0.3534, 8: 0.3375, 9: 0.3249, 10: 0.3146}
D4 = {2: 3.267, 3: 2.574, 4: 2.282, 5: 2.114}  # range chart upper limit factor by subgroup size (ASTM/AIAG)


@dataclass(frozen=True)
class Anova:
    """The ANOVA table of a crossed study and its variance components (standard deviations)."""

    ss_part: float
    ss_appraiser: float
    ss_interaction: float
    ss_error: float
    df_part: int
    df_appraiser: int
    df_interaction: int
    df_error: int
    p_interaction: float | None  # None: MS_error is 0 (no repeatability noise to test against)
    pooled: bool
    ev: float
    av: float
    interaction: float
    pv: float


@dataclass(frozen=True)
class Figures:
    """GRR, TV, the percentages and ndc from EV, AV, interaction and PV."""

    ev: float
    av: float
    interaction: float
    grr: float
    pv: float
    tv: float
    pct_ev: float | None
    pct_av: float | None
    pct_grr: float | None
    pct_pv: float | None
    pct_tolerance: float | None
    ndc: int | None
    grr_band: str | None
    ndc_ok: bool | None

    def to_dict(self) -> dict[str, float | int | str | bool | None]:
        return asdict(self)


def band(pct: float | None) -> str | None:
    """AIAG MSA 4th ed. III-B: < 10 % acceptable, 10-30 % may be acceptable, > 30 % not acceptable."""
    if pct is None:
        return None
    return "acceptable" if pct < 10.0 else "conditional" if pct <= 30.0 else "not acceptable"


def _pct(a: float, b: float) -> float | None:
    return 100.0 * a / b if b > 0 else None


def figures(ev: float, av: float, interaction: float, pv: float, tolerance: float | None) -> Figures:
    """GRR = sqrt(EV^2 + AV^2 + INT^2), TV = sqrt(GRR^2 + PV^2) and the ratios (MSA 4th ed. III-B)."""
    grr = math.sqrt(ev * ev + av * av + interaction * interaction)
    tv = math.sqrt(grr * grr + pv * pv)
    pct_grr = _pct(grr, tv)
    ndc = None if grr <= 0 else int(math.floor(NDC_FACTOR * pv / grr))
    pct_tol = None if tolerance is None else _pct(SPREAD * grr, tolerance)
    return Figures(ev, av, interaction, grr, pv, tv, _pct(ev, tv), _pct(av, tv), pct_grr, _pct(pv, tv),
                   pct_tol, ndc, band(pct_grr), None if ndc is None else ndc >= 5)


def _check(x: np.ndarray) -> tuple[int, int, int]:
    if x.ndim != 3 or min(x.shape) < 1 or not np.all(np.isfinite(x)):
        raise DataError(f"a study is parts x appraisers x trials of finite numbers; got shape {x.shape}")
    p, o, r = x.shape
    if p < 2 or o < 2 or r < 2:
        raise DataError(f"a study needs >= 2 parts, >= 2 appraisers and >= 2 trials; got {p}, {o}, {r}")
    return p, o, r


def _sqrt0(v: float) -> float:
    """A variance component estimated below zero is taken as 0 (MSA 4th ed. III-B, ANOVA method)."""
    return math.sqrt(v) if v > 0 else 0.0


def anova(x: np.ndarray) -> Anova:
    """Two-way crossed random-effects ANOVA with interaction (MSA 4th ed. Appendix A, table A-1):
    sums of squares, the interaction's F test, and the variance components from expected mean squares
    (sigma_e^2 = MS_E, sigma_int^2 = (MS_AP - MS_E)/r, sigma_o^2 = (MS_A - MS_AP)/(n r),
    sigma_p^2 = (MS_P - MS_AP)/(k r); with the interaction pooled, MS_AP is replaced by the pooled MS_E)."""
    p, o, r = _check(x)
    grand = x.mean()
    part = x.mean(axis=(1, 2))
    appr = x.mean(axis=(0, 2))
    cell = x.mean(axis=2)
    ss_p = o * r * float(np.sum((part - grand) ** 2))
    ss_o = p * r * float(np.sum((appr - grand) ** 2))
    ss_po = r * float(np.sum((cell - part[:, None] - appr[None, :] + grand) ** 2))
    ss_e = float(np.sum((x - cell[:, :, None]) ** 2))
    df_p, df_o, df_po, df_e = p - 1, o - 1, (p - 1) * (o - 1), p * o * (r - 1)
    ms_p, ms_o, ms_po, ms_e = ss_p / df_p, ss_o / df_o, ss_po / df_po, ss_e / df_e
    p_int = None if ms_e <= 0 else float(stats.f.sf(ms_po / ms_e, df_po, df_e))
    pooled = p_int is not None and p_int > POOL_P
    if pooled:
        ms_e = (ss_po + ss_e) / (df_po + df_e)
        ms_po, var_int = ms_e, 0.0
    else:
        var_int = (ms_po - ms_e) / r
    return Anova(ss_p, ss_o, ss_po, ss_e, df_p, df_o, df_po, df_e, p_int, pooled,
                 ev=_sqrt0(ms_e), av=_sqrt0((ms_o - ms_po) / (p * r)), interaction=_sqrt0(var_int),
                 pv=_sqrt0((ms_p - ms_po) / (o * r)))


@dataclass(frozen=True)
class AverageRange:
    """The average-and-range estimates (standard deviations), or why they are not available."""

    ev: float | None
    av: float | None
    pv: float | None
    r_bar: float | None
    x_diff: float | None
    r_part: float | None
    unavailable: str | None = None


def average_range(x: np.ndarray) -> AverageRange:
    """MSA 4th ed. III-B figure III-B 15: EV = R-double-bar K1; AV = sqrt((X_diff K2)^2 - EV^2/(n r))
    (0 when negative); PV = R_p K3.  The K constants are tabulated for 2-3 trials, 2-3 appraisers and
    2-10 parts only; outside them the cross-check is not available (said, not extrapolated)."""
    p, o, r = _check(x)
    if r not in K1 or o not in K2 or p not in K3:
        return AverageRange(None, None, None, None, None, None,
                            f"AIAG K1/K2/K3 are tabulated for 2-3 trials, 2-3 appraisers, 2-10 parts; "
                            f"this study has {r}, {o}, {p}")
    r_bar = float(np.mean(x.max(axis=2) - x.min(axis=2)))
    appr = x.mean(axis=(0, 2))
    x_diff = float(appr.max() - appr.min())
    part = x.mean(axis=(1, 2))
    r_part = float(part.max() - part.min())
    ev = r_bar * K1[r]
    av = _sqrt0((x_diff * K2[o]) ** 2 - ev * ev / (p * r))
    return AverageRange(ev, av, r_part * K3[p], r_bar, x_diff, r_part)


def range_limits(x: np.ndarray) -> tuple[float, float | None]:
    """Range chart centre line R-bar and upper limit D4 R-bar (lower limit 0 for <= 6 trials; no
    upper limit drawn beyond the tabulated 2-5 trials)."""
    r_bar = float(np.mean(x.max(axis=2) - x.min(axis=2)))
    d4 = D4.get(x.shape[2])
    return r_bar, None if d4 is None else d4 * r_bar

"""The site the data claim (--gravity, a file's ``# gravity_mps2:`` line): the diagnosis's gravity.

The loader scales every reference to the stated site (config/site.py), so a pose's expected output
is ``k ref`` with k = g_site / g_standard.  The diagnosis writes the same model as ``gamma ref`` with
unit references and gamma the gravity it judges against (gap_effects' module doc): with a stated site
gamma is that site's k (and the references are brought back to unit length, so the site is counted
once), without one the simulator configuration's ``gravity`` effect.  The ``gravity`` candidate,
gamma -> gamma (1 + delta), is then the gap between the gravity the data were taken at and the site
they state; it is testable only where no fitted term absorbs a common scale (a gain or cross_axis in
the baseline: effects/gravity.py), e.g. calibrated output or a board whose sensitivity is known.
"""
from __future__ import annotations

from ..conventions import STANDARD_GRAVITY_MPS2
from ..errors import DataError
from ..session import Session


def stated_site_g(sessions: list[Session], sources: list[str]) -> float | None:
    """The site's gravity in standard g the files state (one for all), or None when none states one."""
    stated: dict[float, str] = {}
    for s, src in zip(sessions, sources, strict=False):
        site = s.metadata.get("site")
        if isinstance(site, dict) and site.get("source") not in (None, "standard"):
            stated.setdefault(round(float(site["gravity_mps2"]), 9), src)
    if len(stated) > 1:
        raise DataError("the files state different sites (" + ", ".join(f"{src}: {g:g} m/s^2" for g, src in
                        stated.items()) + "); diagnose files of one site together, or give --gravity")
    if not stated:
        return None
    return next(iter(stated)) / STANDARD_GRAVITY_MPS2


__all__ = ["stated_site_g"]

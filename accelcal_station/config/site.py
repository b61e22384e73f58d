"""Where the station stands: the site's gravity (``station.site``), the magnitude of the force the
jig's poses put on a board.

A site is either measured (``gravity_mps2``: a gravimeter's or a gravity survey's value, which beats
any formula) or computed from ``latitude_deg`` and ``height_m`` as WGS84 normal gravity (Somigliana's
closed formula, NIMA TR8350.2 eq. 4-1) with the free-air gradient -3.086e-6 m/s^2 per metre.  Without
a site the station assumes standard gravity (9.80665 m/s^2, CGPM 1901) and says so.

The jig's pose references are scaled by ``gravity_g`` (local / standard), so a calibration maps
counts to standard g whatever the site.  ``gravity_u_mps2`` is the site gravity's standard
uncertainty as the uncertainty budget takes it (docs/uncertainty.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, TypedDict

from ..conventions import STANDARD_GRAVITY_MPS2
from ..errors import ConfigError
from ..jsontypes import JsonObject

# WGS84 normal gravity (NIMA TR8350.2, 3rd ed., eq. 4-1 and table 3.4)
GAMMA_E_MPS2 = 9.7803253359  # normal gravity at the equator
SOMIGLIANA_K = 0.00193185265241
WGS84_E2 = 0.00669437999013  # first eccentricity squared
FREE_AIR_MPS2_PER_M = -3.086e-6  # free-air gradient of normal gravity near the surface

# standard uncertainties by source (docs/uncertainty.md): a measured value without a stated one is
# taken as a survey map's (0.1 mGal = 1e-6 m/s^2 is a gravimeter's; maps and interpolation ~1 mGal);
# normal gravity leaves out the local anomaly, tens of mGal on land (free-air anomalies have an RMS of
# about 30-40 mGal worldwide), taken as 50 mGal = 5e-4 m/s^2
MEASURED_U_MPS2 = 1e-5
FORMULA_U_MPS2 = 5e-4
# no site: anywhere from the equator to the poles at sea level, 9.780-9.832 m/s^2 around 9.80665 (a
# half-width of 0.027 m/s^2), rectangular: u = 0.027 / sqrt(3) (GUM 4.3.7)
STANDARD_U_MPS2 = 0.027 / math.sqrt(3.0)

SiteSource = Literal["measured", "normal_gravity", "standard"]


def normal_gravity_mps2(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity at geodetic latitude ``latitude_deg`` and ``height_m`` above the
    ellipsoid: Somigliana's formula, then the free-air gradient (-3.086e-6 m/s^2 per m)."""
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    g0 = GAMMA_E_MPS2 * (1.0 + SOMIGLIANA_K * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
    return g0 + FREE_AIR_MPS2_PER_M * height_m


class SiteJson(TypedDict):
    """``site`` in run --json, fit --json, the store and the calibration file."""

    gravity_mps2: float
    source: str  # measured, normal_gravity or standard
    gravity_u_mps2: float  # its standard uncertainty


@dataclass(frozen=True)
class Site:
    """The site's gravity, where it came from, and its standard uncertainty, m/s^2."""

    gravity_mps2: float = STANDARD_GRAVITY_MPS2
    source: SiteSource = "standard"
    gravity_u_mps2: float = STANDARD_U_MPS2

    @property
    def gravity_g(self) -> float:
        """Local gravity in standard g (the factor the jig's references are scaled by)."""
        return self.gravity_mps2 / STANDARD_GRAVITY_MPS2

    @property
    def relative_u(self) -> float:
        """The site gravity's relative standard uncertainty (a gain's relative uncertainty from it)."""
        return self.gravity_u_mps2 / self.gravity_mps2

    def to_metadata(self) -> JsonObject:
        """``site`` as a calibration file's metadata keeps it."""
        return {"gravity_mps2": self.gravity_mps2, "source": self.source, "gravity_u_mps2": self.gravity_u_mps2}

    def to_json(self) -> SiteJson:
        """``site`` in run --json, the store and the calibration file."""
        return {"gravity_mps2": self.gravity_mps2, "source": self.source, "gravity_u_mps2": self.gravity_u_mps2}


STANDARD_SITE = Site()


def site_from_value(gravity_mps2: float | None) -> Site:
    """The site a command's ``--gravity`` or a file's ``# gravity_mps2:`` line gives (a measured value)."""
    if gravity_mps2 is None:
        return STANDARD_SITE
    if not math.isfinite(gravity_mps2) or not 9.7 <= gravity_mps2 <= 9.9:
        raise ConfigError(f"gravity {gravity_mps2} m/s^2 is implausible; allowed 9.7 to 9.9 m/s^2")
    return Site(float(gravity_mps2), "measured", MEASURED_U_MPS2)

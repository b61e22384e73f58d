"""``station.site`` as the config declares it (a pydantic section) and the Site it gives.  Apart from
config/site.py, whose Site and normal gravity `fit`, `batch` and `diagnose` use without the config
schema's models (their import is a tenth of a second of every command's start)."""
from __future__ import annotations

from ..errors import ConfigError
from .section import Section, _f
from .site import FORMULA_U_MPS2, MEASURED_U_MPS2, STANDARD_SITE, Site, normal_gravity_mps2


class SiteSection(Section):
    """``station.site``: a measured ``gravity_mps2``, or ``latitude_deg`` and ``height_m`` (WGS84 normal
    gravity); none: standard gravity."""

    gravity_mps2: float | None = _f(None, "measured local gravity, m/s^2 (a gravimeter's or a gravity survey's "
                                    "value; beats the formula)", ge=9.7, le=9.9)
    gravity_u_mps2: float | None = _f(None, "standard uncertainty of gravity_mps2, m/s^2 (default 1e-5: a survey "
                                      "map's)", gt=0, le=0.1)
    latitude_deg: float | None = _f(None, "geodetic latitude, deg (WGS84 normal gravity, Somigliana)",
                                    ge=-90, le=90)
    height_m: float | None = _f(None, "height above the WGS84 ellipsoid, m (free-air gradient -3.086e-6 "
                                "m/s^2 per m)", ge=-500, le=9000)


def site_of(section: SiteSection | None) -> Site:
    """The site a ``station.site`` section gives (ConfigError, one line, for a half-given one)."""
    if section is None:
        return STANDARD_SITE
    geo = (section.latitude_deg, section.height_m)
    if section.gravity_mps2 is not None:
        if any(v is not None for v in geo):
            raise ConfigError("station.site: give gravity_mps2 (measured) or latitude_deg and height_m "
                              "(normal gravity), not both")
        return Site(section.gravity_mps2, "measured", section.gravity_u_mps2 or MEASURED_U_MPS2)
    if section.gravity_u_mps2 is not None:
        raise ConfigError("station.site.gravity_u_mps2: only with a measured gravity_mps2")
    if section.latitude_deg is None or section.height_m is None:
        raise ConfigError("station.site: allowed: gravity_mps2 (measured), or both latitude_deg and height_m")
    return Site(normal_gravity_mps2(section.latitude_deg, section.height_m), "normal_gravity", FORMULA_U_MPS2)

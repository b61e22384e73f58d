"""Which extra of pyproject.toml installs a missing optional module (from the installed
distribution's own metadata, so a new extra needs no change here)."""
from __future__ import annotations

import re
from importlib import metadata

DIST = "accelcal-station"
DEV_EXTRAS = ("test", "lint")  # what developers install; the user-facing extra is named instead


def extra_for(module: str | None) -> str | None:
    """The user-facing extra whose requirement provides top-level ``module``, or None."""
    if not module:
        return None
    top = module.split(".")[0].lower().replace("_", "-")
    try:
        reqs = metadata.requires(DIST) or []
    except metadata.PackageNotFoundError:
        return None
    found = []
    for req in reqs:
        m = re.match(r"\s*([A-Za-z0-9_.-]+).*;\s*extra\s*==\s*['\"]([^'\"]+)['\"]", req)
        if m and m.group(1).lower().replace("_", "-") == top:
            found.append(m.group(2))
    user = [e for e in found if e not in DEV_EXTRAS]
    return (user or found or [None])[0]


def missing_text(module: str) -> str:
    """The one line for a missing optional module: what is missing and what to install."""
    extra = extra_for(module)
    what = f"pip install '{DIST}[{extra}]'" if extra else f"pip install {module.split('.')[0]}"
    return f"this needs the optional module {module.split('.')[0]!r}, which is not installed: {what}"


__all__ = ["extra_for", "missing_text"]

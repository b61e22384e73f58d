"""Each station's Gage R&R result beside its yield on the line page (AIAG MSA 4th ed.; lot/msa_study.py).

Computed on demand from the store's runs, never stored: the study is the one
``accelcal report msa --station S`` gives over the same runs (parts: the station's serials with more
than one complete calibrated run, the newest ``MAX_PARTS`` of them; appraisers: their operators;
trials: the repeats), so it is always the study of what the store holds now, and a restart or a
second server shows the same.  Bounded: one grouped query per station for its repeated serials, then
at most ``MAX_RUNS`` runs read; the result is kept per (store, station) until that station's newest
run changes, so a line page refreshed after every run recomputes only the station that ran.

Shown: the worst calibration parameter (largest %GRR of V and W; residual figures left out, their
spread is the measurement's own noise) with its %GRR, band and ndc; "no study" with why otherwise.
"""
from __future__ import annotations

import threading
from typing import TypedDict

from ..errors import DataError
from ..lot.msa_study import analyse, build_study
from ..store import linequeries as lq
from ..store.reader import StoreReader as Store

MAX_PARTS = 50
MAX_RUNS = 400
_CACHE_MAX = 256


class MsaBadge(TypedDict):
    """A station's latest Gage R&R headline, or why it has none (``pct_grr`` None)."""

    parameter: str | None
    pct_grr: float | None
    ndc: int | None
    band: str | None
    parts: int
    appraisers: int
    trials: int
    why: str


_cache: dict[tuple[str, str | None], tuple[int | None, MsaBadge]] = {}  # (store, station): (newest id, badge)
_lock = threading.Lock()


def _none(why: str) -> MsaBadge:
    return {"parameter": None, "pct_grr": None, "ndc": None, "band": None, "parts": 0, "appraisers": 0,
            "trials": 0, "why": why}


def station_msa(store: Store, station: str | None) -> MsaBadge:
    """The station's study now (see the module's docstring)."""
    rows = lq.repeated_serials(store, station, MAX_PARTS)
    serials = [s for r in rows if (s := r.text("device_serial")) is not None]
    if not serials:
        return _none("no board measured more than once")
    recs = store.runs(device=serials, station=station, status="complete")[-MAX_RUNS:] if station is not None \
        else []
    try:
        study = build_study(recs, "operator")
    except DataError as e:
        return _none(str(e)[:160])
    results = [r for r in analyse(study) if str(r["parameter"]).startswith(("V_", "W_"))]
    judged = [r for r in results if isinstance(r["pct_grr"], (int, float))]
    if not judged:
        return _none("no parameter measured in every run")
    worst = max(judged, key=lambda r: float(r["pct_grr"]))  # type: ignore[arg-type]
    ndc = worst["ndc"]
    return {"parameter": str(worst["parameter"]), "pct_grr": float(worst["pct_grr"]),  # type: ignore[arg-type]
            "ndc": ndc if isinstance(ndc, int) else None, "band": str(worst["grr_band"] or ""),
            "parts": len(study.parts), "appraisers": len(study.appraisers), "trials": study.trials, "why": ""}


def cached_msa(store: Store, key: str, station: str | None, newest_id: int | None) -> MsaBadge:
    """station_msa, reused while the station's newest run is ``newest_id``."""
    with _lock:
        hit = _cache.get((key, station))
    if hit is not None and hit[0] == newest_id:
        return hit[1]
    got = station_msa(store, station)
    with _lock:
        if len(_cache) >= _CACHE_MAX:
            _cache.clear()
        _cache[(key, station)] = (newest_id, got)
    return got

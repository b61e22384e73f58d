"""What the line, board and lot pages show, as plain values for the templates."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..config.safe_yaml import HostileYAML, safe_load
from ..errors import AccelcalError
from ..store.records import RunRecord, iso
from ..store.runs import Store
from . import queries
from .charts import Chart, control_chart, residual_chart

# the line page's control charts: fit_summary.measured key, title, unit, acceptance limit key
KEY_PARAMS = [("gain_error_max", "Gain error (max |Wii - 1|)", "", "gain_error_max"),
              ("offset_max_mg", "Offset (max |V|)", "mg", "offset_max_mg"),
              ("cross_axis_max", "Cross-axis (max |Wij|)", "", "cross_axis_max"),
              ("residual_rms_mg", "Fit residual RMS", "mg", "residual_rms_mg")]


def limits_from_text(text: str | None) -> dict[str, float]:
    """The acceptance section of a config's text (numbers only); {} when it cannot be read."""
    try:
        acc = (safe_load(text or "") or {}).get("acceptance") or {}
    except (HostileYAML, ValueError, AttributeError):  # a stored config is only advisory here
        return {}
    return {k: float(v) for k, v in acc.items() if isinstance(v, (int, float))} if isinstance(acc, dict) else {}


def line_context(store: Store, limits: dict[str, float] | None) -> dict[str, Any]:
    """Stations, yields per station and shift, reasons and control charts (aggregate queries only)."""
    t0 = queries.window_start(store)
    if t0 is None:
        return {"empty": True, "stations": [], "shifts": [], "reasons": [], "recent": [], "charts": []}
    lim = limits if limits else limits_from_text(queries.newest_config_text(store))
    series = queries.measured_series(store)
    charts: list[Chart] = []
    for key, title, unit, lkey in KEY_PARAMS:
        pts = [s for s in series if isinstance(s.get(key), (int, float))]
        charts.append(control_chart(title, unit, [float(s[key]) for s in pts],
                                    [f"run {s['id']} ({s['station_id']})" for s in pts], lim.get(lkey)))
    return {"empty": False, "window_from": iso(t0), "stations": queries.station_rows(store, t0),
            "shifts": queries.shift_rows(store, t0), "reasons": queries.reason_counts(store, t0),
            "recent": queries.recent(store), "charts": charts, "limits": lim}


def _residuals(rec: RunRecord) -> Chart | None:
    """One run's residuals per pose, refitted from its stored poses with its model."""
    if not rec.poses or rec.status != "complete":
        return None
    from ..models.fitting import fit_session

    try:
        fit = fit_session(rec.session(), rec.model or "12")
    except AccelcalError:
        return None
    return residual_chart(f"run {rec.id}: residuals per pose (model {fit.model})",
                          [p.name for p in rec.poses], np.asarray(fit.residuals_g) * 1e3)


def board_context(store: Store, serial: str) -> dict[str, Any]:
    """Every run of one board (newest first) with its residual chart and the NVM history."""
    recs = store.runs(device=serial)
    runs = []
    nvm: list[dict[str, Any]] = []
    for rec in reversed(recs):
        runs.append({"rec": rec, "started": iso(rec.started_at), "chart": _residuals(rec),
                     "reasons": [r.to_dict() for r in rec.reasons],
                     "figures": (rec.fit_summary or {}).get("measured") or {}})
        nvm.extend({"run": rec.id, "t": iso(e["t"]), "kind": e["kind"], "message": e["message"]}
                   for e in rec.events if str(e["kind"]).startswith("nvm_"))
        if rec.nvm_status and rec.nvm_status != "none":
            o = rec.nvm_outcome or {}
            nvm.append({"run": rec.id, "t": iso(rec.finished_at), "kind": f"run {rec.nvm_status}",
                        "message": f"slot {o.get('slot')}, generation {o.get('generation')}"})
    return {"serial": serial, "runs": runs, "nvm": nvm,
            "similar": [] if recs else queries.serials_like(store, serial)}


def lot_context(store: Store, lot: str) -> dict[str, Any]:
    """The lot report's content (store.lot_summary, and control charts of the calibrations)."""
    from ..calibration import param_vector
    from ..lot.report import PARAMS

    summ = store.lot_summary(lot=lot)
    charts = []
    if summ["runs"]:
        recs = [r for r in store.runs(lot=lot, status="complete") if r.calibration and not r.damaged]
        lim = limits_from_text(recs[-1].config_text) if recs else {}
        vals = np.array([param_vector(r.calibration or {}) for r in recs]) if recs else np.zeros((0, 12))
        for name, idx, scale, key, centre in PARAMS:
            x = vals[:, idx] * scale if len(vals) else np.zeros(0)
            lk = lim.get(key)
            s = 1e-3 * scale if key == "offset_max_mg" else 1.0
            charts.append(control_chart(name, "", x.tolist(), [f"run {r.id}" for r in recs],
                                        None if lk is None else centre + lk * s,
                                        None if lk is None else centre - lk * s))
    return {"lot": lot, "summary": summ, "charts": charts, "lots": queries.lots(store)}

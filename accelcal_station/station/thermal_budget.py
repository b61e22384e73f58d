"""The uncertainty budget of each calibration set point of a thermal table (docs/uncertainty.md).

Every set point's fit gets the room-temperature board's budget (acceptance/budget.py: Type A from the
capture's own standard errors with the effective sample count, Type B from the jig's angle tolerance,
the site's gravity, the board temperature's span over that set point's poses and one count's
resolution) plus the temperature the fit is filed at: ``thermal.temperature_u_c`` through the table's
slope there (``assigned_temperature``), the slope taken from the set points' own fits
(``numpy.gradient`` over their temperatures: central differences inside, one-sided at the ends).
"""
from __future__ import annotations

import numpy as np

from ..acceptance.budget import BudgetInputs, UncertaintyJson, budget, tempco_of
from ..errors import AccelcalError
from ..models.result import FitResult
from ..session import Session
from .report import RunReport
from .settings import StationConfig

# one set point's fit: (set point C, mean board temperature C, fit, its poses)
SetPointFit = tuple[float, float, FitResult, Session]


def _theta(fit: FitResult) -> np.ndarray:
    """(12,) V in mg, then W row by row: the budget's parameter order."""
    return np.concatenate([np.asarray(fit.V, float) * 1e3, np.asarray(fit.W, float).ravel()])


def _sem_g(rep: RunReport, set_point_c: float, P: int) -> np.ndarray | None:
    """(P, 3) the capture's own standard error of each calibration pose at the set point, g."""
    rows = [p for p in rep.poses if p.get("set_point_c") == set_point_c and p.get("role") == "calibrate"]
    if len(rows) != P or not all("sem_mg" in p for p in rows):
        return None
    return np.array([p["sem_mg"] for p in rows], dtype=float) / 1e3


def set_point_budgets(cfg: StationConfig, temperature_u_c: float, fits: list[SetPointFit], rep: RunReport,
                      counts_per_g: float) -> dict[float, UncertaintyJson]:
    """Each set point's budget by set point (module doc); a set point whose budget cannot be evaluated
    is left out and said in the run's events."""
    if len(fits) < 2:
        return {}
    temps = np.array([t for _, t, _, _ in fits])
    slopes = np.gradient(np.stack([_theta(f) for _, _, f, _ in fits]), temps, axis=0)
    out: dict[float, UncertaintyJson] = {}
    for (sp, _, fit, session), slope in zip(fits, slopes, strict=True):
        t = session.temps_c
        std = None
        if all(p.std is not None for p in session.poses):
            std = np.array([p.std for p in session.poses], dtype=float) / counts_per_g
        inp = BudgetInputs(fit.model, fit.readings_g, session.references_g, _sem_g(rep, sp, len(session)), std,
                           np.array([p.n or 0 for p in session.poses], dtype=float), 1.0 / counts_per_g,
                           cfg.jig.angle_tolerance_deg, cfg.site, None if t is None else float(np.ptp(t)),
                           tempco_of(rep.chip), temperature_u_c, slope)
        try:
            out[sp] = budget(inp).to_json()
        except AccelcalError as e:
            rep.events.append(f"uncertainty budget at {sp:g} C not evaluated: {e}")
    return out


__all__ = ["SetPointFit", "set_point_budgets"]

"""A board's uncertainty budget and the decision rule, after its fit (docs/uncertainty.md).

The budget (acceptance/budget.py) takes the capture's own standard error of each pose mean (Type A),
the jig's angle tolerance (``jig.angle_tolerance_deg``), the site's gravity (``station.site``), the
board temperature's span over the run with the chip's data-sheet coefficients, and one count's
resolution.  The decision rule (acceptance/decision.py, ``acceptance.decision_rule``) then names each
parameter inside its limit by less than U: reasons that fail the board (guarded) or warnings (simple).
"""
from __future__ import annotations

import numpy as np

from ..acceptance.budget import Budget, BudgetInputs, budget, tempco_of
from ..acceptance.decision import near_limits, rule_json
from ..acceptance.reasons import Reason
from ..errors import AccelcalError
from ..models.result import FitResult
from ..session import Session
from .report import RunReport
from .settings import StationConfig


def budget_inputs(cfg: StationConfig, session: Session, fit: FitResult, rep: RunReport,
                  counts_per_g: float | None) -> BudgetInputs:
    """What the board's budget is computed from: its fit, its poses and the capture's standard errors."""
    sem = None
    if len(rep.poses) == len(session) and all("sem_mg" in p for p in rep.poses):
        sem = np.array([p["sem_mg"] for p in rep.poses], dtype=float) / 1e3  # the capture's own, g
    std = None
    if counts_per_g and all(p.std is not None for p in session.poses):
        std = np.array([p.std for p in session.poses], dtype=float) / counts_per_g
    n = np.array([p.n or 0 for p in session.poses], dtype=float)
    temps = session.temps_c
    return BudgetInputs(fit.model, fit.readings_g, session.references_g, sem, std, n,
                        None if not counts_per_g else 1.0 / counts_per_g, cfg.jig.angle_tolerance_deg, cfg.site,
                        None if temps is None else float(np.ptp(temps)), tempco_of(rep.chip))


def uncertainty_step(cfg: StationConfig, session: Session, fit: FitResult, rep: RunReport,
                     counts_per_g: float | None) -> list[Reason]:
    """The budget and the rule recorded on the report; the reasons the rule fails the board with
    (guarded), none under simple acceptance (its near-limit reasons go to ``rep.warnings``)."""
    rule = cfg.limits.decision_rule
    try:
        b: Budget = budget(budget_inputs(cfg, session, fit, rep, counts_per_g))
    except AccelcalError as e:
        rep.events.append(f"uncertainty budget not evaluated: {e}")
        return []
    rep.uncertainty = b.to_json()
    rep.decision_rule = rule_json(rule, b.k)
    near = [n.reason(rule) for n in near_limits(fit.W, fit.V, b.expanded_W, b.expanded_V_mg, cfg.limits.values)]
    if rule == "guarded":
        return near
    rep.warnings.extend(near)
    return []

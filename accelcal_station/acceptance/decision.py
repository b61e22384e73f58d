"""The decision rule: how a board's measured V and W, with their expanded uncertainty U, are judged
against the acceptance limits (ILAC-G8:09/2019, JCGM 106:2012, ISO 14253-1:2017).

- ``simple`` (ILAC-G8 4.2.1, "simple acceptance", w = 0): a value up to its limit passes.
- ``guarded`` (ILAC-G8 4.2.2, guard band w = U; ISO 14253-1's acceptance zone for the supplier proving
  conformance): a value passes only up to its limit minus U.  At that acceptance limit the risk of
  passing a board truly beyond the tolerance is at most about 2.3 % (U = 2 u_c, one-sided normal).

The limits with a U are those on the calibration's parameters: ``offset_max_mg`` (each |V_i|),
``gain_error_max`` (each |W_ii - 1|) and ``cross_axis_max`` (each |W_ij|, i != j).  A value inside its
limit by less than U gets the reason ``within_uncertainty_of_limit`` under either rule: under
``guarded`` it fails the board; under ``simple`` it passes it, the reason kept as a warning.  A value
beyond its limit fails with the limit's own reason under either rule.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from .reasons import Reason

RULES = ("simple", "guarded")
CODE = "within_uncertainty_of_limit"
AXES = "xyz"
REFERENCES = "ILAC-G8:09/2019 4.2; ISO 14253-1:2017; JCGM 106:2012"


class DecisionRuleJson(TypedDict):
    """``decision_rule`` in run --json and the store."""

    rule: str
    guard_band: str
    applies_to: list[str]
    near_limit: str
    references: str


def rule_json(rule: str, k: float) -> DecisionRuleJson:
    """The rule as the run states it."""
    return {"rule": rule, "guard_band": f"w = U (k = {k:g})" if rule == "guarded" else "w = 0",
            "applies_to": ["offset_max_mg", "gain_error_max", "cross_axis_max"],
            "near_limit": f"{CODE}: " + ("FAIL" if rule == "guarded" else "PASS with a warning"),
            "references": REFERENCES}


@dataclass(frozen=True)
class NearLimit:
    """A parameter inside its limit by less than its U."""

    key: str  # the limit
    name: str  # the parameter: V_x, W_xx, W_xy, ...
    value: float  # |value| in the limit's unit
    limit: float
    U: float

    def reason(self, rule: str) -> Reason:
        unit = " mg" if self.key.endswith("_mg") else ""
        then = (f"accepted only up to {self.limit - self.U:.4g}{unit} (guarded acceptance)" if rule == "guarded"
                else "passed by simple acceptance")
        return Reason(CODE, f"{self.key}: {self.name} {self.value:.4g}{unit} is within U {self.U:.3g}{unit} of "
                      f"the limit {self.limit:g}{unit}; {then}")


def _figures(W: np.ndarray, V: np.ndarray, U_W: np.ndarray, U_V_mg: np.ndarray
             ) -> dict[str, list[tuple[str, float, float]]]:
    """Each limit's parameters: (name, |value| in the limit's unit, U)."""
    out: dict[str, list[tuple[str, float, float]]] = {
        "offset_max_mg": [(f"V_{AXES[i]}", abs(float(V[i])) * 1e3, float(U_V_mg[i])) for i in range(3)],
        "gain_error_max": [(f"W_{AXES[i]}{AXES[i]}", abs(float(W[i, i]) - 1.0), float(U_W[i, i])) for i in range(3)],
        "cross_axis_max": [(f"W_{AXES[i]}{AXES[j]}", abs(float(W[i, j])), float(U_W[i, j]))
                           for i in range(3) for j in range(3) if i != j]}
    return out


def near_limits(W: np.ndarray, V: np.ndarray, U_W: np.ndarray, U_V_mg: np.ndarray,
                limits: dict[str, float]) -> list[NearLimit]:
    """Every parameter inside its configured limit by less than its U (``V`` in g)."""
    found = []
    for key, params in _figures(np.asarray(W), np.asarray(V), np.asarray(U_W), np.asarray(U_V_mg)).items():
        lim = limits.get(key)
        if lim is None:
            continue
        found += [NearLimit(key, name, v, lim, u) for name, v, u in params if lim - u < v <= lim]
    return found

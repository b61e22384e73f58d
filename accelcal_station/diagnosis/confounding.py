"""Confounding with acquisition order, per term (diagnosis/order.py's module doc): after the selection
(where every static candidate competed with the order trend), name the terms of each selected effect a
change over the session could stand in for, and decide whether the effect keeps its place.

An effect stays selected when its other terms carry evidence of their own: the model with the effect
minus its order-like terms must beat the model without the effect (the same one-sided paired test as
the selection, at alpha).  When they do not, everything the effect explains is in the order-like terms
(a cubic in u_z on poses taken in order of z is a cubic in row number, whatever its exact shape over
the rows): it is ``confounded`` alone, not selected, and its step is undone.  An effect that lost to
the order trend in the selection (Selection.order.lost) is ``confounded`` alone too.
"""
from __future__ import annotations

from dataclasses import dataclass

from .evaluation import Evaluation
from .gap_data import GapData
from .order import OrderConfound, confounded_terms
from .selection import ORDER_EXEMPT, Evaluator, Selection, Step, p_greater


@dataclass
class Resolved:
    """The selection after confounding: final evaluation, selected effects, their steps, the confounds."""

    final: Evaluation
    selected: list[str]
    steps: list[Step]
    confounded: dict[str, OrderConfound]


def _rests_on_order(ev: Evaluator, data: GapData, selected: list[str], effect: str, c: OrderConfound,
                    units_of: Evaluation, alpha: float) -> bool:
    """Whether ``effect`` adds nothing to the others once its order-like terms are left out (module doc)."""
    others = [s for s in selected if s != effect]
    without = ev(others)
    data.drop_terms = frozenset(f"{effect}:{t['term']}" for t in c["terms"])
    try:
        restricted = ev(selected)
    finally:
        data.drop_terms = frozenset()
    units = units_of.nll_unit != 0
    return p_greater((without.nll_unit - restricted.nll_unit)[units]) >= alpha or restricted.rms_g >= without.rms_g


def resolve(ev: Evaluator, data: GapData, base: Evaluation, sel: Selection, alpha: float) -> Resolved:
    """Per-term confounds of the selected effects, and the effects confounded alone (module doc)."""
    selected, steps, final = list(sel.selected), list(sel.steps), sel.final
    confounded: dict[str, OrderConfound] = {}
    for e in [s for s in sel.selected if s not in ORDER_EXEMPT]:
        c = confounded_terms(data, e, alone=False)
        if c is None:
            continue
        if _rests_on_order(ev, data, selected, e, c, base, alpha):
            c["alone"] = True
            c["why"] = (f"what it explains rests on {', '.join(t['term'] for t in c['terms'])}, which a change over "
                        "the session of the same shape would explain as well")
            selected.remove(e)
            steps = [s for s in steps if s["added"] != e]
            final = ev(selected) if selected else base
        confounded[e] = c
    for e in sel.order.lost:
        c = confounded_terms(data, e, alone=True)
        if c is not None and e not in selected:
            confounded[e] = c
    return Resolved(final, selected, steps, confounded)

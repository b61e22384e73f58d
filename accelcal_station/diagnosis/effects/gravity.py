"""gravity: the gravity the data were taken at differs by delta from the one they are judged against
(the stated site's, --gravity or '# gravity_mps2:', else the simulator's ``gravity`` effect:
diagnosis/site.py): a shift of the norm, or of every reference."""
from __future__ import annotations

from .base import DeterministicEffect
from .columns import StaticView


class Gravity(DeterministicEffect):
    name = "gravity"
    static_columns = True
    time_columns = False
    degenerate = ("local gravity scales every static reading alike and the fitted gain absorbs it exactly "
                  "(1 g references and the 1 g norm cannot tell gravity from sensitivity); it needs an "
                  "independent reference such as a known gain or a second acceleration level: a configuration "
                  "without gain and cross_axis (e.g. calibrated output) and the site stated (--gravity)")

    def columns(self, view: StaticView) -> None:
        if view.norm:
            view.add("gravity", "delta", {}, shift=1.0)
        else:
            ref = view.ref
            assert ref is not None, "a static view that is not norm-only has references"
            view.add("gravity", "delta", {c: -ref[:, c] for c in range(3)})

"""Which catalog effects these data can test, and why not the others: the static view's rank and
degrees of freedom with a fold held out, and each effect's own conditions (engine's module doc, step 3)."""
from __future__ import annotations

import math
from collections.abc import Callable, Collection

import numpy as np

from ..errors import UnderdeterminedError
from ..identifiability import assess
from ..models.held import hold_plan
from ..sim.sensor_model import EFFECT_NAMES
from .effects.base import DeterministicEffect
from .effects.catalog import DETERMINISTIC
from .effects.design import describe_design, design_rank_ok, static_design
from .effects.saturation import Saturation
from .folds import make_folds
from .gap_data import GapData, TimeData
from .loading import Simulator


def candidates(data: GapData, sim: Simulator, td: TimeData | None) -> tuple[list[str], dict[str, str], bool, str]:
    """(testable candidates, {effect: why not}, static view usable, why not)."""
    base = sim.baseline
    why: dict[str, str] = {}
    static_ok, static_why = True, ""
    ok, cond = design_rank_ok(base, data, data.norm_only)
    p_train = data.P - math.ceil(data.P / data.n_folds)

    def dof(effects: Collection[str]) -> int:
        A_cols = len(_labels(effects, data))
        return p_train - (A_cols if data.norm_only else math.ceil(A_cols / 3))

    if data.fit_refused:
        static_ok, static_why = False, f"`accelcal fit` refuses these poses ({data.fit_refused})"
    elif not ok:
        words = describe_design(data, base).get("text", f"condition {cond:.3g}")
        static_ok, static_why = False, f"these poses do not determine the baseline ({', '.join(base)}): {words}"
    elif (out := _undetermined_fold(data, base)) is not None:
        static_ok = False
        static_why = (f"with {out} held out, the other poses do not determine the baseline ({', '.join(base)}), "
                      "so a held-out gap would come from an undetermined fit (revisit the poses each is alone in)")
    elif dof(base) < 0:
        static_ok = False
        static_why = (f"{data.P} poses are too few to fit the baseline ({len(_labels(base, data))} parameters"
                      f"{' on the norm' if data.norm_only else ' over 3 channels'}) with a pose held out")
    testable = []
    for e in EFFECT_NAMES:
        if e in base or e not in DETERMINISTIC:
            continue  # stochastic only: judged by its own signature (engine._stochastic), never by the gap
        eff = DETERMINISTIC[e]
        ok, reason = eff.testable(data, td)
        if eff.static_columns and not eff.time_columns and not static_ok:
            why[e] = f"the static view is unavailable: {static_why}"
        elif not ok:
            why[e] = Saturation.reason(data, sim.clip_g) if isinstance(eff, Saturation) else reason
        elif eff.time_columns:
            testable.append(e)  # judged in the time view too: the static view's rank does not gate it
        else:
            why_not = _static_why_not(data, base, eff, dof)
            if why_not:
                why[e] = why_not
            else:
                testable.append(e)
    return testable, why, static_ok, static_why


def _undetermined_fold(data: GapData, base: tuple[str, ...]) -> str | None:
    """The held-out poses (named) of the first training fold that leaves the baseline undetermined, or None."""
    train = make_folds(data).train
    for k in range(train.shape[0] - 1):
        if not _fold_determined(data, base, train[k]):
            names = [data.names[i] for i in np.flatnonzero(~train[k])]
            return f"pose{'s' if len(names) > 1 else ''} {', '.join(names[:6])}{' ...' if len(names) > 6 else ''}"
    return None


def _fold_determined(data: GapData, base: tuple[str, ...], rows: np.ndarray) -> bool:
    """Whether the training poses ``rows`` determine the baseline: by fit's own identifiability for the
    model fit chooses (models/choice.py, identifiability.py, models/held.py), else by the design's rank."""
    g = data.g[rows]
    if data.fit_faces:  # the hand-placed norm fit: every face needs a pose (models/handplaced.py)
        u = g / np.linalg.norm(g, axis=1, keepdims=True)
        ax = np.argmax(np.abs(u), axis=1)
        return len({(int(a), bool(u[i, a] > 0)) for i, a in enumerate(ax)}) == 6
    if data.fit_model == "9":
        try:
            hold_plan(g, "9")
        except UnderdeterminedError:
            return False
        return True
    if data.fit_model is not None:  # the baseline's terms of fit's model: offset and W (no cubic: a candidate)
        return assess(g, "12" if "cross_axis" in base else "6").determined
    return design_rank_ok(base, data, data.norm_only, rows)[0]


def _static_why_not(data: GapData, base: tuple[str, ...], eff: DeterministicEffect,
                    dof: Callable[[Collection[str]], int]) -> str:
    """Why the static view cannot fit ``eff`` on top of the baseline ('' when it can)."""
    ok, cond = design_rank_ok(base + (eff.name,), data, data.norm_only)
    if not ok:
        words = describe_design(data, base + (eff.name,)).get("text", f"condition {cond:.3g}")
        return f"{eff.degenerate} ({words})"
    if dof(base + (eff.name,)) < 0:
        return f"{data.P} poses are too few to fit its parameters with a pose held out"
    return ""


def _labels(effects: Collection[str], data: GapData) -> list[tuple[str, str]]:
    dT = None if data.temp_c is None else data.temp_c - np.mean(data.temp_c)
    dh = np.zeros((data.P, 2)) if "drift" in effects else None
    return static_design(set(effects), data.g, data.ref, dT, dh, data.norm_only, data.n_temps)[3]

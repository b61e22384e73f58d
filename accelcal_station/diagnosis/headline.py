"""The headline of a diagnosis (``headline`` of diagnose --json, the GAP lines of its text): the held-out
residual RMS `accelcal fit` reports for the same file and model terms, over the floor of a pose mean.

One set of numbers: the held-out RMS is fit's own figure (models/fitting.fit_session, the function
`accelcal fit` calls: leave-one-pose-out, or leave-one-orientation-out where orientations repeat, as
acceptance judges), for the model whose terms are the baseline's (fit's choice, models/choice.py, less
the terms the simulator does not have: model 12 where fit chooses 15 and the simulator has no cubic).
The gap is that RMS over the floor's RMS for the same residuals (static view: 3 components a pose with
references, the norm without).  The selection's own held-out figures (K folds round-robin, each pose
weighted by its floor) differ where the folds or the weights do; ``note`` says by how much and why in
one line.  ``expected_mg`` is what the held-out residuals would be at the floor with the design's own
fit uncertainty (floor plus the fit's prediction variance): a barely determined design's held-out
residual is far above the floor of a pose mean without any gap.
"""
from __future__ import annotations

from typing import TypedDict

import numpy as np

from ..errors import AccelcalError
from ..models.fitting import fit_session
from .evaluation import Evaluation
from .gap_data import GapData

SAME_REL = 0.01  # the selection's figure within 1 % of fit's: the same figure


class Headline(TypedDict):
    """The headline figures (module doc); None where there is no static view or fit cannot give them."""

    held_out_rms_mg: float | None
    gap: float | None
    floor_mg: float | None
    expected_mg: float | None
    source: str
    fit_model: str | None
    selection_rms_mg: float | None
    selection_gap: float | None
    note: str


def fit_model_for(data: GapData, baseline: tuple[str, ...]) -> str | None:
    """The model `accelcal fit` fits with the baseline's terms: fit's choice, less what the simulator lacks."""
    if data.fit_model is None or data.fit_faces:
        return None
    if data.fit_model == "9":
        return "9"
    return "15" if "cubic" in baseline else "12" if "cross_axis" in baseline else "6"


def _fit_figure(data: GapData, baseline: tuple[str, ...]) -> tuple[float | None, str | None, str]:
    """(fit's held-out RMS in g, the model, how it was held out) or (None, None, why not)."""
    model = fit_model_for(data, baseline)
    if len(data.sessions) != 1:
        return None, None, f"{len(data.sources)} files: `accelcal fit` reads one file"
    if data.fit_faces:
        return None, None, "hand-placed faces: `accelcal fit --hand-placed` reports the norm fit's held-out norm error"
    if model is None:
        return None, None, "`accelcal fit` refuses these poses or chose no model"
    if data.n_temps >= 2:
        return None, None, "poses at several temperatures: `accelcal fit` fits each temperature apart"
    if data.norm_only and model != "9":
        return None, None, f"--norm-only: `accelcal fit` fits model {model} on the references"
    try:
        fr = fit_session(data.sessions[0], model)
    except AccelcalError as e:
        return None, model, f"`accelcal fit --model {model}` refuses: {e}"
    rms = fr.acceptance_crossval_rms_g
    how = "leave-one-orientation-out" if fr.orientations_repeat else "leave-one-pose-out"
    return (None if rms is None or not np.isfinite(rms) else float(rms)), model, how


def headline(data: GapData, baseline: tuple[str, ...], base: Evaluation) -> Headline:
    """The headline (module doc) of the baseline evaluation ``base``."""
    r, f, v = base.r_static, base.floor_static, base.v_static
    if r is None or f is None or v is None:
        return {"held_out_rms_mg": None, "gap": None, "floor_mg": None, "expected_mg": None,
                "source": "no static view: the time view's held-out gap", "fit_model": None,
                "selection_rms_mg": None, "selection_gap": base.gap, "note": ""}
    floor = float(np.sqrt(np.mean(f)))
    sel = float(np.sqrt(np.mean(r**2)))
    rms, model, how = _fit_figure(data, baseline)
    if rms is None:
        return {"held_out_rms_mg": 1e3 * sel, "gap": sel / floor, "floor_mg": 1e3 * floor,
                "expected_mg": 1e3 * float(np.sqrt(np.mean(v))), "source": "the selection's held-out folds",
                "fit_model": model, "selection_rms_mg": 1e3 * sel, "selection_gap": sel / floor,
                "note": f"not `accelcal fit`'s figure: {how}"}
    if model != data.fit_model:  # fit's own choice has terms the simulator does not: the baseline's model is judged
        how += f"; fit chooses model {data.fit_model}, whose extra terms the simulator lacks"
    folds = "one pose at a time" if data.n_folds == data.P else f"{data.n_folds} folds of poses round-robin"
    same = abs(sel - rms) <= SAME_REL * rms
    note = ("the selection's held-out folds give the same figure" if same else
            f"the selection below holds out {folds}, each pose weighted by its floor "
            f"({_n_range(data.n)} samples a pose): {1e3 * sel:.4g} mg there")
    return {"held_out_rms_mg": 1e3 * rms, "gap": rms / floor, "floor_mg": 1e3 * floor,
            "expected_mg": 1e3 * float(np.sqrt(np.mean(v))), "source": f"`accelcal fit --model {model}` {how}",
            "fit_model": model, "selection_rms_mg": 1e3 * sel, "selection_gap": sel / floor, "note": note}


def _n_range(n: np.ndarray) -> str:
    lo, hi = float(np.min(n)), float(np.max(n))
    return f"{lo:.0f}" if lo == hi else f"{lo:.0f}-{hi:.0f}"

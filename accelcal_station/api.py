"""The library face, for engineers in notebooks and for the command line alike.

``from accelcal_station import load, fit, simulate, diagnose, Calibration``: read a pose table
or raw log, fit a calibration, run a pose design on a simulated board, diagnose the sim-to-real
gap. `accelcal fit`, `accelcal simulate` and `accelcal diagnose` call these same functions, so a
notebook gets exactly what the command prints. docs/python-api.md has a runnable example.

Layer: above the flows (station, lot, diagnosis) and the parts below them; only the CLI
imports this module.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Unpack

import numpy as np

from .calibration import Calibration
from .data.loader import Loaded, load
from .data.log_time import check_rate
from .diagnosis.request import DiagnoseOptions, DiagnoseRequest
from .errors import AccelcalError, DataError, UnderdeterminedError, UnitsError
from .fixtures.designs import get_design
from .models.choice import choose_model, with_face_references
from .models.fitting import fit_session, fit_temperature
from .models.handplaced import norm_fit_result
from .models.result import FitResult
from .session import Session

if TYPE_CHECKING:  # the simulator and the diagnosis are imported by the calls that use them (fast `accelcal fit`)
    from .diagnosis.result import Diagnosis
    from .drivers.simulated import SimulatedBoard
    from .fixtures.simulated_run import SimulatedRun, Sink

_LAZY = {"Diagnosis": ".diagnosis.result", "SimulatedRun": ".fixtures.simulated_run"}


def __getattr__(name: str) -> Any:
    """``Diagnosis`` and ``SimulatedRun`` on first use (PEP 562), as the functions import them."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __package__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


TEMP_METHODS = ("linear", "quadratic")


@dataclass
class Fit:
    """A calibration fitted to a session: ``calibration`` (to apply, save and burn) and, per
    calibration temperature (``None`` for a session at one temperature), the fit behind it."""

    calibration: Calibration
    model: str
    fits: list[tuple[float | None, FitResult]]
    sessions: list[Session] = field(default_factory=list)
    temp_method: str | None = None

    @property
    def result(self) -> FitResult:
        """The one fit of a single-temperature session (residuals, covariance, cross-validation)."""
        if len(self.fits) != 1:
            raise DataError(f"this calibration has {len(self.fits)} temperatures; take .fits[i] for one of them")
        return self.fits[0][1]


def check_temp_method(method: str) -> None:
    """Interpolation between calibration temperatures: linear or quadratic (AN4399 section 9)."""
    if method not in TEMP_METHODS:
        raise DataError(f"--temp-method {method!r}; allowed: linear, quadratic")


def _as_loaded(data: str | Path | Loaded | Session, model: str | None) -> tuple[Session, Loaded | None, str]:
    if isinstance(data, Session):
        return data, None, "the data"
    if isinstance(data, Loaded):
        return data.session, data, str(data.log.source) if data.log is not None else "the data"
    loaded = load(data, references=model is not None and model != "9")
    return loaded.session, loaded, str(data)


def fit(data: str | Path | Loaded | Session, model: str | int | None = None, *, temp_method: str = "linear",
        source: str | None = None) -> Fit:
    """Fit model 6, 9, 12 or 15 (AN4399 Eqn 46; the 9-parameter gravity norm) to a pose table's
    path, a loaded file or a Session; with poses at two or more temperatures, one fit per
    temperature and a table interpolated between them (AN4399 section 9).

    With no ``model``, the richest model the poses determine (models/choice.py: 15 or 12 with
    references; without, the hand-placed faces' norm fit or 9), as `accelcal fit` chooses it.
    ``source`` names the data in error messages (default: the path).
    """
    m = str(model) if model is not None else None
    session, loaded, name = _as_loaded(data, m)
    is_raw = loaded is not None and loaded.log is not None
    name = source or name
    if m is None:
        return _fit_chosen(session, name, temp_method, is_raw)
    check_temp_method(temp_method)
    if m != "9" and session.units == "counts" and session.counts_per_g is None:
        raise UnitsError(f"{name}: readings are counts with no counts_per_g; model {m} needs --counts-per-g N "
                         "or a '# counts_per_g: N' line (only model 9 can estimate it)")
    have_t = [p.temp_c is not None for p in session.poses]
    if any(have_t) and not all(have_t):
        raise DataError(f"{name}: pose {session.names[have_t.index(False)]!r} has no temp_c while others do; "
                        "give temp_c for every pose or for none")
    temps = session.by_temperature() if any(have_t) else []
    try:
        if len(temps) >= 2:
            cal, by_t = fit_temperature(session, m, temp_method)
            return Fit(cal, m, [(t, f) for t, f in by_t], [sub for _, sub in temps], temp_method)
        fr = fit_session(session, m)
    except AccelcalError as e:
        found = f" (found {len(session)} static intervals in the raw log)" if is_raw else ""
        raise type(e)(f"{name}: {e}{found}") from None
    except np.linalg.LinAlgError as e:  # a design so degenerate the eigen/SVD solvers do not converge
        raise UnderdeterminedError(f"{name}: the {len(session)} poses are numerically degenerate for model {m} "
                                   f"({e}); allowed: poses spread over distinct orientations") from None
    return Fit(fr.calibration, m, [(None, fr)], [session])


def _fit_chosen(session: Session, name: str, temp_method: str, is_raw: bool) -> Fit:
    """No model given: choose it from the data; hand-placed faces get the norm fit's gain and offset."""
    try:
        choice = choose_model(session)
    except AccelcalError as e:
        raise type(e)(f"{name}: {e}") from None
    if choice.faces is None:
        return fit(session, choice.model, temp_method=temp_method, source=name)
    faced = with_face_references(session, choice.faces)
    return hand_placed_fit(fit(faced, "6", temp_method=temp_method, source=name), faced)


def hand_placed_fit(result: Fit, session: Session) -> Fit:
    """A model-6 fit of hand-placed faces (``session`` with the faces as references) made the norm
    fit (models/handplaced.py): the one FitResult that is printed, judged and saved."""
    if len(result.fits) != 1:
        return result
    fr = result.result
    ref = session.references_g
    if ref is None:
        raise DataError("hand-placed faces need the faces' references (an 'axis up' pose table)")
    nf = norm_fit_result(fr.readings_g, ref, fr, session.noise_g())
    return Fit(nf.calibration, "6", [(None, nf)], result.sessions, result.temp_method)


MAX_TEMPS = 16  # set points of one simulated run
MAX_SAMPLES_PER_POSE = 10**7  # drawn and written in chunks (streamed), so bounded by time, not memory
MAX_TOTAL_SAMPLES = 10**8  # poses x set points x samples: about a minute of simulation and 2 GB of raw log


def _check_run(samples: int, temps_c: Sequence[float] | None, move_s: float, poses: int = 1) -> None:
    """The limits `accelcal simulate` puts on its options, for callers that skip the command line
    (checked before any sample is made: they bound its time and its output)."""
    if not (isinstance(samples, int) and 2 <= samples <= MAX_SAMPLES_PER_POSE):
        raise DataError(f"samples={samples!r}; allowed: a whole number from 2 to {MAX_SAMPLES_PER_POSE} "
                        "(a pose's std needs 2)")
    temps = list(temps_c or [])
    if len(temps) > MAX_TEMPS:
        raise DataError(f"temps_c: {len(temps)} temperatures; allowed: at most {MAX_TEMPS}")
    total = samples * poses * max(1, len(temps))
    if total > MAX_TOTAL_SAMPLES:
        raise DataError(f"samples={samples} x {poses} poses x {max(1, len(temps))} temperatures = {total} samples; "
                        f"allowed: at most {MAX_TOTAL_SAMPLES} in one run (fewer samples, poses or temperatures)")
    if not all(isinstance(t, (int, float)) and math.isfinite(t) and -60.0 <= t <= 150.0 for t in temps):
        raise DataError(f"temps_c={temps!r}; allowed: temperatures in C between -60 and 150")
    if len(set(temps)) != len(temps):
        raise DataError(f"temps_c={temps!r}: a temperature repeats; each must be distinct")
    if not (math.isfinite(move_s) and 0.0 <= move_s <= 3600.0):
        raise DataError(f"move_s={move_s!r}; allowed: 0 to 3600 seconds")


def simulate(design: str, *, config: str | None = None, seed: int | None = None, samples: int = 1000,
             temps_c: Sequence[float] | None = None, move_s: float = 2.0, raw: bool = False,
             sink: Sink | None = None, on_board: Callable[[SimulatedBoard], None] | None = None) -> SimulatedRun:
    """Run pose design ``design`` (six-face, an4399-8, optimal-N, ...) on the simulated board of a
    station config (default: an ideal MMA8451) at each of ``temps_c``: the pose means as a Session
    in counts, the raw samples when ``raw`` (handed chunk by chunk to ``sink`` when given, not
    kept), and the board's ground truth (``.truth()``).  ``on_board`` sees the board before any
    sample is taken (e.g. to write a raw log's header: ``run_metadata``)."""
    from .fixtures.simulated_run import run_design, simulated_board

    get_design(design)  # an unknown design is refused before the board is built
    _check_run(samples, temps_c, move_s, len(get_design(design)))
    board = simulated_board(config, seed)
    temps = list(temps_c) if temps_c else None
    if on_board is not None:
        on_board(board)
    return run_design(board, design, samples=samples, temps=temps, move_s=move_s, raw=raw, sink=sink)


def diagnose(files: Sequence[str | Path] | DiagnoseRequest, **options: Unpack[DiagnoseOptions]) -> Diagnosis:
    """The sim-to-real gap of ``files`` (pose tables, or raw logs with ``raw=True``) against the simulated
    device of ``config`` (default configs/sim.yaml): which catalog effect explains it, judged on
    held-out residuals (DESIGN.md, the diagnosis). The options are DiagnoseRequest's fields, as keywords
    (``config``, ``raw``, ``units``, ``counts_per_g``, ``gravity_mps2``, ``columns``, ``skip_rows``,
    ``rate_hz``, ``samples``, ``norm_only``), or one DiagnoseRequest in place of ``files``.
    ``.to_json()`` is `accelcal diagnose --json`."""
    from .diagnosis.engine import diagnose as _diagnose
    from .diagnosis.loading import load_data, load_simulator

    if isinstance(files, DiagnoseRequest):
        if options:
            raise TypeError("diagnose: give a DiagnoseRequest or files with keyword options, not both")
        request = files
    else:
        request = DiagnoseRequest(files=list(files), **options)
    check_rate(request.rate_hz)
    sim = load_simulator(request.config)
    return _diagnose(load_data(request), sim)


__all__ = ["Calibration", "DiagnoseRequest", "Diagnosis", "Fit", "FitResult", "Loaded", "Session", "SimulatedRun",
           "diagnose", "fit", "hand_placed_fit", "load", "simulate"]

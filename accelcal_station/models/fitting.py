"""Calibration models: fit a pose set (one board or a stack of boards).

``fit`` and ``fit_batch`` are the entry points; both go through the same stacked
code, so fitting D boards at once is identical to fitting them one at a time.

  model "6"   diagonal gain + offset, least squares (AN4399 Eqns 6-17)
  model "12"  full W + offset (AN4399 Eqns 35-48)
  model "15"  full W + offset + diagonal cubic (AN4399 Eqns 67-72)
  model "9"   A = M (V - B), symmetric M, gravity norm only (nine-position paper)
"""
from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..calibration import MODELS, Calibration, TemperatureTable
from ..conventions import check_units, units_per_g
from ..errors import DataError, UnderdeterminedError, UnitsError
from ..identifiability import first_of_orientation
from ..session import Session
from .crossval import crossval_by_orientation
from .gravity_norm import PARAM_NAMES, nominal_scale
from .held import HoldPlan, confirm_holds, cubic_held, hold_plans
from .result import BatchFit, FitResult
from .sanity import Refusal, absurd_coefficients, absurd_norm_model, absurd_readings
from .screening import screen
from .site_norm import at_site_norm
from .stacked import BLOCK, assemble, fit_stacked
from .threads import usable_cpus


def check_model(model: str | int) -> str:
    m = str(model)
    if m not in MODELS:
        raise DataError(f"model {model!r}; allowed: {', '.join(MODELS)}")
    return m


def check_plausible_g(gf: np.ndarray, units: str, sq: np.ndarray | None = None) -> None:
    """Refuse readings whose median norm is not about 1 g (wrong units or scale); ``sq``: the
    readings' squared norms when the caller has them."""
    with np.errstate(over="ignore", invalid="ignore"):  # a 1e308 reading is refused per pose later (models/sanity.py)
        sq = np.einsum("...k,...k->...", gf, gf) if sq is None else sq
        if np.all((sq >= 0.1) & (sq <= 8.9)):  # every norm within 0.31-2.99 g: so is the median
            return
        sq = np.einsum("...k,...k->...", gf, gf)
        if np.all((sq >= 0.1) & (sq <= 8.9)):
            return
        norms = np.linalg.norm(gf, axis=-1)
    med = float(np.median(norms))
    if not (0.3 <= med <= 3.0):
        hint = "counts given as g? use --units counts --counts-per-g N" if med > 3 else "wrong counts_per_g?"
        raise UnitsError(f"readings in {units} have a median norm of {med:.4g} g, expected about 1 g ({hint})")


def _input_per_g(x: np.ndarray, model: str, units: str, counts_per_g: ArrayLike | None,
                 gravity_mps2: float | None) -> np.ndarray:
    """Input units per g of each board (D,): counts_per_g (one or one per board), estimated from
    the readings for model 9 on counts without it, else the g or m/s^2 scale."""
    D = x.shape[0]
    if model == "9" and units == "counts" and counts_per_g is None:
        return nominal_scale(x)  # (D,)
    if units == "counts":
        cpg = np.broadcast_to(np.asarray(counts_per_g if counts_per_g is not None else np.nan, dtype=float), (D,))
        if not np.all(np.isfinite(cpg)) or np.any(cpg <= 0):
            raise UnitsError(f"model {model} on counts needs --counts-per-g (a positive number)")
        return cpg.copy()
    return np.full(D, units_per_g(units, gravity_mps2=gravity_mps2))  # g or mps2: no counts_per_g


def fit_batch(readings: ArrayLike, references: ArrayLike | None = None, model: str | int = "12", *,
              units: str = "g", counts_per_g: ArrayLike | None = None, gravity_mps2: float | None = None,
              noise: ArrayLike | None = None, workers: int | None = None, norm_g: float = 1.0) -> BatchFit:
    """Fit D boards at once with the one estimator per model: the stacked fitters of
    models/stacked.py (closed forms for 6/12/15, batched Gauss-Newton for 9), which lot
    files, pose tables, the store and single boards all go through.

    readings: (D, P, 3) pose means in ``units``; references: (D, P, 3) or (P, 3)
    expected output in g (required for 6/12/15, ignored by 9); noise: optional
    (D, P, 3) standard error of each mean in ``units``.  counts_per_g may be a
    scalar or one value per board; for model 9 it may be None (estimated).
    ``workers``: threads (default: one per usable CPU, at most 8); a large stack is cut into
    blocks of boards, each screened, planned, fitted and checked on one thread (every step is
    per board, so the result does not depend on the number of threads).
    ``norm_g``: model 9's calibrated norm, the site's gravity in standard g (models/site_norm.py).
    """
    model = check_model(model)
    check_units(units)
    x = np.asarray(readings, dtype=float)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise DataError(f"readings must have shape (boards, poses, 3); got {x.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        finite = bool(np.isfinite(x.sum())) or bool(np.all(np.isfinite(x)))  # one sum decides most stacks
    if not finite:
        raise DataError("readings contain NaN or infinity")
    scale = _input_per_g(x, model, units, counts_per_g, gravity_mps2)
    # one scale for the stack (a lot, the g of a pose table): a scalar division, the same numbers
    gf = x / scale[0] if len(scale) and (scale == scale[0]).all() else x / scale[:, None, None]
    nz = None
    if noise is not None:
        nz = np.broadcast_to(np.asarray(noise, dtype=float), x.shape) / scale[:, None, None]
    front = _Front(model, units, references, workers)
    blocks = front_blocks(len(gf), model)
    if len(blocks) == 1:
        res = front.fit(gf, x, nz)
    else:
        if model != "9":  # the median norm of the whole stack, as one block would judge it
            check_plausible_g(gf, units)
        res = _blocked(front, gf, x, nz, blocks)
    res = at_site_norm(res, norm_g)
    res.input_units = units
    res.input_per_g = scale
    return res


# Models whose front and fit are cut into blocks of boards on threads: on 20,000 boards and 2
# CPUs, fit_batch took 123 against 148 ms on one thread (model 9) and 190 against 234 ms (15);
# model 12's many short numpy calls hand the GIL over more than they overlap (38.8 against 34.0
# ms): one block, and fit_stacked's own.  A block is fit_stacked's (model 9's 8192 boards), so
# every board is fitted among the same boards whatever the number of threads: model 9's
# iterations and their LAPACK fallbacks run per block, and the figures are the same to the bit.
FRONT_BLOCK = {"6": 8192, "9": BLOCK["9"], "15": 8192}


def front_blocks(D: int, model: str) -> list[slice]:
    """fit_batch's blocks of D boards: consecutive FRONT_BLOCK[model] boards (one block for a
    model not cut, or a stack that fits in one), the same on any number of threads."""
    size = FRONT_BLOCK.get(model, D)
    return [slice(a, min(a + size, D)) for a in range(0, D, size)] if size < D else [slice(0, D)]


def _blocked(front: _Front, gf: np.ndarray, x: np.ndarray, nz: np.ndarray | None, blocks: list[slice]) -> BatchFit:
    """fit_batch's front and fit per block of boards, the blocks on a thread pool, assembled in order."""
    def one(sl: slice) -> tuple[slice, BatchFit]:
        return sl, front.fit(gf[sl], x[sl], None if nz is None else nz[sl], rows=sl, checked=True)

    if front.threads == 1:
        parts = [one(sl) for sl in blocks]
    else:
        with ThreadPoolExecutor(max_workers=min(len(blocks), front.threads)) as ex:
            parts = list(ex.map(one, blocks))
    res = assemble(len(gf), gf, parts)
    defused = [(sl, b.readings_g) for sl, b in parts if not np.shares_memory(b.readings_g, gf)]
    if defused:  # a block fitted some boards on their references (absurd readings): as one block would say
        res.readings_g = gf.copy()
        for sl, g in defused:
            res.readings_g[sl] = g
    return res


@dataclass(frozen=True)
class _Front:
    """What fit_batch does to a stack of boards already in g: screen, plan, fit, cross-validate
    and refuse the absurd (``fit``), for the whole stack or one block of it."""

    model: str
    units: str
    references: ArrayLike | None
    workers: int | None

    @property
    def threads(self) -> int:
        return min(usable_cpus(), 8) if self.workers is None else max(1, int(self.workers))

    def _refs(self, rows: slice | None) -> np.ndarray | None:
        """The references of the boards ``rows`` (None: all): (P, 3) shared, or theirs of (D, P, 3)."""
        if self.references is None:
            return None
        ref = np.asarray(self.references, dtype=float)
        return ref[rows] if rows is not None and ref.ndim == 3 else ref

    def fit(self, gf: np.ndarray, x: np.ndarray, nz: np.ndarray | None, rows: slice | None = None,
            checked: bool = False) -> BatchFit:
        """The boards gf (D, P, 3) in g (x: the same in input units); ``checked``: their
        plausibility judged already (over the whole stack); ``rows``: their rows of the stack.
        A reading far beyond any sensor (1e300) overflows the screens on its way to being refused
        by name (_refuse_absurd): no warning (numpy's error state is per thread, so set here)."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._fit(gf, x, nz, rows, checked)

    def _fit(self, gf: np.ndarray, x: np.ndarray, nz: np.ndarray | None, rows: slice | None,
             checked: bool) -> BatchFit:
        # model 12 holds no term (a board is fitted or refused), so its fit does not wait for the
        # plan: on a second CPU it runs while the front screens, and is used unless a board had to
        # be fitted on its references instead (an absurd reading)
        overlap = self.model == "12" and len(gf) >= OVERLAP_BOARDS and rows is None and self.threads > 1 \
            and max(gf.max(), -gf.min()) <= 1e6  # no reading that could overflow the fit (it would be refitted)
        if not overlap:  # one board, a lot chunk, one CPU: no executor at all
            return self._front(gf, x, nz, rows, checked, None)
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="accelcal-fit12") as ex:
            return self._front(gf, x, nz, rows, checked, ex.submit(_fit12, gf, self._refs(rows), x, nz, self.workers))

    def _front(self, gf: np.ndarray, x: np.ndarray, nz: np.ndarray | None, rows: slice | None,
               checked: bool, early: Future[BatchFit] | None) -> BatchFit:
        model, references = self.model, self._refs(rows)
        workers = self.workers if rows is None else 1
        # what the references certify without comparing poses (models.screening.screen: exact where
        # it holds), from one boards-last pass over the readings
        refs = None if references is None or model == "9" else references
        scr = screen(gf, refs if refs is not None and refs.shape[-2:] == gf.shape[-2:] else None, model)
        if model != "9" and not checked:
            check_plausible_g(gf, self.units, scr.sq)
        # from the distinct orientations, before any solver runs: what each board determines, and
        # the weak terms held at nominal (models/held.py; refused when a gain or an offset is weak)
        first = first_of_orientation(gf, apart=scr.apart)  # once, for the plan and the leave-one-orientation-out folds
        plan = hold_plans(gf, model, nz, first, scr.determined)
        if model == "9":  # each noise-rule hold checked by the held-out data (models/held.py)
            plan = confirm_holds(gf, nz, plan, workers)
        if len(gf) == 1 and plan.refused[0]:  # one board: its reason, before a solver says less
            raise UnderdeterminedError(plan.refused[0])
        bad_readings = absurd_readings(gf, scr.sq) if model != "9" else None  # judged once, used twice
        gf_fit = _defused(gf, references, bad_readings)
        try:
            if early is not None and gf_fit is gf:
                res = early.result()
                res.held = plan.held
            else:
                with np.errstate(over="ignore", invalid="ignore"):
                    res = _fit_stack(gf_fit, references, x, model, nz, plan, workers,
                                     scr.boards_last if gf_fit is gf else None)
        except np.linalg.LinAlgError:
            raise DataError("the readings cannot be fitted (numerically singular or overflowing: "
                            "a reading far beyond the sensor's range?)") from None
        _crossval_orient(res, gf_fit, references, x, model, nz, plan, first if gf_fit is gf else None, workers)
        if any(plan.refused):
            absurd = np.zeros(len(gf), dtype=bool) if bad_readings is None else bad_readings.mask
            for d, why in enumerate(plan.refused):
                if why and not absurd[d]:  # an absurd reading is named instead (_refuse_absurd)
                    res.ok[d] = False
                    res.messages[d] = why
                    res.held[d] = []
        res.poses_apart = scr.apart
        if plan.freed:
            res.freed = plan.freed
        _refuse_absurd(res, bad_readings)
        return res


OVERLAP_BOARDS = 8192  # model 12 stacks from which the fit starts beside the front (fit_batch); a lot chunk
# (~4,100 boards) does not: beside the CSV read-ahead thread it cost `accelcal batch` 10 % (gate lot 1.95 against 2.13)


def _fit12(gf: np.ndarray, references: ArrayLike | None, x: np.ndarray, nz: np.ndarray | None,
           workers: int | None) -> BatchFit:
    """Model 12's stacked fit of every board (what _fit_stack does when nothing is held), on its own thread."""
    with np.errstate(over="ignore", invalid="ignore"):
        return fit_stacked(gf, _references(references, x, "12"), "12", nz, workers)


def _defused(gf: np.ndarray, references: ArrayLike | None, bad_readings: Refusal | None) -> np.ndarray:
    """The readings to fit: a board with an absurd reading (1e308) is fitted on its references
    instead, so it cannot overflow the stack, and is then refused with the reading named."""
    if bad_readings is None or references is None or not bad_readings.mask.any():
        return gf
    ref = np.broadcast_to(np.asarray(references, dtype=float), gf.shape)
    return np.where(bad_readings.mask[:, None, None], ref, gf)


def _fit_stack(gf: np.ndarray, references: ArrayLike | None, x: np.ndarray, model: str,
               nz: np.ndarray | None, plan: HoldPlan, workers: int | None = None,
               boards_last: np.ndarray | None = None) -> BatchFit:
    """The one stacked estimator (models/stacked.py) for every board, with each board's held
    terms at nominal: model 9 by the constrained Gauss-Newton (a free mask per board), model
    15 with the cubic held by model 12's fit of those boards, stated as model 15."""
    if not any(plan.held):  # nothing held on any board (the usual lot): one fit of the stack
        res = fit_stacked(gf, None if model == "9" else _references(references, x, model), model, nz, workers,
                          boards_last=boards_last)
        res.held = plan.held
        return res
    held = [bool(h) for h in plan.held]
    if model == "9":
        free = plan.free(PARAM_NAMES) if any(held) else None
        res = fit_stacked(gf, None, "9", nz, workers, free=free)
    elif model == "15" and any(held):
        ref = np.broadcast_to(_references(references, x, model), gf.shape)
        rows = np.flatnonzero(held)
        nz_h = None if nz is None else nz[rows]
        as15 = cubic_held(fit_stacked(gf[rows], ref[rows], "12", nz_h, workers), [plan.held[d] for d in rows])
        if len(rows) == len(gf):
            return as15
        rest = np.flatnonzero(~np.array(held))
        nz_r = None if nz is None else nz[rest]
        res = assemble(len(gf), gf, [(rest, fit_stacked(gf[rest], ref[rest], "15", nz_r, workers)), (rows, as15)])
    else:
        res = fit_stacked(gf, _references(references, x, model), model, nz, workers)
    res.held = plan.held  # the plan's own (D,) lists, made for this fit
    return res


def _crossval_orient(res: BatchFit, gf: np.ndarray, references: ArrayLike | None, x: np.ndarray, model: str,
                     nz: np.ndarray | None, plan: HoldPlan, first: np.ndarray | None = None,
                     workers: int | None = None) -> None:
    """Leave every pose of one distinct orientation out at a time (models/crossval.py), each fold
    refitted by the one stacked estimator with the board's held terms."""
    ref = None if model == "9" else np.broadcast_to(_references(references, x, model), gf.shape)

    def fold(rows: np.ndarray, keep: np.ndarray) -> BatchFit:
        sub = HoldPlan([plan.held[d] for d in rows], [""] * len(rows))
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            try:
                return _fit_stack(gf[rows][:, keep], None if ref is None else ref[rows][:, keep], x[rows][:, keep],
                                  model, None if nz is None else nz[rows][:, keep], sub, workers)
            except (UnderdeterminedError, DataError, np.linalg.LinAlgError):
                return _failed(len(rows))

    rms, ok, distinct = crossval_by_orientation(gf, ref, model, fold, res.crossval_rms_g, res.crossval_ok, first)
    res.crossval_by_orientation_rms_g, res.crossval_by_orientation_ok, res.distinct_orientations = rms, ok, distinct


def _failed(n: int) -> BatchFit:
    """A fold no fit determines: every board not ok (its cross-validation is not computable)."""
    z = np.zeros((n, 3))
    return BatchFit("", np.zeros((n, 3, 3)), z, z, np.zeros((n, 0, 3)), np.zeros((n, 0)), z, np.zeros(n),
                    np.zeros(n), np.zeros(n, bool), np.zeros(n), np.zeros((n, 3, 3)), z, z, np.zeros(n, bool),
                    np.zeros((n, 0, 0)), np.zeros((n, 0)), [], np.zeros(n, bool), [""] * n, np.zeros((n, 0, 3)))


def _references(references: ArrayLike | None, x: np.ndarray, model: str) -> np.ndarray:
    if references is None:
        raise DataError(f"model {model} needs pose references (ref_x/ref_y/ref_z or pitch/roll); "
                        "model 9 needs none")
    ref = np.asarray(references, dtype=float)
    if ref.shape[-2:] != x.shape[-2:] or not np.all(np.isfinite(ref)):
        raise DataError(f"references must match readings' shape {x.shape[-2:]} and be finite")
    return ref


def _refuse_absurd(res: BatchFit, bad_readings: Refusal | None) -> None:
    """Mark boards whose readings or coefficients are physically absurd as not fitted
    (models/sanity.py, over the whole stack): a degenerate calibration is never returned."""
    if res.model == "9":  # raw readings may carry any offset (unsigned counts): judge the output
        checks = [absurd_norm_model(res.W, res.norm_error_g)]
    else:
        checks = [c for c in (bad_readings, absurd_coefficients(res.W, res.V)) if c is not None]
    taken = np.zeros(len(res), bool)
    for check in checks:  # the first check that refuses a board names its reason
        for d in np.flatnonzero(check.mask & ~taken & res.ok):
            res.ok[d] = False
            res.messages[d] = check.why(d)
            if res.status:
                res.status[d] = "failed"
        taken |= check.mask


def fit(readings: ArrayLike, references: ArrayLike | None = None, model: str | int = "12", *, units: str = "g",
        counts_per_g: ArrayLike | None = None, gravity_mps2: float | None = None,
        noise: ArrayLike | None = None, norm_g: float = 1.0) -> FitResult:
    """Fit one board: readings (P, 3) in ``units``; returns a FitResult (``norm_g`` as fit_batch's).

    Raises UnderdeterminedError, naming what is missing, when the poses cannot
    determine the model; never returns NaN coefficients.
    """
    x = np.asarray(readings, dtype=float)
    if x.ndim != 2 or x.shape[-1] != 3:
        raise DataError(f"readings must have shape (poses, 3); got {x.shape}")
    ref = None if references is None else np.asarray(references, dtype=float)[None]
    nz = None if noise is None else np.asarray(noise, dtype=float)[None]
    b = fit_batch(x[None], ref, model, units=units, counts_per_g=counts_per_g,
                  gravity_mps2=gravity_mps2, noise=nz, norm_g=norm_g)
    if not b.ok[0]:
        raise UnderdeterminedError(b.messages[0])
    fr = b.result(0)
    if fr.held:  # the stored calibration says what it did not estimate (zero variance: held, not fitted)
        fr.calibration.metadata["held"] = [h.to_json() for h in fr.held]
    return fr


def fit_session(session: Session, model: str | int = "12") -> FitResult:
    """Fit a Session (references from the session; std/n give the noise).  Model 9's norm is the
    session's site gravity in standard g (the references of the others are scaled to it already)."""
    if len(session) == 0:
        raise DataError("the session has no poses")
    noise = session.noise()  # input units: works for scale-less counts (model 9) too
    nine = str(model) == "9"
    return fit(session.readings, None if nine else session.references_g, model,
               units=session.units, counts_per_g=session.counts_per_g,
               gravity_mps2=session.gravity_mps2, noise=noise, norm_g=session.site_gravity_g if nine else 1.0)


def fit_temperature(session: Session, model: str | int = "12", method: str = "linear",
                    tolerance_c: float = 2.0) -> tuple[Calibration, list[tuple[float, FitResult]]]:
    """Fit at each calibration temperature and build a temperature table (AN4399 section 9).

    Poses are grouped by temp_c (within ``tolerance_c``); each group is fitted on its own
    and every parameter is then interpolated ``linear``-ly or by a ``quadratic``.
    """
    groups = session.by_temperature(tolerance_c)
    if len(groups) < 2:
        raise UnderdeterminedError(
            f"temperature calibration needs poses at two or more temperatures; found {len(groups)} "
            f"(grouping within {tolerance_c:g} C)")
    fits = []
    for t, sub in groups:
        try:
            fits.append((t, fit_session(sub, model)))
        except UnderdeterminedError as e:
            raise UnderdeterminedError(f"at {t:g} C: {e}") from None
    first = fits[0][1].calibration
    # model 9 on counts estimates input_per_g per group: bring every group's W and Gamma
    # to the first group's scale, since the table is applied with that one scale
    ratio = [first.input_per_g / f.calibration.input_per_g for _, f in fits]
    table = TemperatureTable([t for t, _ in fits], [f.W * r for (_, f), r in zip(fits, ratio, strict=True)],
                             [f.V for _, f in fits], [f.Gamma * r**3 for (_, f), r in zip(fits, ratio, strict=True)],
                             method)
    cal = Calibration(str(model), table.W[0], table.V[0], table.Gamma[0], first.input_units,
                      first.input_per_g, temperature=table)
    return cal, fits


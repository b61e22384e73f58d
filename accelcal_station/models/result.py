"""Fit results: one object per fit (scipy.optimize style), one per batch of boards."""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, NotRequired, TypedDict

import numpy as np

from ..calibration import Calibration
from ..jsontypes import JsonObject


@dataclass(frozen=True)
class Held:
    """A term fitted at its nominal value because the poses do not determine it (models/held.py)."""

    term: str  # parameter name, e.g. "M_xy"
    value: float  # the nominal value it is held at
    reason: str
    hint: str

    @property
    def text(self) -> str:
        return f"{self.reason}; {self.hint}"

    def to_json(self) -> JsonObject:
        return {"term": self.term, "value": self.value, "reason": self.reason, "hint": self.hint}


class PoseRow(TypedDict):
    """One pose of a fit as JSON: its reading, residual (reference - calibrated) and norm error, in g
    (``temp_c``: a fit at several temperatures names each row's, first)."""

    temp_c: NotRequired[float | None]
    pose: str
    reading_g: list[float]
    residual_g: list[float]
    norm_error_g: float


class FitCore(TypedDict):
    """What a fit's JSON gives at one temperature and a table fit's at several alike (FitJson, and
    cli/fit's TableFitJson); ``poses`` may be a stand-in the caller replaces."""

    model: str
    pose_count: int
    W: list[list[float]]
    V: list[float]
    Gamma: list[float]
    P: list[float]
    residual_rms_g: float
    residual_max_g: float
    crossval_rms_g: float | None
    poses: list[PoseRow] | str


class FitJson(FitCore):
    """A fit as JSON (FitResult.to_json_dict)."""

    params: dict[str, float]
    stderr: dict[str, list[float] | list[list[float]]] | None
    crossval_by_orientation_rms_g: float | None
    distinct_orientations: int | None
    condition_number: float
    success: bool
    status: str
    message: str
    nfev: int
    input_units: str
    input_per_g: float
    held: list[JsonObject]
    freed: list[JsonObject]


@dataclass
class FitResult:
    """Everything a fit says about one board.

    residuals_g: (P, 3) reference minus calibrated output, per pose and axis, in g
      (model 9: calibrated output minus its projection on the unit sphere).
    norm_error_g: (P,) |calibrated| - 1 g per pose.
    P: (3,) per-channel sum of squared residuals (AN4399 Eqn 45; g^2).
    stderr: standard errors of W, V, Gamma (same shapes), or None where the data
      cannot say (an exact fit with no per-pose noise given).
    crossval_rms_g: leave-one-pose-out RMS (model 9: RMS norm error of each
      left-out pose), or None when leaving a pose out leaves the model undetermined.
    crossval_by_orientation_rms_g: the same with every pose of one distinct orientation left
      out at a time (models/crossval.py); equal to crossval_rms_g when no orientation repeats.
    distinct_orientations: distinct orientations among the poses (None: not counted).
    """

    model: str
    calibration: Calibration
    pose_count: int
    readings_g: np.ndarray
    residuals_g: np.ndarray
    norm_error_g: np.ndarray
    P: np.ndarray
    residual_rms_g: float
    residual_max_g: float
    stderr: dict[str, np.ndarray] | None
    covariance: np.ndarray | None
    condition_number: float
    crossval_rms_g: float | None
    crossval_residuals_g: np.ndarray | None
    params: np.ndarray
    param_names: list[str]
    success: bool = True
    status: str = "ok"
    message: str = ""
    nfev: int = 1
    held: list[Held] = field(default_factory=list)  # terms held at nominal: the poses do not determine them
    freed: list[Held] = field(default_factory=list)  # noise-rule holds the held-out data overruled: fitted
    crossval_by_orientation_rms_g: float | None = None
    distinct_orientations: int | None = None

    @property
    def orientations_repeat(self) -> bool:
        """Some orientation is revisited: the by-orientation figure is the held-out one to judge by."""
        return self.distinct_orientations is not None and self.distinct_orientations < self.pose_count

    @property
    def acceptance_crossval_rms_g(self) -> float | None:
        """The held-out figure acceptance judges: by orientation where orientations repeat, else
        leave-one-pose-out (the same figure then)."""
        return self.crossval_by_orientation_rms_g if self.orientations_repeat else self.crossval_rms_g

    @property
    def W(self) -> np.ndarray:
        return self.calibration.W

    @property
    def V(self) -> np.ndarray:
        return self.calibration.V

    @property
    def Gamma(self) -> np.ndarray:
        return self.calibration.Gamma

    def pose_rows(self, pose_names: list[str] | None = None, start: int = 0, stop: int | None = None
                  ) -> list[PoseRow]:
        """The JSON rows of poses ``start:stop`` (a large table is written a block of rows at a time)."""
        names = pose_names or [str(i) for i in range(self.pose_count)]
        r, e, n = self.readings_g[start:stop].tolist(), self.residuals_g[start:stop].tolist(), \
            self.norm_error_g[start:stop].tolist()
        return [{"pose": names[start + i], "reading_g": r[i], "residual_g": e[i], "norm_error_g": n[i]}
                for i in range(len(n))]

    def to_json_dict(self, pose_names: list[str] | None = None, poses: str | None = None) -> FitJson:
        """The fit as JSON; ``poses`` given stands for the per-pose rows (``pose_rows``), else they are built."""
        rows = self.pose_rows(pose_names) if poses is None else poses
        se = None
        if self.stderr is not None:
            se = {k: np.asarray(v).tolist() for k, v in self.stderr.items()}
        return {
            "model": self.model,
            "pose_count": self.pose_count,
            "W": self.W.tolist(),
            "V": self.V.tolist(),
            "Gamma": self.Gamma.tolist(),
            "params": dict(zip(self.param_names, self.params.tolist(), strict=True)),
            "stderr": se,
            "P": self.P.tolist(),
            "residual_rms_g": self.residual_rms_g,
            "residual_max_g": self.residual_max_g,
            "crossval_rms_g": self.crossval_rms_g,
            "crossval_by_orientation_rms_g": self.crossval_by_orientation_rms_g,
            "distinct_orientations": self.distinct_orientations,
            "condition_number": self.condition_number,
            "success": self.success,
            "status": self.status,
            "message": self.message,
            "nfev": self.nfev,
            "input_units": self.calibration.input_units,
            "input_per_g": self.calibration.input_per_g,
            "held": [h.to_json() for h in self.held],
            "freed": [h.to_json() for h in self.freed],
            "poses": rows,
        }


class LazyCovariance(ABC):
    """A (D, ...) covariance stored as a few arrays and formed per board on indexing (the
    stacked fitters' BatchFit.covariance); the arrays are named in ``_fields``, which the
    lot assembler copies."""

    _fields: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(getattr(self, self._fields[0]))

    @abstractmethod
    def __getitem__(self, d: Any) -> np.ndarray:
        """The covariance of board(s) ``d``, formed from the stored arrays (each fitter's own form)."""


@dataclass
class BatchFit:
    """Stacked fits of D boards; ``ok[d]`` False marks a board that could not be fitted."""

    model: str
    W: np.ndarray  # (D, 3, 3)
    V: np.ndarray  # (D, 3)
    Gamma: np.ndarray  # (D, 3)
    residuals_g: np.ndarray  # (D, P, 3)
    norm_error_g: np.ndarray  # (D, P)
    P: np.ndarray  # (D, 3)
    residual_rms_g: np.ndarray  # (D,)
    crossval_rms_g: np.ndarray  # (D,), NaN where not computable (see crossval_ok)
    crossval_ok: np.ndarray  # (D,) bool
    condition_number: np.ndarray  # (D,)
    stderr_W: np.ndarray  # (D, 3, 3)
    stderr_V: np.ndarray  # (D, 3)
    stderr_Gamma: np.ndarray  # (D, 3)
    stderr_ok: np.ndarray  # (D,) bool
    covariance: np.ndarray | LazyCovariance  # model specific, (D, ...)
    params: np.ndarray  # (D, k)
    param_names: list[str]
    ok: np.ndarray  # (D,) bool
    messages: list[str]
    readings_g: np.ndarray  # (D, P, 3)
    input_units: str = "g"
    input_per_g: np.ndarray | float = 1.0
    nfev: np.ndarray | None = None
    status: list[str] | None = None
    held: list[list[Held]] = field(default_factory=list)  # (D,) each board's terms held at nominal
    freed: list[list[Held]] = field(default_factory=list)  # (D,) holds the held-out data overruled (models/held.py)
    crossval_by_orientation_rms_g: np.ndarray | None = None  # (D,), NaN where not computable
    crossval_by_orientation_ok: np.ndarray | None = None  # (D,) bool
    distinct_orientations: np.ndarray | None = None  # (D,) int
    # (D,) bool: every two poses certified more than 5 deg apart (models/screening.py; False: not certified)
    poses_apart: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not self.held:  # the fitters leave it empty: nothing held on any board
            # one shared empty list (a board's terms are replaced, never appended to): no D small
            # objects for the garbage collector to walk on every chunk
            self.held = [[]] * len(self.ok)
        if not self.freed:
            self.freed = [[]] * len(self.ok)

    def __len__(self) -> int:
        return len(self.ok)

    def result(self, d: int) -> FitResult:
        """The FitResult of board ``d`` (identical to fitting that board alone)."""
        per_g = float(np.broadcast_to(self.input_per_g, (len(self),))[d])
        cal = Calibration(self.model, self.W[d], self.V[d], self.Gamma[d], self.input_units, per_g)
        res = self.residuals_g[d]
        stderr = None
        if self.stderr_ok[d]:
            stderr = {"W": self.stderr_W[d], "V": self.stderr_V[d], "Gamma": self.stderr_Gamma[d]}
        return FitResult(
            model=self.model,
            calibration=cal,
            pose_count=res.shape[0],
            readings_g=self.readings_g[d],
            residuals_g=res,
            norm_error_g=self.norm_error_g[d],
            P=self.P[d],
            residual_rms_g=float(self.residual_rms_g[d]),
            residual_max_g=float(np.max(np.abs(res))) if res.size else 0.0,
            stderr=stderr,
            covariance=self.covariance[d] if self.stderr_ok[d] else None,
            condition_number=float(self.condition_number[d]),
            crossval_rms_g=float(self.crossval_rms_g[d]) if self.crossval_ok[d] else None,
            crossval_residuals_g=None,
            params=self.params[d],
            param_names=self.param_names,
            success=bool(self.ok[d]),
            status=self.status[d] if self.status else ("ok" if self.ok[d] else "failed"),
            message=self.messages[d],
            nfev=int(self.nfev[d]) if self.nfev is not None else 1,
            held=list(self.held[d]),
            freed=list(self.freed[d]),
            crossval_by_orientation_rms_g=_orient(self, d),
            distinct_orientations=None if self.distinct_orientations is None else int(self.distinct_orientations[d]),
        )


def _orient(b: BatchFit, d: int) -> float | None:
    if b.crossval_by_orientation_rms_g is None or b.crossval_by_orientation_ok is None:
        return None
    return float(b.crossval_by_orientation_rms_g[d]) if b.crossval_by_orientation_ok[d] else None

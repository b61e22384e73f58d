"""A calibration: the AN4399 form ``G = W G_f + V + Gamma G_f^3`` (AN4399 Eqns 35, 67).

``G_f`` is the uncalibrated reading in g (input divided by ``input_per_g``); ``G`` is
the calibrated specific force in g.  Every model (6, 9, 12, 15 parameters) reports its
result in this one form so any calibration can be applied, stored and compared alike.
A calibration may carry a temperature table (AN4399 section 9): then W, V and Gamma
are interpolated to the temperature of the data.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np
from numpy.typing import ArrayLike

from .conventions import check_units, units_per_g
from .errors import DataError, TemperatureRangeError, UnitsError
from .jsontypes import JsonObject, JsonValue

SCHEMA = "accelcal.calibration"
# The format version this writes. Every version ever shipped keeps a reader in _READERS (as imucal
# keeps its legacy loaders), so a file from any older accelcal still loads; a newer one is refused
# in one line naming both versions. Shipped: 1 (since the first release; still current).
SCHEMA_VERSION = 1
MODELS = ("6", "9", "12", "15")
MAX_FILE_BYTES = 1 << 20
MAX_TEMPERATURES = 1000  # calibration temperatures of one table: a chamber visits tens


@dataclass(init=False)
class TemperatureTableDict(TypedDict):
    """An AN4399 section 9 table as JSON: every parameter at each temperature."""

    method: str
    temps_c: list[float]
    W: list[list[list[float]]]
    V: list[list[float]]
    Gamma: list[list[float]]


class CalibrationDict(TypedDict):
    """A calibration file's JSON object (format SCHEMA_VERSION): what ``to_dict`` writes."""

    schema: str
    version: int
    model: str
    input_units: str
    input_per_g: float
    W: list[list[float]]
    V: list[float]
    Gamma: list[float]
    temperature: TemperatureTableDict | None
    metadata: JsonObject  # free-form: who, where, which fit; keys differ by writer and version


class TemperatureTable:
    """Per-temperature AN4399 coefficients and how to interpolate them (AN4399 Eqns 83-92).

    ``method`` is ``linear`` (piecewise linear between calibration temperatures) or
    ``quadratic`` (exact through three temperatures, least squares through more).
    """

    temps_c: np.ndarray  # (K,)
    W: np.ndarray  # (K, 3, 3)
    V: np.ndarray  # (K, 3)
    Gamma: np.ndarray  # (K, 3)
    method: str = "linear"

    def __init__(self, temps_c: ArrayLike, W: ArrayLike, V: ArrayLike, Gamma: ArrayLike, method: str = "linear"):
        temps = np.asarray(temps_c, dtype=float)
        k = temps.size
        if temps.ndim != 1 or not 0 < k <= MAX_TEMPERATURES:
            raise DataError(f"temperature table temps_c: shape {temps.shape}; allowed: a list of 2 to "
                            f"{MAX_TEMPERATURES} temperatures")
        arrays = {n: np.asarray(a, dtype=float) for n, a in (("W", W), ("V", V), ("Gamma", Gamma))}
        for n, shape in (("W", (k, 3, 3)), ("V", (k, 3)), ("Gamma", (k, 3))):
            if arrays[n].shape != shape:
                raise DataError(f"temperature table {n}: shape {arrays[n].shape}; allowed {shape}, one per temperature")
        if not all(np.all(np.isfinite(a)) for a in (temps, *arrays.values())):
            raise DataError("temperature table: NaN or infinity among its temperatures or coefficients")
        order = np.argsort(temps)
        self.temps_c = temps[order]
        self.W, self.V, self.Gamma = (arrays[n][order] for n in ("W", "V", "Gamma"))
        self.method = method
        if self.method not in ("linear", "quadratic"):
            raise DataError(f"temperature method {self.method!r}; allowed: linear, quadratic")
        if k < 2:
            raise DataError("a temperature table needs calibrations at two or more temperatures")
        if np.any(np.diff(self.temps_c) <= 0):
            raise DataError(f"temperatures {self.temps_c.tolist()} repeat; each must be distinct")
        if self.method == "quadratic" and k < 3:
            raise DataError("quadratic temperature interpolation needs three or more temperatures")

    @property
    def range_c(self) -> tuple[float, float]:
        return float(self.temps_c[0]), float(self.temps_c[-1])

    def _params(self) -> np.ndarray:
        return np.concatenate([self.W.reshape(len(self.temps_c), 9), self.V, self.Gamma], axis=1)

    def interpolate(self, temp_c: ArrayLike, extrapolate: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """W, V, Gamma at each temperature; shapes (..., 3, 3), (..., 3), (..., 3)."""
        t = np.asarray(temp_c, dtype=float)
        if not np.all(np.isfinite(t)):
            raise DataError("temperature is NaN or infinite")
        lo, hi = self.range_c
        if not extrapolate and (np.any(t < lo - 1e-9) or np.any(t > hi + 1e-9)):
            bad = t[(t < lo) | (t > hi)].ravel()[0]
            raise TemperatureRangeError(
                f"temperature {bad:g} C is outside the calibrated range {lo:g} to {hi:g} C; "
                "pass extrapolate=True (--extrapolate) to extrapolate deliberately"
            )
        params = self._params()  # (K, 15)
        if self.method == "quadratic":
            coef = quadratic_coefficients(self.temps_c, params)  # (3, 15)
            out = coef[0] + coef[1] * t[..., None] + coef[2] * t[..., None] ** 2
        else:
            flat = t.ravel()
            out = np.empty((flat.size, params.shape[1]))
            for j in range(params.shape[1]):
                # np.interp clamps; linear extrapolation is done by hand when asked
                out[:, j] = np.interp(flat, self.temps_c, params[:, j])
                if extrapolate:
                    lo_s = (params[1, j] - params[0, j]) / (self.temps_c[1] - self.temps_c[0])
                    hi_s = (params[-1, j] - params[-2, j]) / (self.temps_c[-1] - self.temps_c[-2])
                    out[:, j] += np.where(flat < lo, (flat - lo) * lo_s, 0.0)
                    out[:, j] += np.where(flat > hi, (flat - hi) * hi_s, 0.0)
            out = out.reshape(t.shape + (params.shape[1],))
        W = out[..., :9].reshape(t.shape + (3, 3))
        return W, out[..., 9:12], out[..., 12:15]

    def to_dict(self) -> TemperatureTableDict:
        return {
            "method": self.method,
            "temps_c": self.temps_c.tolist(),
            "W": self.W.tolist(),
            "V": self.V.tolist(),
            "Gamma": self.Gamma.tolist(),
        }

    @classmethod
    def from_dict(cls, d: JsonObject | TemperatureTableDict) -> TemperatureTable:
        """A table from its JSON object (numbers checked by the constructor)."""
        return cls(_numbers(d["temps_c"]), _numbers(d["W"]), _numbers(d["V"]), _numbers(d["Gamma"]),
                   _name(d.get("method", "linear"), "temperature method"))


def quadratic_coefficients(temps_c: ArrayLike, values: ArrayLike) -> np.ndarray:
    """alpha, beta, gamma with ``value(T) = alpha + beta T + gamma T^2`` (AN4399 Eqns 83-92).

    Exact through three temperatures; least squares through more.  ``values`` has
    shape (K,) or (K, m); the result has shape (3,) or (3, m).
    """
    t = np.asarray(temps_c, dtype=float)
    y = np.asarray(values, dtype=float)
    A = np.stack([np.ones_like(t), t, t**2], axis=1)
    if len(t) == 3:
        return np.linalg.solve(A, y)
    return np.linalg.lstsq(A, y, rcond=None)[0]


@dataclass
class Calibration:
    """A calibration in AN4399 form that applies itself to data in known units.

    ``input_units`` and ``input_per_g`` say what the coefficients were fitted on:
    ``G_f = input / input_per_g``.  For counts that is ``counts_per_g``.
    """

    model: str
    W: np.ndarray
    V: np.ndarray
    Gamma: np.ndarray = field(default_factory=lambda: np.zeros(3))
    input_units: str = "g"
    input_per_g: float = 1.0
    temperature: TemperatureTable | None = None
    metadata: JsonObject = field(default_factory=dict)  # free-form (CalibrationDict)

    def __post_init__(self) -> None:
        self.model = str(self.model)
        if self.model not in MODELS:
            raise DataError(f"model {self.model!r}; allowed: {', '.join(MODELS)}")
        self.W = np.asarray(self.W, dtype=float).reshape(3, 3)
        self.V = np.asarray(self.V, dtype=float).reshape(3)
        self.Gamma = np.asarray(self.Gamma, dtype=float).reshape(3)
        check_units(self.input_units)
        if not (np.all(np.isfinite(self.W)) and np.all(np.isfinite(self.V)) and np.all(np.isfinite(self.Gamma))):
            raise DataError("calibration coefficients contain NaN or infinity")
        if not (np.isfinite(self.input_per_g) and self.input_per_g > 0):
            raise DataError(f"input_per_g {self.input_per_g} must be positive")

    @classmethod
    def identity(cls, input_units: str = "g", input_per_g: float = 1.0) -> Calibration:
        return cls("12", np.eye(3), np.zeros(3), np.zeros(3), input_units, input_per_g)

    @property
    def counts_per_g(self) -> float | None:
        return self.input_per_g if self.input_units == "counts" else None

    def coefficients(self, temp_c: ArrayLike | None = None, extrapolate: bool = False
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """W, V, Gamma (at ``temp_c`` when the calibration has a temperature table)."""
        if self.temperature is None:
            return self.W, self.V, self.Gamma
        if temp_c is None:
            raise UnitsError(
                "this calibration depends on temperature; give the temperature of the data (temp_c)"
            )
        return self.temperature.interpolate(temp_c, extrapolate=extrapolate)

    def apply(self, values: ArrayLike, units: str, *, counts_per_g: float | None = None,
              gravity_mps2: float | None = None, temp_c: ArrayLike | None = None,
              extrapolate: bool = False) -> np.ndarray:
        """Calibrated specific force in g of readings ``values`` (..., 3) in ``units``.

        ``units`` is required: the calibration refuses to guess.  Counts use the
        calibration's own ``counts_per_g`` unless one is given, and a different one
        is refused (the coefficients would be wrong by the ratio); m/s^2 likewise
        use the calibration's own gravity unless ``gravity_mps2`` is given.
        """
        check_units(units)
        x = np.asarray(values, dtype=float)
        if x.shape[-1] != 3:
            raise DataError(f"readings must have 3 columns (x, y, z); got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise DataError("readings contain NaN or infinity")
        if units == "counts":
            own = self.counts_per_g
            if counts_per_g is None and own is None:
                raise UnitsError(f"calibration was fitted in {self.input_units}; counts need counts_per_g")
            if counts_per_g is not None and own is not None and not np.isclose(counts_per_g, own):
                raise UnitsError(
                    f"calibration was fitted at {own:g} counts/g; data given at {counts_per_g:g} counts/g"
                )
            scale = own if counts_per_g is None else float(counts_per_g)
        else:
            if units == "mps2" and gravity_mps2 is None and self.input_units == "mps2":
                gravity_mps2 = self.input_per_g  # the local gravity it was fitted with, as for counts
            scale = units_per_g(units, gravity_mps2=gravity_mps2)
        gf = x / scale
        W, V, G = self.coefficients(temp_c, extrapolate)
        W = np.asarray(W)
        return np.einsum("...ij,...j->...i", W, gf) + V + G * gf**3

    # -- versioned JSON (imucal style) -------------------------------------------------
    def to_dict(self) -> CalibrationDict:
        return {
            "schema": SCHEMA,
            "version": SCHEMA_VERSION,
            "model": self.model,
            "input_units": self.input_units,
            "input_per_g": self.input_per_g,
            "W": self.W.tolist(),
            "V": self.V.tolist(),
            "Gamma": self.Gamma.tolist(),
            "temperature": None if self.temperature is None else self.temperature.to_dict(),
            "metadata": self.metadata,
        }

    @classmethod
    def from_dict(cls, d: JsonObject | CalibrationDict, source: str = "calibration") -> Calibration:
        """A calibration from its JSON object, in any format version up to SCHEMA_VERSION."""
        if not isinstance(d, dict) or d.get("schema") != SCHEMA:
            raise DataError(f"{source}: not an accelcal calibration (missing schema {SCHEMA!r})")
        reader = _READERS[format_version(d, source)]  # only versions with a reader come back
        try:
            return reader(d)
        except KeyError as e:
            raise DataError(f"{source}: missing key {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            raise DataError(f"{source}: malformed calibration ({e})") from None

    def save(self, path: str | Path) -> None:
        """Write JSON atomically (temporary file then rename): never a half-written file."""
        from .atomic import atomic_write

        atomic_write(Path(path), json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """A calibration JSON file (a regular file of at most MAX_FILE_BYTES); errors name the file."""
        from .fileguard.jsondoc import read_json

        d = read_json(path, "an accelcal calibration", MAX_FILE_BYTES, "a calibration with a table of 100 "
                      "temperatures is some 50 kB")
        return cls.from_dict(d, str(path))


def format_version(d: JsonObject | CalibrationDict, source: str = "calibration") -> int:
    """The file's format version, checked: newer than this accelcal reads is one clear line."""
    v = d.get("version")
    if isinstance(v, bool) or not isinstance(v, int):
        raise DataError(f"{source}: calibration version {v!r}; allowed: a whole number 1 to {SCHEMA_VERSION}")
    if v > SCHEMA_VERSION:
        raise DataError(f"{source}: written by a newer accelcal (calibration format version {v}); this accelcal "
                        f"reads up to version {SCHEMA_VERSION}: read it with a newer accelcal-station")
    if v not in _READERS:
        raise DataError(f"{source}: calibration version {v}; no accelcal wrote it (versions 1 to {SCHEMA_VERSION})")
    return v


def _read_v1(d: JsonObject | CalibrationDict) -> Calibration:
    """Format 1: W (3 x 3), V, Gamma (absent: zeros), input units and per-g scale, an optional
    AN4399 section 9 table, metadata."""
    temp = d.get("temperature")
    if temp is not None and not isinstance(temp, dict):
        raise TypeError(f"temperature: {type(temp).__name__}; allowed: a table (temps_c, W, V, Gamma) or null")
    meta = d.get("metadata", {})
    if not isinstance(meta, dict):
        raise TypeError(f"metadata: {type(meta).__name__}; allowed: an object")
    return Calibration(
        model=str(d["model"]), W=_numbers(d["W"]), V=_numbers(d["V"]), Gamma=_numbers(d.get("Gamma", [0, 0, 0])),
        input_units=_name(d["input_units"], "input_units"), input_per_g=_float(d["input_per_g"]),
        temperature=None if temp is None else TemperatureTable.from_dict(temp),
        metadata=meta,
    )


def _numbers(v: JsonValue | list[float] | list[list[float]] | list[list[list[float]]]) -> np.ndarray:
    """A JSON list of numbers (nested) as floats; ValueError/TypeError otherwise (from_dict's one line)."""
    return np.asarray(v, dtype=float)


def _float(v: JsonValue) -> float:
    if isinstance(v, str | int | float):  # as float() of the JSON value: "4096" is read as before
        return float(v)
    raise TypeError(f"float() argument must be a string or a real number, not '{type(v).__name__}'")


def _name(v: JsonValue, what: str) -> str:
    if not isinstance(v, str):
        raise TypeError(f"{what}: {v!r}; allowed: a name")
    return v


# one reader per format version ever shipped; a new version adds its reader and keeps the old ones
_READERS: dict[int, Callable[[JsonObject | CalibrationDict], Calibration]] = {1: _read_v1}


PARAM_NAMES = ([f"W{i}{j}" for i in range(3) for j in range(3)] + [f"V{i}" for i in range(3)]
               + [f"Gamma{i}" for i in range(3)])


def param_vector(cal: Mapping[str, object]) -> np.ndarray:
    """W (row major), V, Gamma of a calibration dict as 15 numbers, PARAM_NAMES order."""
    return np.concatenate([np.asarray(cal["W"], float).ravel(), np.asarray(cal["V"], float),
                           np.asarray(cal.get("Gamma", [0, 0, 0]), float)])

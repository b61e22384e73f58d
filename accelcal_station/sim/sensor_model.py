"""The simulated accelerometer: the effects catalog and the forward model to raw counts.

Conventions.  A chip reads the specific force: +1 g on the axis pointing away from the
Earth (MMA8451Q data sheet "Product orientation"; MPU-6050 product specification), so a
flat board, component side up, reads +1 g on z; a commanded pose places the board with its
``PoseSpec.reference_g`` pointing up, and that is its ideal output (docs/conventions.md).
Inside the model, specific force is in *standard* g (9.80665 m/s^2), the unit the
chip's sensitivity is specified in.  A calibration fitted against unit pose
references targets the *local* 1 g instead; the two differ only when the
``gravity`` effect is enabled.

The sensor chain, in order (each stage only when its effect is enabled):

1. true specific force  ``f = (local_g / 9.80665) * mount @ attitude.T @ up``, the board's
   attitude in the world (``R_err @ reference_g`` for a pose placed with ``reference_g`` up;
   ``gravity``; ``pose_error`` gives ``R_err``, applied by the board / jig)
2. linear response      ``u = K(T) f``, ``K = diag(gain(T)) (I + C) R_pkg^T``
   (``gain``, ``cross_axis``: coupling ``C`` and package rotation ``R_pkg``)
3. nonlinearity         the reading ``G`` solves ``f = K^-1 (G - o(T)) - q G^2 - c G^3``
   per axis (``quadratic`` q, ``cubic`` c): the inverse of AN4399 Eqn 67 with
   ``Gamma = -c``, so model 15 inverts ``cubic`` exactly; with ``simulator.physics:
   forward`` (``SensorModel.forward``) instead ``G = o + u + q u^2 + c u^3``, u = K f
   (a sensor's own response, which model 15 only approximates)
4. offset               ``o(T)`` in step 3 (``offset``); ``temperature`` makes offset and
   gain linear + quadratic in ``T - t_ref_c``
5. drift                + offset random walk and exponential warm-up (time since power-up)
6. settling             + ``fraction * (step of f) * exp(-(t - t_step) / tau_s)`` after each change
7. noise                + ``density * sqrt(ENBW)`` per sample; ENBW = ODR/2 (MMA8451) or
                        (pi/2) x the DLPF_CFG bandwidth, the one-pole filter's (MPU6050).
                        MPU6050: the DLPF makes the noise a one-pole low-pass process
                        sampled at the ODR, lag-k autocorrelation ``exp(-2 pi f_c k / ODR)``
                        (f_c the DLPF_CFG bandwidth), and the signal lags by the data
                        sheet's DLPF delay.  MMA8451: the oversampling mode (CTRL_REG2
                        MODS) averages OSR conversions per output sample in non-overlapping
                        blocks: independent samples, density scaled by
                        sqrt(OSR_normal / OSR_mode) (``ChipSpec.noise_scale``)
8. counts               ``* counts_per_g`` (the chip's nominal sensitivity at its range)
9. saturation           clip at the chip's code range (``full_scale_fraction`` of it)
10. quantization        round to multiples of ``lsb_counts`` (integer counts)

Stages 1, 5 and 6 need state (orientation, time) and live in
:class:`accelcal_station.drivers.simulated.SimulatedBoard`; this module holds the
catalog, its YAML schema, the chip datasheet defaults and the stateless physics.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache
from typing import Annotated, Any, TypeAlias

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field, StrictBool, create_model

from ..calibration import Calibration
from ..config.parts import parse
from ..config.schema import Section
from ..conventions import STANDARD_GRAVITY_MPS2
from ..errors import ConfigError
from .chips import CHIPS as CHIPS  # re-exported: the model's callers name the chips through it
from .chips import ChipSpec as ChipSpec
from .chips import get_chip as get_chip

# -- the effects catalog -----------------------------------------------------------------

CHIP_DEFAULT = "chip"  # a parameter default taken from the chip's datasheet


@dataclass(frozen=True)
class Param:
    """One parameter of an effect: name, unit, shape ((), (3,) per axis, (3, 3)), range."""

    name: str
    unit: str
    doc: str
    default: Any
    shape: tuple[int, ...] = ()
    lo: float | None = None
    hi: float | None = None
    integer: bool = False


@dataclass(frozen=True)
class EffectSpec:
    name: str
    doc: str
    params: tuple[Param, ...] = ()

    def param(self, name: str) -> Param:
        return next(p for p in self.params if p.name == name)


_V0 = [0.0, 0.0, 0.0]
_M0 = [[0.0] * 3 for _ in range(3)]

EFFECTS: dict[str, EffectSpec] = {e.name: e for e in (
    EffectSpec("offset", "zero-g offset per axis, added to the reading", (
        Param("offset_mg", "mg", "zero-g offset at t_ref_c", _V0, (3,), -2000.0, 2000.0),)),
    EffectSpec("gain", "sensitivity per axis relative to the chip's nominal counts_per_g", (
        Param("gain", "1", "reading per unit specific force (1 = nominal)", [1.0, 1.0, 1.0], (3,), 0.5, 1.5),)),
    EffectSpec("cross_axis", "off-diagonal coupling C and package rotation: K = diag(gain) (I + C) R_pkg^T", (
        Param("coupling", "1", "C[i][j]: fraction of axis j's force read on axis i; diagonal must be 0",
              _M0, (3, 3), -0.2, 0.2),
        Param("rotation_deg", "deg", "package rotation vector (axis * angle) of the chip on the board",
              _V0, (3,), -10.0, 10.0))),
    EffectSpec("cubic", "odd nonlinearity per axis: f = K^-1 (G - o) - c G^3 (AN4399 Eqn 67, Gamma = -c)", (
        Param("cubic_per_g2", "1/g^2", "c: cubic coefficient of the reading G (g)", _V0, (3,), -0.05, 0.05),)),
    EffectSpec("quadratic", "even nonlinearity per axis: f = K^-1 (G - o) - q G^2 (no model inverts it)", (
        Param("quadratic_per_g", "1/g", "q: square coefficient of the reading G (g)", _V0, (3,), -0.05, 0.05),)),
    EffectSpec("temperature", "offset and gain linear and quadratic in (T - t_ref_c)", (
        Param("t_ref_c", "C", "temperature at which offset and gain take their configured values",
              25.0, (), -40.0, 125.0),
        Param("offset_mg_per_c", "mg/C", "linear offset coefficient", _V0, (3,), -10.0, 10.0),
        Param("offset_mg_per_c2", "mg/C^2", "quadratic offset coefficient", _V0, (3,), -1.0, 1.0),
        Param("gain_ppm_per_c", "ppm/C", "linear gain coefficient", _V0, (3,), -2000.0, 2000.0),
        Param("gain_ppm_per_c2", "ppm/C^2", "quadratic gain coefficient", _V0, (3,), -100.0, 100.0))),
    EffectSpec("pose_error", "the jig's true orientation differs from the commanded one: R_err = R_jig R_scatter", (
        Param("jig_rotation_deg", "deg", "fixed rotation vector of the jig relative to its nominal frame",
              _V0, (3,), -20.0, 20.0),
        Param("scatter_deg", "deg", "rms per-axis rotation drawn afresh at every pose presentation",
              0.0, (), 0.0, 10.0))),
    EffectSpec("gravity", "local gravity differs from standard gravity: |f| = local_mps2 / 9.80665 standard g", (
        Param("local_mps2", "m/s^2", "local gravity", STANDARD_GRAVITY_MPS2, (), 9.7, 9.9),)),
    EffectSpec("noise", "white noise, per-sample sigma = density * sqrt(ENBW)", (
        Param("density_ug_per_rthz", "ug/sqrt(Hz)", "noise density per axis (default: the chip's datasheet)",
              CHIP_DEFAULT, (3,), 0.0, 1e5),)),
    EffectSpec("quantization", "round to integer counts, in steps of lsb_counts", (
        Param("lsb_counts", "counts", "quantization step (1 = the chip's full resolution)", 1, (), 1, 2**12,
              integer=True),)),
    EffectSpec("saturation", "clip at the chip's output code range", (
        Param("full_scale_fraction", "1", "fraction of the code range at which the output clips",
              1.0, (), 0.01, 1.0),)),
    EffectSpec("drift", "offset random walk plus exponential warm-up since power-up", (
        Param("random_walk_ug_per_rts", "ug/sqrt(s)", "offset random walk: std after t seconds is this * sqrt(t)",
              _V0, (3,), 0.0, 1e5),
        Param("warmup_mg", "mg", "warm-up offset reached as t -> infinity: A (1 - exp(-t / tau))",
              _V0, (3,), -500.0, 500.0),
        Param("warmup_tau_s", "s", "warm-up time constant", 60.0, (), 1e-3, 1e6))),
    EffectSpec("settling", "transient after each change of the true force, decaying exponentially", (
        Param("fraction", "1", "transient amplitude as a fraction of the step (> 0 overshoot, < 0 lag)",
              0.0, (), -1.0, 1.0),
        Param("tau_s", "s", "decay time constant", 0.2, (), 1e-4, 1e3))),
)}

EFFECT_NAMES: tuple[str, ...] = tuple(EFFECTS)
# simulator.physics: how stage 3's nonlinearity acts (SensorModel.forward); the first is the default
PHYSICS = ("implicit", "forward")
DEFAULT_EFFECTS = ("noise", "quantization", "saturation")  # an ideal chip: datasheet behaviour only


def _param_type(p: Param) -> Any:
    """A parameter's declared type: a number in [lo, hi]; per axis, one number for all three or
    [x, y, z]; a 3x3 list of rows."""
    # built at run time from the catalog: values, not names mypy can check as types
    num: Any = Annotated[int if p.integer else float, Field(ge=p.lo, le=p.hi)]
    triple: Any = Annotated[list[num], Field(min_length=3, max_length=3)]
    if p.shape == (3,):
        return num | triple
    if p.shape == (3, 3):
        return Annotated[list[triple], Field(min_length=3, max_length=3)]
    return num


_SHAPE_TEXT = {(): "", (3,): "; a number or [x, y, z]", (3, 3): "; a 3x3 list [[.., .., ..], [..], [..]]"}


# one effect's validated parameters: name -> a number, or a numpy array for per-axis and matrix values
EffectParams = dict[str, np.ndarray | float]
# a parameter as YAML gives it: a number, [x, y, z], or a 3x3 list of rows
EffectValue: TypeAlias = float | list[float] | list[list[float]]
# an ``effects:`` section as YAML gives it: effect -> its parameters (SensorModel.to_config; from_config reads it)
EffectsConfig: TypeAlias = dict[str, dict[str, EffectValue]]


@cache
def effect_model(name: str) -> type[Section]:
    """The declared parameters of one effect of the catalog (config/schema.py's Section: one-line errors)."""
    fields: dict[str, Any] = {"enabled": (StrictBool, Field(True, description="false: the effect is off"))}
    for p in EFFECTS[name].params:
        fields[p.name] = (_param_type(p) | None, Field(None, description=f"{p.doc}, {p.unit}{_SHAPE_TEXT[p.shape]}"))
    return create_model(f"Effect_{name}", __base__=Section, __doc__=EFFECTS[name].doc, **fields)


@cache
def effects_model() -> type[Section]:
    """An ``effects:`` mapping: each effect of the catalog, its parameters, or true/false (on/off)."""
    fields: dict[str, Any] = {n: (effect_model(n) | StrictBool | None, None) for n in EFFECT_NAMES}
    return create_model("Effects", __base__=Section, **fields)


def parse_effect(name: str, spec: Any, chip: ChipSpec, path: str) -> EffectParams | None:
    """Validated parameters of one effect (None when ``enabled: false``)."""
    if name not in EFFECTS:
        raise ConfigError(f"{path}: unknown effect; allowed: {', '.join(EFFECT_NAMES)}")
    eff = EFFECTS[name]
    if spec is True or spec is None:
        spec = {}
    if spec is False:
        return None
    m = spec if isinstance(spec, Section) else parse(spec, effect_model(name), path)
    enabled = m.enabled  # type: ignore[attr-defined]
    out: EffectParams = {}
    for p in eff.params:
        v = getattr(m, p.name)
        if v is None:
            v = [chip.noise_ug_per_rthz] * 3 if p.default == CHIP_DEFAULT else p.default
        if p.shape == (3,) and not isinstance(v, list):
            v = [v] * 3  # one number for all three axes
        out[p.name] = np.array(v, dtype=float) if p.shape else (int(v) if p.integer else float(v))
    if name == "cross_axis" and np.any(np.diag(out["coupling"]) != 0):
        raise ConfigError(f"{path}.coupling: diagonal entries must be 0 (sensitivity is the gain effect)")
    return out if enabled else None


def parse_effects(effects: Any, chip: ChipSpec, path: str = "simulator.effects") -> dict[str, EffectParams]:
    """The enabled effects of a YAML ``effects:`` mapping, in catalog order.

    An effect is enabled by its presence (``name:``, ``name: {}`` or ``name: true``);
    ``enabled: false`` or ``name: false`` switches it off.  Unknown effects, unknown
    parameters and out-of-range values raise ConfigError naming the key path.
    """
    m = parse(effects, effects_model(), path)
    given = m.model_fields_set
    parsed = {n: parse_effect(n, getattr(m, n), chip, f"{path}.{n}") for n in EFFECT_NAMES if n in given}
    return {n: v for n, v in parsed.items() if v is not None}


# -- physics -----------------------------------------------------------------------------


def rotation_matrix(rotvec_deg: ArrayLike) -> np.ndarray:
    """Rotation matrix of a rotation vector in degrees (Rodrigues); (..., 3) -> (..., 3, 3)."""
    r = np.deg2rad(np.asarray(rotvec_deg, dtype=float))
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = r / np.where(theta[..., 0] > 0, theta[..., 0], 1.0)
    Kx = np.zeros(r.shape[:-1] + (3, 3))
    Kx[..., 0, 1], Kx[..., 0, 2], Kx[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    Kx = Kx - np.swapaxes(Kx, -1, -2)
    return np.eye(3) + np.sin(theta) * Kx + (1.0 - np.cos(theta)) * (Kx @ Kx)


@dataclass
class SensorModel:
    """The enabled effects of one simulated sensor and the stateless physics.

    ``effects`` maps each enabled effect name to its parameters (numpy arrays for
    per-axis values); build it from YAML with :meth:`from_config`.
    """

    chip: ChipSpec
    effects: dict[str, EffectParams] = field(default_factory=dict)
    path: str = "simulator.effects"
    # True: the nonlinearity acts forward on the sensor's linear response u = K f, G = o + u + q u^2 + c u^3
    # (a sensor's physics, not the inverse of a calibration model; the diagnosis self-check's boards)
    forward: bool = False

    @classmethod
    def from_config(cls, effects: Any, chip: ChipSpec | str = "mma8451",
                    path: str = "simulator.effects", forward: bool = False) -> SensorModel:
        chip = get_chip(chip) if isinstance(chip, str) else chip
        if effects is None:
            effects = {n: {} for n in DEFAULT_EFFECTS}
        return cls(chip, parse_effects(effects, chip, path), path, forward)

    def to_config(self) -> EffectsConfig:
        """The YAML ``effects:`` mapping of this model (round-trips through from_config)."""
        return {n: {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in p.items()}
                for n, p in self.effects.items()}

    def with_effect(self, name: str, **params: EffectValue) -> SensorModel:
        """A copy with ``name`` enabled (parameters as in YAML; missing ones default)."""
        cfg = self.to_config()
        cfg[name] = {**cfg.get(name, {}), **params}
        return SensorModel.from_config(cfg, self.chip, self.path, self.forward)

    def without(self, *names: str) -> SensorModel:
        return SensorModel.from_config({n: p for n, p in self.to_config().items() if n not in names},
                                       self.chip, self.path, self.forward)

    @property
    def enabled(self) -> tuple[str, ...]:
        return tuple(self.effects)

    def has(self, name: str) -> bool:
        return name in self.effects

    def _p(self, effect: str, param: str) -> Any:
        """A parameter's value, or its neutral default when the effect is disabled."""
        if effect in self.effects:
            return self.effects[effect][param]
        d = EFFECTS[effect].param(param).default
        return np.array(d, dtype=float) if isinstance(d, list) else d

    # stage 4 + temperature
    def _dt(self, temp_c: float) -> float:
        return float(temp_c) - float(self._p("temperature", "t_ref_c"))

    def offset_g(self, temp_c: float = 25.0) -> np.ndarray:
        """o(T) in g: offset_mg + a1 dT + a2 dT^2 (temperature effect), dT = T - t_ref_c."""
        dt = self._dt(temp_c)
        mg = self._p("offset", "offset_mg") + self._p("temperature", "offset_mg_per_c") * dt \
            + self._p("temperature", "offset_mg_per_c2") * dt**2
        return 1e-3 * np.asarray(mg, dtype=float)

    def gain(self, temp_c: float = 25.0) -> np.ndarray:
        """gain(T) = gain (1 + 1e-6 (b1 dT + b2 dT^2)) per axis."""
        dt = self._dt(temp_c)
        ppm = self._p("temperature", "gain_ppm_per_c") * dt + self._p("temperature", "gain_ppm_per_c2") * dt**2
        return self._p("gain", "gain") * (1.0 + 1e-6 * ppm)

    def linear_matrix(self, temp_c: float = 25.0) -> np.ndarray:
        """K(T) = diag(gain(T)) (I + C) R_pkg^T: reading per unit true force (stage 2)."""
        C = self._p("cross_axis", "coupling")
        R = rotation_matrix(self._p("cross_axis", "rotation_deg"))
        return np.diag(self.gain(temp_c)) @ (np.eye(3) + C) @ R.T

    def nonlinearity(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, c): square and cubic coefficients per axis (zeros when disabled)."""
        return (np.asarray(self._p("quadratic", "quadratic_per_g"), dtype=float),
                np.asarray(self._p("cubic", "cubic_per_g2"), dtype=float))

    def check_range(self, range_g: float, path: str | None = None) -> None:
        """Refuse a nonlinearity that folds (is not monotonic) within +-range_g."""
        q, c = self.nonlinearity()
        slope = 2 * np.abs(q) * range_g + 3 * np.abs(c) * range_g**2
        if np.any(slope >= 0.5):
            name = "cubic.cubic_per_g2" if np.any(3 * np.abs(c) * range_g**2 >= 0.25) else "quadratic.quadratic_per_g"
            raise ConfigError(f"{path or self.path}.{name}: too large for the {range_g:g} g range "
                              f"(2|q|R + 3|c|R^2 = {slope.max():.3g} must stay below 0.5 so the response is monotonic)")

    def response_g(self, f_g: ArrayLike, temp_c: float = 25.0) -> np.ndarray:
        """Noise-free reading G in g (stages 2-4) for true specific force f (..., 3) in g.

        Solves ``G = o + K (f + q G^2 + c G^3)`` by Newton's method when a
        nonlinearity is enabled (exact to float64 rounding).
        """
        f = np.asarray(f_g, dtype=float)
        K = self.linear_matrix(temp_c)
        o = self.offset_g(temp_c)
        G = o + f @ K.T
        q, c = self.nonlinearity()
        if not (np.any(q) or np.any(c)):
            return G
        if self.forward:  # reading = S a + q (S a)^2 + c (S a)^3 + b, with S = K(T), b = o(T)
            u = G - o
            return o + u + q * u**2 + c * u**3
        shape = G.shape
        G = G.reshape(-1, 3)
        f2 = f.reshape(-1, 3) if f.shape == shape else np.broadcast_to(f, shape).reshape(-1, 3)
        for _ in range(60):
            F = o + (f2 + q * G**2 + c * G**3) @ K.T - G
            J = K[None] * (2 * q * G + 3 * c * G**2)[:, None, :] - np.eye(3)
            step = np.linalg.solve(J, -F[..., None])[..., 0]
            G = G + step
            if np.max(np.abs(step)) < 1e-14 * max(1.0, float(np.max(np.abs(G)))):
                break
        return G.reshape(shape)

    def noise_sigma_g(self, odr_hz: float, dlpf: int | None = None) -> np.ndarray:
        """Per-sample white-noise standard deviation in g: density * sqrt(ENBW)."""
        if "noise" not in self.effects:
            return np.zeros(3)
        d = self.effects["noise"]["density_ug_per_rthz"] * 1e-6
        return d * np.sqrt(self.chip.enbw_hz(odr_hz, dlpf))

    def gravity_g(self) -> float:
        """Magnitude of the true specific force at rest, in standard g."""
        return float(self._p("gravity", "local_mps2")) / STANDARD_GRAVITY_MPS2

    def to_counts(self, g: ArrayLike, counts_per_g: float) -> np.ndarray:
        """Stages 8-10: scale, clip at the code range, round (int64 when quantized)."""
        x = np.asarray(g, dtype=float) * counts_per_g
        lo, hi = -np.inf, np.inf
        if "saturation" in self.effects:
            frac = float(self.effects["saturation"]["full_scale_fraction"])
            lo, hi = np.ceil(self.chip.code_limits[0] * frac), np.floor(self.chip.code_limits[1] * frac)
            x = np.clip(x, lo, hi)
        if "quantization" in self.effects:
            lsb = self.effects["quantization"]["lsb_counts"]
            # a coarse LSB keeps the clipped output on representable codes
            x = np.clip(np.round(x / lsb), np.ceil(lo / lsb), np.floor(hi / lsb)) * lsb
            return x.astype(np.int64)
        return x

    def truth(self, temp_c: float, counts_per_g: float) -> Calibration:
        """The AN4399 calibration that inverts offset, gain, cross_axis and cubic at temp_c.

        From step 3, ``f = K^-1 G - K^-1 o - c G^3``, so ``W = K^-1``, ``V = -K^-1 o``,
        ``Gamma = -c`` (AN4399 Eqn 67) -- exact, not an approximation (with ``forward`` physics
        the same W, V, Gamma, of which model 15's fit is then an approximation).  The
        ``quadratic`` term has no AN4399 counterpart and is left out; the output is in
        standard g (the ``gravity`` effect is not inverted); drift, settling, noise,
        saturation and quantization are not part of a calibration.
        """
        Winv = np.linalg.inv(self.linear_matrix(temp_c))
        _, c = self.nonlinearity()
        return Calibration("15", Winv, -Winv @ self.offset_g(temp_c), -c, "counts", float(counts_per_g),
                           metadata={"source": "simulator truth", "temp_c": float(temp_c),
                                     "effects": list(self.enabled)})

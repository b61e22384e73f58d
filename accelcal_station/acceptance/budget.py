"""The uncertainty budget of one board's calibration (GUM, JCGM 100:2008): each source's standard
uncertainty propagated to the offsets V (mg) and the matrix W, combined (GUM eq. 10, the sources
uncorrelated) and expanded with k = 2 (GUM 6.2).

Sources (docs/uncertainty.md):

- ``noise`` (Type A): each pose mean's standard error as the capture reports it (the effective
  sample count's, when the capture accounts for correlated samples), through the fit.
- ``jig_angle`` (Type B): every pose within +-``angle_tolerance_deg`` of its commanded attitude about
  the two axes that tilt gravity, rectangular (u = t/sqrt(3), GUM 4.3.7), each pose independent.
- ``site_gravity`` (Type B): the site gravity's standard uncertainty (config/site.py); every reference
  scales with it, so V and W scale with it (relative sensitivity 1).
- ``temperature`` (Type B): the board temperature's span over the run times the data sheet's
  temperature coefficients, rectangular (u = tc dT / sqrt(3)).
- ``quantization`` (Type B): one count's resolution, LSB/sqrt(12) (GUM F.2.2.1) on a pose mean; divided
  by sqrt(n) where the samples' own spread is a count or more (the noise dithers it), else not.
- ``assigned_temperature`` (Type B, a thermal table's set points only): the standard uncertainty of the
  temperature a set point's fit is assigned (the die sensor's or the chamber air's) times the table's
  slope there, d(parameter)/dT from the neighbouring set points' fits (GUM 5.1.3: the parameter the
  table gives at a temperature is off by the slope times the error in the temperature it was filed at).

The fit's sensitivities to the readings and to the pose references are taken by the fit itself
(``fit_batch`` on the readings and references each moved by a small step: the models are linear in
the references and smooth in the readings, so this is the fit's linear sensitivity, GUM 5.1.3).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from ..config.site import Site
from ..errors import AccelcalError
from ..models.fitting import fit_batch

K_EXPANDED = 2.0  # coverage factor: about 95 % for a near-normal combined distribution (GUM 6.2.2)
READ_STEP_G = 1e-5  # finite-difference step of a reading, g
TILT_STEP_RAD = 1e-5  # of a reference's tilt, rad


@dataclass(frozen=True)
class Tempco:
    """A chip's data-sheet temperature coefficients (maximum, taken as the half-width of a rectangle)."""

    offset_mg_per_k: tuple[float, float, float]
    gain_per_k: float  # fraction of sensitivity per K
    source: str


DATASHEET_TEMPCO = {
    "mma8451": Tempco((0.15, 0.15, 0.15), 0.008e-2,
                      "MMA8451Q data sheet Rev. 10.3, Table 2: TCOff +-0.15 mg/C, TCS +-0.008 %/C"),
    "mpu6050": Tempco((35 / 70, 35 / 70, 60 / 70), 0.02e-2,
                      "MPU-6000/6050 product specification Rev. 3.4, 6.2: zero-G change +-35 mg (X, Y), +-60 mg "
                      "(Z) over 0-70 C; sensitivity change +-0.02 %/C"),
}


def tempco_of(chip: str) -> Tempco | None:
    """The data sheet's coefficients for a chip name (``mma8451``, ``mpu6050``), or None."""
    return next((t for name, t in DATASHEET_TEMPCO.items() if name in chip.lower()), None)


@dataclass
class BudgetInputs:
    """What one board's budget is computed from (g unless named)."""

    model: str
    readings_g: np.ndarray  # (P, 3) pose means
    references_g: np.ndarray | None  # (P, 3) as fitted (scaled to the site); None: model 9
    sem_g: np.ndarray | None = None  # (P, 3) each mean's standard error as the capture reports it
    std_g: np.ndarray | None = None  # (P, 3) per-sample spread (whether the noise dithers the LSB)
    n: np.ndarray | None = None  # (P,) samples averaged
    lsb_g: float | None = None  # one count, g
    angle_tolerance_deg: float | None = None
    site: Site = field(default_factory=Site)
    temp_span_c: float | None = None  # max - min board temperature over the poses
    tempco: Tempco | None = None
    temp_u_c: float | None = None  # a thermal set point: its assigned temperature's standard uncertainty, C
    temp_slope: np.ndarray | None = None  # (12,) d(parameter)/dT there: V in mg/K, then W row by row per K


class UJson(TypedDict):
    """Standard or expanded uncertainties per parameter: V in mg, W dimensionless."""

    V_mg: list[float]
    W: list[list[float]]


class ComponentJson(TypedDict):
    """One line of the budget."""

    source: str
    type: str  # A or B (GUM 4.2, 4.3)
    value: float | None  # the input quantity's standard uncertainty (or half-width), in ``unit``
    unit: str
    distribution: str
    propagation: str
    note: str
    u: UJson  # its standard uncertainty in each parameter


class UncertaintyJson(TypedDict):
    """``uncertainty`` in run --json and the store."""

    k: float
    expanded: UJson
    combined: UJson
    budget: list[ComponentJson]


@dataclass
class Component:
    """One source's standard uncertainty in every parameter (12: V_x,y,z in mg, then W row by row)."""

    source: str
    type: str
    value: float | None
    unit: str
    distribution: str
    propagation: str
    u: np.ndarray  # (12,)
    note: str = ""

    def to_json(self) -> ComponentJson:
        return {"source": self.source, "type": self.type, "value": self.value, "unit": self.unit,
                "distribution": self.distribution, "propagation": self.propagation, "note": self.note,
                "u": _ujson(self.u)}


def _ujson(u: np.ndarray) -> UJson:
    return {"V_mg": [float(v) for v in u[:3]], "W": u[3:].reshape(3, 3).tolist()}


@dataclass
class Budget:
    """A board's budget: its components, combined (root sum of squares) and expanded (k)."""

    components: list[Component]
    k: float = K_EXPANDED

    @property
    def combined(self) -> np.ndarray:
        """(12,) u_c per parameter (GUM eq. 10, uncorrelated sources)."""
        return np.sqrt(np.sum([c.u ** 2 for c in self.components], axis=0)) if self.components else np.zeros(12)

    @property
    def expanded(self) -> np.ndarray:
        """(12,) U = k u_c."""
        return self.k * self.combined

    @property
    def expanded_V_mg(self) -> np.ndarray:
        return self.expanded[:3]

    @property
    def expanded_W(self) -> np.ndarray:
        return self.expanded[3:].reshape(3, 3)

    def to_json(self) -> UncertaintyJson:
        return {"k": self.k, "expanded": _ujson(self.expanded), "combined": _ujson(self.combined),
                "budget": [c.to_json() for c in self.components]}


def _tilt_axes(r: np.ndarray) -> np.ndarray:
    """(2, 3) two unit axes perpendicular to ``r``: rotations about them tilt gravity."""
    u = r / np.linalg.norm(r)
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(u, e1)])


def _params(W: np.ndarray, V: np.ndarray) -> np.ndarray:
    """(D, 12): V in mg, then W row by row."""
    return np.concatenate([V * 1e3, W.reshape(len(W), 9)], axis=1)


def sensitivities(inp: BudgetInputs) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The fitted parameters (12,), their sensitivity to each reading (P, 3, 12) per g, and to each
    pose's two tilts (P, 2, 12) per rad (None without references): one fit_batch of the board and its
    moved copies."""
    x, ref = np.asarray(inp.readings_g, float), inp.references_g
    P = len(x)
    xs, refs = [x], []
    for i in range(P):
        for a in range(3):
            xm = x.copy()
            xm[i, a] += READ_STEP_G
            xs.append(xm)
    n_read = len(xs)
    if ref is not None:
        ref = np.asarray(ref, float)
        for i in range(P):
            for e in _tilt_axes(ref[i]):
                rm = ref.copy()
                rm[i] = ref[i] + TILT_STEP_RAD * np.cross(e, ref[i])  # the first-order rotation of r about e
                refs.append(rm)
    X = np.stack(xs + [x] * len(refs))
    R = None if ref is None else np.stack([ref] * n_read + refs)
    noise = None if inp.sem_g is None else np.broadcast_to(inp.sem_g, X.shape)
    b = fit_batch(X, R, inp.model, units="g", noise=noise, workers=1)
    if not np.all(b.ok):
        raise AccelcalError(f"the budget's sensitivities: a moved copy of the board did not fit ({b.messages})")
    theta = _params(b.W, b.V)
    J_read = ((theta[1:n_read] - theta[0]) / READ_STEP_G).reshape(P, 3, 12)
    J_tilt = None if ref is None else ((theta[n_read:] - theta[0]) / TILT_STEP_RAD).reshape(P, 2, 12)
    return theta[0], J_read, J_tilt


def _through(J: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(12,) sqrt(sum_i (J_i u_i)^2): independent inputs ``u`` (same leading shape as J's) through J."""
    Jf = J.reshape(-1, J.shape[-1])
    return np.sqrt((Jf ** 2).T @ (np.asarray(u, float).reshape(-1) ** 2))


def _noise(inp: BudgetInputs, J_read: np.ndarray) -> Component:
    if inp.sem_g is None:
        return Component("noise", "A", None, "mg", "normal", "not evaluated", np.zeros(12),
                         "the poses carry no standard error (std and n)")
    sem = np.asarray(inp.sem_g, float)
    return Component("noise", "A", float(np.max(sem)) * 1e3, "mg", "normal", "linear sensitivity of the fit",
                     _through(J_read, sem), "each pose mean's standard error as the capture reports it "
                     "(value: the largest)")


def _jig(inp: BudgetInputs, J_tilt: np.ndarray | None) -> Component:
    t = inp.angle_tolerance_deg
    if J_tilt is None or t is None:
        why = "model 9 uses no pose references" if J_tilt is None else "no jig angle tolerance"
        return Component("jig_angle", "B", t, "deg", "rectangular", "not evaluated", np.zeros(12), why)
    u_rad = math.radians(t) / math.sqrt(3.0)
    return Component("jig_angle", "B", t, "deg", "rectangular", "linear sensitivity of the fit",
                     _through(J_tilt, np.full(J_tilt.shape[:2], u_rad)),
                     "every pose within +-value of its commanded attitude about both tilt axes, independently")


def _gravity(inp: BudgetInputs, theta: np.ndarray) -> Component:
    s = inp.site
    return Component("site_gravity", "B", s.gravity_u_mps2, "m/s^2", "normal" if s.source == "measured"
                     else "rectangular" if s.source == "standard" else "normal", "relative sensitivity 1 "
                     "(every reference scales with it)", np.abs(theta) * s.relative_u,
                     f"site {s.source}: {s.gravity_mps2:.6f} m/s^2")


def _temperature(inp: BudgetInputs) -> Component:
    tc, span = inp.tempco, inp.temp_span_c
    if tc is None or span is None:
        why = "no board temperature over the run" if span is None else "no data-sheet coefficients for the chip"
        return Component("temperature", "B", span, "K", "rectangular", "not evaluated", np.zeros(12), why)
    u = np.zeros(12)
    u[:3] = np.asarray(tc.offset_mg_per_k) * span / math.sqrt(3.0)
    u[3:][[0, 4, 8]] = tc.gain_per_k * span / math.sqrt(3.0)
    return Component("temperature", "B", span, "K", "rectangular", "direct (sensitivity 1 on V and W_ii)", u,
                     f"board temperature span over the run x {tc.source}")


def _quantization(inp: BudgetInputs, J_read: np.ndarray) -> Component:
    lsb = inp.lsb_g
    if lsb is None:
        return Component("quantization", "B", None, "mg", "rectangular", "not evaluated", np.zeros(12),
                         "no count size (readings not in counts)")
    P = len(J_read)
    u = np.full((P, 3), lsb / math.sqrt(12.0))
    if inp.std_g is not None and inp.n is not None:
        dithered = np.asarray(inp.std_g, float) >= lsb  # the noise spans a count: the resolution averages out
        u = np.where(dithered, u / np.sqrt(np.maximum(np.asarray(inp.n, float), 1.0))[:, None], u)
    return Component("quantization", "B", lsb * 1e3, "mg", "rectangular", "linear sensitivity of the fit",
                     _through(J_read, u), "one count / sqrt(12) per pose mean, / sqrt(n) where the noise dithers it")


def _assigned_temperature(u_c: float, slope: np.ndarray) -> Component:
    return Component("assigned_temperature", "B", u_c, "C", "normal", "the table's slope d(parameter)/dT "
                     "between the neighbouring set points", np.abs(np.asarray(slope, float)) * u_c,
                     "the temperature this set point's fit is filed at (die sensor or chamber air)")


def budget(inp: BudgetInputs) -> Budget:
    """The board's budget (module docstring)."""
    theta, J_read, J_tilt = sensitivities(inp)
    parts = [_noise(inp, J_read), _jig(inp, J_tilt), _gravity(inp, theta), _temperature(inp),
             _quantization(inp, J_read)]
    if inp.temp_u_c is not None and inp.temp_slope is not None:
        parts.append(_assigned_temperature(inp.temp_u_c, inp.temp_slope))
    return Budget(parts)

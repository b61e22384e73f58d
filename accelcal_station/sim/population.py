"""A population of simulated boards: the distribution each new board's parameters are drawn from.

``device.simulator.population`` (beside ``effects:``, which holds the fixed parameters
every board shares)::

    population:
      quantities: [offset.offset_mg[0], gain.gain[0], cubic.cubic_per_g2[2]]
      components:                       # a mixture; weights sum to 1
        - weight: 0.9
          mean: {offset.offset_mg[0]: 18.0, gain.gain[0]: 1.012}   # missing: the effects: value
          sd: {offset.offset_mg[0]: 10.0, gain.gain[0]: 0.004}     # missing: 0 (fixed)
          correlation: [[1, 0.6, 0], [0.6, 1, 0], [0, 0, 1]]      # in quantities' order (default I)
          dof: 5                        # Student-t degrees of freedom (heavy tails); absent: Gaussian
        - {weight: 0.1, mean: {cubic.cubic_per_g2[2]: 0.015}, sd: {cubic.cubic_per_g2[2]: 0.003}}
      tails:                            # per-quantity Student-t marginals (a Gaussian copula)
        cross_axis.coupling[0][1]: {dof: 3.2, loc: 0.004, scale: 0.0019}
      changes:                          # along the lot (board index from 0)
        - {quantity: offset.offset_mg[0], kind: step, at_board: 12000, size: 5.0}
        - {quantity: gain.gain[1], kind: trend, at_board: 0, size: 1.0e-7}   # size per board

A quantity is one scalar parameter of a catalog effect: ``effect.param``, ``effect.param[i]``
or ``effect.param[i][j]`` (sim/sensor_model.EFFECTS); naming one enables its effect.  Board
``k``'s vector is ``x = mu_c + L_c z sqrt(nu / chi2_nu)`` for the component ``c`` drawn by
weight (``L_c L_c^T = diag(sd) R diag(sd)``; no chi2 factor when Gaussian); a quantity with
``tails`` then has its value ``y`` mapped through its own Student-t marginal,
``x = loc + scale T_dof^-1(Phi((y - loc) / scale))`` (a Gaussian copula with a t marginal: one
parameter's heavy tail without making the others heavy or adding components; near ``loc`` the
map is close to the identity), plus every change active at ``k``, then clipped to the
parameter's physical range.  A single fixed board is one
component with zero spread.  Every error is one line naming the key and what is allowed.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np

from ..config.checks import check_keys, number
from ..errors import ConfigError
from ..jsontypes import JsonObject, JsonValue
from .sensor_model import EFFECTS, EffectParams, Param

POPULATION_KEYS = ("quantities", "components", "changes", "tails")
TAIL_KEYS = ("dof", "loc", "scale")
COMPONENT_KEYS = ("weight", "mean", "sd", "correlation", "dof")
CHANGE_KEYS = ("quantity", "kind", "at_board", "size")
CHANGE_KINDS = ("step", "trend")
_NAME = re.compile(r"^([a-z_]+)\.([a-z0-9_]+)((?:\[[0-2]\]){0,2})$")


@dataclass(frozen=True)
class Quantity:
    """One scalar effect parameter: ``effect.param[index]``."""

    effect: str
    param: str
    index: tuple[int, ...]

    @property
    def name(self) -> str:
        return f"{self.effect}.{self.param}" + "".join(f"[{i}]" for i in self.index)

    @property
    def spec(self) -> Param:
        return EFFECTS[self.effect].param(self.param)


def parse_quantity(name: Any, path: str) -> Quantity:
    """``effect.param[i][j]`` checked against the catalog (index count = the parameter's shape)."""
    m = _NAME.match(name) if isinstance(name, str) else None
    allowed = "effect.param, effect.param[i] or effect.param[i][j] of a catalog effect (e.g. offset.offset_mg[0])"
    if m is None:
        raise ConfigError(f"{path}: {name!r}; allowed: {allowed}")
    eff, par, idx = m.group(1), m.group(2), tuple(int(i) for i in re.findall(r"\d", m.group(3)))
    if eff not in EFFECTS:
        raise ConfigError(f"{path}: {name!r}: unknown effect {eff!r}; allowed: {', '.join(EFFECTS)}")
    names = [p.name for p in EFFECTS[eff].params]
    if par not in names:
        raise ConfigError(f"{path}: {name!r}: {eff} has no parameter {par!r}; allowed: {', '.join(names)}")
    p = EFFECTS[eff].param(par)
    if len(idx) != len(p.shape) or p.integer:
        raise ConfigError(f"{path}: {name!r}: {eff}.{par} has shape {p.shape or 'scalar'} "
                          f"({'an integer, not drawn' if p.integer else f'give {len(p.shape)} index(es)'})")
    if eff == "cross_axis" and par == "coupling" and idx[0] == idx[1]:
        raise ConfigError(f"{path}: {name!r}: the coupling diagonal is 0 (sensitivity is gain.gain[i])")
    return Quantity(eff, par, idx)


@dataclass(frozen=True)
class Component:
    weight: float
    mean: np.ndarray  # (Q,)
    sd: np.ndarray  # (Q,)
    correlation: np.ndarray  # (Q, Q)
    dof: float | None = None  # Student-t degrees of freedom; None: Gaussian

    def chol(self) -> np.ndarray:
        cov = self.correlation * np.outer(self.sd, self.sd)
        w, v = np.linalg.eigh(cov)  # PSD square root: a zero sd is allowed (no Cholesky)
        return v * np.sqrt(np.clip(w, 0.0, None))


@dataclass(frozen=True)
class Change:
    quantity: Quantity
    kind: str  # step | trend
    at_board: int
    size: float  # step: the jump; trend: change per board from at_board on

    def shift(self, boards: np.ndarray) -> np.ndarray:
        after = boards >= self.at_board
        if self.kind == "step":
            return np.where(after, self.size, 0.0)
        return np.where(after, self.size * (boards - self.at_board), 0.0)


@dataclass(frozen=True)
class Tail:
    """A quantity's Student-t marginal (module docstring): dof, location and scale in its units."""

    dof: float
    loc: float
    scale: float

    def to_t(self, y: np.ndarray) -> np.ndarray:
        """Gaussian-scale values to the t marginal: loc + scale T^-1(Phi((y - loc) / scale))."""
        from scipy.special import ndtr, stdtrit

        z = (y - self.loc) / self.scale
        p = ndtr(-np.abs(z))  # the lower tail of |z|: no 1 - tiny rounding to 1
        return self.loc + self.scale * np.sign(z) * -stdtrit(self.dof, np.clip(p, 1e-300, 0.5))

    def to_gauss(self, x: np.ndarray) -> np.ndarray:
        """The inverse: loc + scale Phi^-1(T((x - loc) / scale))."""
        from scipy.special import ndtri, stdtr

        t = (x - self.loc) / self.scale
        p = stdtr(self.dof, -np.abs(t))
        return self.loc + self.scale * np.sign(t) * -ndtri(np.clip(p, 1e-300, 0.5))


@dataclass
class Population:
    quantities: list[Quantity]
    components: list[Component]
    changes: list[Change] = field(default_factory=list)
    tails: dict[str, Tail] = field(default_factory=dict)  # quantity name -> its t marginal

    @property
    def names(self) -> list[str]:
        return [q.name for q in self.quantities]

    def draw(self, boards: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Parameter vectors (len(boards), Q) for the boards with these lot indices."""
        boards = np.asarray(boards, dtype=np.int64)
        n, Q = len(boards), len(self.quantities)
        w = np.array([c.weight for c in self.components])
        which = rng.choice(len(w), size=n, p=w / w.sum())
        z = rng.standard_normal((n, Q))
        x = np.empty((n, Q))
        for k, c in enumerate(self.components):
            sel = which == k
            y = z[sel] @ c.chol().T
            if c.dof is not None:  # multivariate t: a Gaussian scaled by sqrt(nu / chi2_nu)
                y *= np.sqrt(c.dof / rng.chisquare(c.dof, int(sel.sum())))[:, None]
            x[sel] = c.mean + y
        for name, tail in self.tails.items():
            k = self.names.index(name)
            x[:, k] = tail.to_t(x[:, k])
        for ch in self.changes:
            x[:, self.quantities.index(ch.quantity)] += ch.shift(boards)
        lo = np.array([-np.inf if q.spec.lo is None else q.spec.lo for q in self.quantities])
        hi = np.array([np.inf if q.spec.hi is None else q.spec.hi for q in self.quantities])
        return np.clip(x, lo, hi)

    def apply(self, effects: dict[str, EffectParams], x: np.ndarray) -> dict[str, EffectParams]:
        """The effects (parsed, as SensorModel holds them) of one board with vector ``x`` (Q,)."""
        out = {n: {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in p.items()}
               for n, p in effects.items()}
        for q, v in zip(self.quantities, x, strict=True):
            eff = out.setdefault(q.effect, _defaults(q.effect))
            vec = eff[q.param]
            if q.index and isinstance(vec, np.ndarray):  # per-axis and matrix parameters are arrays
                vec[q.index] = v
            else:
                eff[q.param] = float(v)
        return out

    def to_config(self) -> JsonObject:
        """The YAML mapping (round-trips through parse_population)."""
        names = self.names
        comps: list[JsonValue] = []
        for c in self.components:
            d: JsonObject = {"weight": float(c.weight), "mean": dict(zip(names, map(float, c.mean), strict=True)),
                             "sd": dict(zip(names, map(float, c.sd), strict=True)),
                             "correlation": c.correlation.tolist()}
            if c.dof is not None:
                d["dof"] = float(c.dof)
            comps.append(d)
        out: JsonObject = {"quantities": [*names], "components": comps,
                           "changes": [{"quantity": ch.quantity.name, "kind": ch.kind, "at_board": int(ch.at_board),
                                        "size": float(ch.size)} for ch in self.changes]}
        if self.tails:
            out["tails"] = {n: {"dof": t["dof"], "loc": t["loc"], "scale": t["scale"]}
                            for n, t in self.tails_config().items()}
        return out

    def tails_config(self) -> dict[str, TailConfig]:
        """``tails:`` as written (a quantity's Student-t marginal)."""
        return {n: {"dof": float(t.dof), "loc": float(t.loc), "scale": float(t.scale)} for n, t in self.tails.items()}


class TailConfig(TypedDict):
    """A quantity's Student-t marginal as written under ``population.tails``."""

    dof: float
    loc: float
    scale: float


def _defaults(effect: str) -> EffectParams:
    return {p.name: (np.array(p.default, dtype=float) if isinstance(p.default, list) else p.default)
            for p in EFFECTS[effect].params}


def base_value(effects: dict[str, EffectParams], q: Quantity) -> float:
    """The fixed value of a quantity in the parsed ``effects:`` (or the catalog's neutral default)."""
    p = effects.get(q.effect, {}).get(q.param)
    if p is None:
        p = _defaults(q.effect)[q.param]
    return float(np.asarray(p, dtype=float)[q.index])


def _vector(d: Any, names: list[str], path: str, fill: np.ndarray, lo: float | None = None) -> np.ndarray:
    check_keys(d, names, path)
    out = fill.copy()
    for k in d or {}:
        out[names.index(k)] = number(d, k, path, lo=lo)
    return out


def _correlation(v: Any, Q: int, path: str) -> np.ndarray:
    if v is None:
        return np.eye(Q)
    try:
        R = np.array(v, dtype=float)
    except (TypeError, ValueError):
        R = np.full(1, np.nan)
    if R.shape != (Q, Q) or not np.all(np.isfinite(R)):
        raise ConfigError(f"{path}: allowed: a {Q}x{Q} matrix of numbers in the order of population.quantities")
    if not (np.allclose(R, R.T, atol=1e-9) and np.allclose(np.diag(R), 1.0) and np.all(np.abs(R) <= 1 + 1e-9)):
        raise ConfigError(f"{path}: must be symmetric with 1 on the diagonal and entries within [-1, 1]")
    if np.linalg.eigvalsh(R)[0] < -1e-4:
        raise ConfigError(f"{path}: not positive semi-definite (no joint distribution has these correlations)")
    return R


def _component(c: Any, names: list[str], base: np.ndarray, path: str) -> Component:
    check_keys(c, COMPONENT_KEYS, path)
    if not isinstance(c, dict) or "weight" not in c:
        raise ConfigError(f"{path}: a component needs weight (and mean, sd, correlation, dof as needed)")
    dof = c.get("dof")
    return Component(number(c, "weight", path, lo=0.0, hi=1.0), _vector(c.get("mean"), names, f"{path}.mean", base),
                     _vector(c.get("sd"), names, f"{path}.sd", np.zeros(len(names)), lo=0.0),
                     _correlation(c.get("correlation"), len(names), f"{path}.correlation"),
                     None if dof is None else number(c, "dof", path, lo=1.0, hi=1e6))


def _change(d: Any, names: list[str], quantities: list[Quantity], path: str) -> Change:
    check_keys(d, CHANGE_KEYS, path)
    if not isinstance(d, dict) or not all(k in d for k in CHANGE_KEYS):
        raise ConfigError(f"{path}: a change needs {', '.join(CHANGE_KEYS)}")
    if d["quantity"] not in names:
        raise ConfigError(f"{path}.quantity: {d['quantity']!r}; allowed: one of population.quantities")
    if d["kind"] not in CHANGE_KINDS:
        raise ConfigError(f"{path}.kind: {d['kind']!r}; allowed: {', '.join(CHANGE_KINDS)}")
    return Change(quantities[names.index(d["quantity"])], d["kind"],
                  number(d, "at_board", path, lo=0, integer=True), number(d, "size", path))


def parse_population(spec: Any, effects: dict[str, EffectParams], path: str = "simulator.population"
                     ) -> Population:
    """Validate a ``population:`` mapping against the parsed fixed ``effects``."""
    spec = check_keys(spec, POPULATION_KEYS, path)
    qs = spec.get("quantities")
    if not isinstance(qs, list) or not qs:
        raise ConfigError(f"{path}.quantities: allowed: a non-empty list of effect.param[i] names")
    quantities = [parse_quantity(q, f"{path}.quantities[{i}]") for i, q in enumerate(qs)]
    names = [q.name for q in quantities]
    if len(set(names)) != len(names):
        raise ConfigError(f"{path}.quantities: a quantity appears twice")
    comps = spec.get("components")
    if not isinstance(comps, list) or not comps:
        raise ConfigError(f"{path}.components: allowed: a non-empty list of {{weight, mean, sd, correlation, dof}}")
    base = np.array([base_value(effects, q) for q in quantities])
    components = [_component(c, names, base, f"{path}.components[{i}]") for i, c in enumerate(comps)]
    total = sum(c.weight for c in components)
    if abs(total - 1.0) > 1e-6:
        raise ConfigError(f"{path}.components: weights sum to {total:.6g}; allowed: they sum to 1")
    changes = spec.get("changes") or []
    if not isinstance(changes, list):
        raise ConfigError(f"{path}.changes: allowed: a list of {{quantity, kind, at_board, size}}")
    return Population(quantities, components,
                      [_change(c, names, quantities, f"{path}.changes[{i}]") for i, c in enumerate(changes)],
                      _tails(spec.get("tails"), names, f"{path}.tails"))


def _tails(spec: Any, names: list[str], path: str) -> dict[str, Tail]:
    check_keys(spec, names, path)
    out = {}
    for name, t in (spec or {}).items():
        check_keys(t, TAIL_KEYS, f"{path}.{name}")
        if not isinstance(t, dict) or not all(k in t for k in TAIL_KEYS):
            raise ConfigError(f"{path}.{name}: a tail needs {', '.join(TAIL_KEYS)}")
        out[name] = Tail(number(t, "dof", f"{path}.{name}", lo=1.0, hi=1e6), number(t, "loc", f"{path}.{name}"),
                         number(t, "scale", f"{path}.{name}", lo=1e-300))
    return out

"""The Diagnosis record: what `accelcal diagnose` found (engine.diagnose), and its JSON."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from ..identifiability import TermsDescription
from ..jsontypes import JsonObject
from .evaluation import Evaluation
from .gap_data import GapData
from .headline import Headline
from .loading import Simulator
from .noise_floor import Floor
from .order import OrderConfound
from .order_trend import OrderTrendJson
from .selection import ALPHA, MIN_GAP_SHRINK, Ranked, Step, Tried
from .shape import Leftover
from .where import Where


class FloorJson(TypedDict):
    """The floor the gap is measured against: where it came from, per-axis sigma, LSB, pose scatter."""

    source: str
    sigma_mg: list[float]
    lsb_mg: float
    pose_scatter_deg: float


class Untestable(TypedDict):
    effect: str
    reason: str


class TestJson(TypedDict):
    """What the gap is and how a candidate is judged (words, and the test's alpha and shrink)."""

    gap: str
    name: str
    alpha: float
    min_gap_shrink: float


class DataJson(TypedDict):
    """The data diagnosed: files, poses, what each pose carries."""

    sources: list[str]
    poses: int
    references: bool
    samples_per_pose_known: bool
    temperatures: int
    raw_captures: bool
    rate_hz: float | None
    counts_per_g: list[float | None]  # per file (None: not counts)
    static_view: bool
    static_view_note: str | None
    notes: list[str]


class DiagnosisJson(TypedDict):
    """`accelcal diagnose --json` (key order is the output's)."""

    verdict: str
    verdict_text: str
    confounded: dict[str, OrderConfound]
    confounded_with: dict[str, OrderConfound]
    order_trend: OrderTrendJson | None
    headline: Headline | None
    gap_before: float
    gap_after: float
    rms_mg_before: float
    rms_mg_after: float
    floor_mg: float
    floor: FloorJson
    selected: list[str]
    steps: list[Step]
    tried: list[Tried]
    ranking: list[Ranked]
    stochastic: dict[str, JsonObject]  # each stochastic effect's signature (effects/*.py: its own evidence)
    left: Leftover
    identifiability: TermsDescription | None
    untestable: list[Untestable]
    baseline: list[str]
    config: str
    config_effects: list[str]
    test: TestJson
    data: DataJson
    where: Where


@dataclass
class Diagnosis:
    """The data, the simulator and its floor, the baseline's and the final model's held-out evaluations,
    the selection (ranking, steps, every candidate tried), where the gap lies, the stochastic signatures,
    what is left and the verdict (engine's module doc)."""

    data: GapData
    sim: Simulator
    floor: Floor
    base: Evaluation
    final: Evaluation
    ranking: list[Ranked]
    steps: list[Step]
    selected: list[str]
    untestable: dict[str, str]
    static_ok: bool
    static_why: str
    where: Where
    alpha: float = ALPHA
    stochastic: dict[str, JsonObject] = field(default_factory=dict)  # open: each effect's own evidence
    tried: list[Tried] = field(default_factory=list)
    verdict: str = ""
    verdict_text: str = ""
    leftover: Leftover = field(default_factory=Leftover)
    identifiability: TermsDescription | None = None
    confounded_with: dict[str, OrderConfound] = field(default_factory=dict)  # diagnosis/order.py
    order_trend: OrderTrendJson | None = None  # the competitor of every static candidate (order_trend.py)
    headline: Headline | None = None  # fit's held-out figure over the floor (headline.py)

    @property
    def gap_before(self) -> float:
        return self.base.gap

    @property
    def gap_after(self) -> float:
        return self.final.gap

    def to_json(self) -> DiagnosisJson:
        """The JSON of `accelcal diagnose --json`."""
        return to_json(self)


def to_json(d: Diagnosis) -> DiagnosisJson:
    """The JSON of `accelcal diagnose --json` (key order is the output's)."""
    data, fl = d.data, d.floor
    floor_rms = [float(np.sqrt(np.mean(x))) for x in (d.base.floor_static, d.base.floor_time) if x is not None]
    return {
        "verdict": d.verdict, "verdict_text": d.verdict_text, "confounded": d.confounded_with,
        "confounded_with": d.confounded_with, "order_trend": d.order_trend,
        "headline": d.headline,
        "gap_before": d.gap_before, "gap_after": d.gap_after,
        "rms_mg_before": 1e3 * d.base.rms_g, "rms_mg_after": 1e3 * d.final.rms_g,
        "floor_mg": 1e3 * float(np.sqrt(np.mean(np.square(floor_rms)))),
        "floor": {"source": fl.source, "sigma_mg": (1e3 * np.asarray(fl.sigma_g)).tolist(), "lsb_mg": 1e3 * fl.q_g,
                  "pose_scatter_deg": math.degrees(fl.scatter_rad)},
        "selected": d.selected, "steps": d.steps, "tried": d.tried, "ranking": d.ranking,
        "stochastic": d.stochastic, "left": d.leftover, "identifiability": d.identifiability,
        "untestable": [{"effect": e, "reason": r} for e, r in d.untestable.items()],
        "baseline": list(d.sim.baseline), "config": d.sim.source, "config_effects": list(d.sim.enabled),
        "test": {"gap": "held-out residual RMS over the floor's RMS; the floor is fixed before any candidate, so "
                        "only residuals move the gap",
                 "name": "one-sided paired test (min of t-test and Wilcoxon signed-rank, doubled) on per-(pose, axis) "
                         "held-out log predictive density (fixed floor + the fit's prediction variance), "
                         "Bonferroni over the candidates of each step; a candidate must also shrink the held-out RMS "
                         "and min_gap_shrink of some view's log(gap); stop when every view's mean squared "
                         "standardised residual lies in the two-sided 1-alpha range of chi2_N/N",
                 "alpha": d.alpha, "min_gap_shrink": MIN_GAP_SHRINK},
        "data": {"sources": data.sources, "poses": data.P, "references": not data.norm_only,
                 "samples_per_pose_known": data.n_known, "temperatures": data.n_temps,
                 "raw_captures": data.captures is not None, "rate_hz": data.rate_hz, "counts_per_g": data.counts_per_g,
                 "static_view": d.static_ok, "static_view_note": d.static_why or None, "notes": data.notes},
        "where": d.where,
    }

"""The twin's results as records: what `twin fit | check | whatif --json` print, key by key.

TypedDicts, not dataclasses: the `--json` objects are these dicts as built (key order included),
so the printed bytes do not depend on a conversion step; mypy checks every key and value.
The twin's config itself (a station config YAML with ``population:`` replaced) is an open
document (`accelcal_station.jsontypes.JsonObject`): its schema is the station config's.
"""
from __future__ import annotations

from typing import NotRequired, TypeAlias, TypedDict

from ..sim.population import TailConfig


class Summary(TypedDict):
    """One quantity's distribution in a lot (compare._summary)."""

    n: int
    mean: float
    sd: float
    p05: float
    median: float
    p95: float


class Size(TypedDict):
    """A sample size (the joint test's rows)."""

    n: int


class Effect(TypedDict, total=False):
    """A gap's size in the quantity's own units (compare.effect / counts_effect / the energy test):
    which keys are present depends on the test and on whether an acceptance limit judges it."""

    wasserstein: float
    shift_p05: float
    shift_median: float
    shift_p95: float
    limit: str
    limit_value: float
    beyond_limit_real: float
    beyond_limit_sim: float
    yield_change: float
    share_change: dict[str, float]
    largest: str | None
    energy_distance: float
    margin: str
    material: bool


class _Test(TypedDict):
    quantity: str
    test: str
    statistic: float
    p_value: float
    effect: Effect
    detected: NotRequired[bool]  # these three once flagged (compare.flag)
    gap: NotRequired[bool]
    level: NotRequired[float]


class DistributionTest(_Test):
    """A quantity's distribution, real lot against simulated (compare.quantity_test)."""

    real: Summary
    sim: Summary


class CountsTest(_Test):
    """Verdict or reason counts, real against simulated."""

    real: dict[str, int]
    sim: dict[str, int]


class JointTest(_Test):
    """The joint fitted parameters (energy distance): the rows compared."""

    real: Size
    sim: Size


QuantityTest: TypeAlias = DistributionTest | CountsTest | JointTest  # one test of a real lot against a simulated one


class ResidualTest(TypedDict):
    """A residual-check test as `twin fit` reports it."""

    quantity: str
    p_value: float
    detected: bool
    real: Summary
    sim: Summary
    effect: Effect


class Simulated(TypedDict):
    """What a check simulated (simlot.simulate_like)."""

    config: str
    boards: int
    population: bool


class ConfigCheck(TypedDict):
    """One config against the real lot (check.check_config)."""

    config: str
    boards: int
    population: bool
    seed: int
    tests: list[QuantityTest]
    gaps: list[str]
    detected: list[str]
    verdict: str
    false_alarm_rate: float


class Before(TypedDict):
    """The gap before the twin (the default config's check)."""

    config: str
    gaps: list[str]
    detected: list[str]
    verdict: str
    tests: list[QuantityTest]


class CheckReport(TypedDict):
    """`twin check --json`."""

    boards: int
    model: str
    false_alarm_rate: float
    seed: int
    method: str
    before: NotRequired[Before]
    config: str
    tests: list[QuantityTest]
    gaps: list[str]
    detected: list[str]
    verdict: str


class YieldEstimate(TypedDict):
    value: float
    interval: list[float]
    parameter_sd: float


class Failures(TypedDict):
    noise_like: float
    systematic: float
    note: str


class ReasonGrowth(TypedDict):
    reason: str
    before: float
    after: float


class WhatIfReport(TypedDict):
    """`twin whatif --json`."""

    config: str
    seed: int
    simulated_boards: int
    real_boards: int
    limits: dict[str, float]
    first_pass_yield: YieldEstimate
    yield_after_one_retest: YieldEstimate
    failures: Failures
    yield_now: float
    reasons_grow: list[ReasonGrowth]
    interval_note: str
    warnings: list[str]
    real_yield: NotRequired[float]


class Matched(TypedDict):
    lot: float
    twin_before_last_step: float


class NoiseFit(TypedDict, total=False):
    """The per-axis noise fitted to the lot (noise.fit_noise); empty when the lot gives none."""

    stated_sd_counts: list[float]
    fitted_sd_counts: list[float]
    scale: float | None
    matched: dict[str, Matched]
    method: str


class AndersonStat(TypedDict):
    statistic: float
    p_value: float


class PhysicsCandidate(TypedDict):
    """One physics tried by physics.choose_physics: its score and per-measure A-D statistics."""

    physics: str
    score: float
    residual_rms_mg: AndersonStat
    crossval_rms_mg: AndersonStat


class TailCandidate(TypedDict):
    """One quantity's marginal BICs (tails.fit_tails)."""

    quantity: str
    dof: float
    bic_t: float
    bic_gaussian: float
    bic_two_gaussians: float | None
    heavy: bool


class EffectSpread(TypedDict):
    mean: float
    sd: float | None
    scale: float


class ComponentReport(TypedDict):
    """One mixture component as `twin fit` reports it."""

    weight: float
    dof: float | None
    effects: dict[str, EffectSpread]
    carries: list[str]
    differs_in: list[str]


class Criterion(TypedDict):
    name: str
    candidates: list[dict[str, float]]


class PhysicsReport(TypedDict):
    chosen: str
    criterion: str
    candidates: list[PhysicsCandidate]


class TailsReport(TypedDict):
    quantities: dict[str, TailConfig]
    candidates: list[TailCandidate]
    note: str


class ChangeReport(TypedDict):
    quantity: str
    kind: str
    at_board: int
    interval: list[int]
    size: float
    p_value: float


class TwinReport(TypedDict):
    """`twin fit --json` (before its ``out``)."""

    source_boards: int
    model: str
    skipped: int
    criterion: Criterion
    physics: PhysicsReport
    components: list[ComponentReport]
    noise: NoiseFit
    tails: TailsReport
    residual_check: list[ResidualTest]
    warnings: list[str]
    changes: list[ChangeReport]


class TwinFitReport(TwinReport):
    """`twin fit --json`: the twin and the config file written."""

    out: str

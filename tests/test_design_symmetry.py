"""Optimal-N designs agree across machines (issue 41).

The channel-separation criterion (AN4399 section 5) is blind to permuting the axes, flipping
their signs and reordering the poses, so a multistart search may land on any of 48 x N!
equivalent optima, picked by floating-point tie-breaking that differs between machines; its
optimum may also be a flat set (coordinates no channel gap depends on).  What must hold on any
machine, and is tested here:
- the canonical rule maps every symmetric equivalent of a tabled design to the table (to the
  table's rounding, 0.01 deg);
- a search whose start points are turned by a symmetry (what another machine's tie-breaking
  does) writes the tabled design;
- a search from scratch matches the table's quality (minimum channel separation within 1e-4 g,
  the cost of rounding angles to 0.01 deg; predicted standard errors within 1 %) and is the
  same design up to the symmetries (every reading within 0.5 deg).
The symmetry group and the equivalence check below are written here, independently of
fixtures/designs.py.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from accelcal_station.fixtures import designs
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.designs import canonical_angles, get_design, min_separation, predict_stderr
from accelcal_station.fixtures.optimal_table import OPTIMAL

GROUP = [np.diag(s)[list(p)] for p in itertools.permutations(range(3)) for s in itertools.product((1, -1), repeat=3)]
ROUNDING_DEG = 0.015  # the table is written to 0.01 deg; allow the last digit


def _unit(pitch_roll: list[tuple[float, float]]) -> np.ndarray:
    t, r = np.deg2rad(np.asarray(pitch_roll, dtype=float)).T
    return np.stack([-np.sin(t), np.cos(t) * np.sin(r), np.cos(t) * np.cos(r)], axis=1)  # AN4399 Eqn 22


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise angles (deg) between the rows of a and b."""
    return np.rad2deg(np.arccos(np.clip(a @ b.T, -1.0, 1.0)))


def _distance_up_to_symmetry(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest, over the 48 signed axis permutations and every pairing of poses, of the
    largest angle between paired readings (deg)."""
    best = np.inf
    for g in GROUP:
        d = _angle_deg(a @ g.T, b)
        i, j = linear_sum_assignment(d)
        best = min(best, float(d[i, j].max()))
    return best


def _angles(design: list[PoseSpec]) -> list[tuple[float, float]]:
    return [(p.pitch_deg, p.roll_deg) for p in design]


def test_the_group_has_48_distinct_elements():
    assert len({g.tobytes() for g in GROUP}) == 48 and len({g.tobytes() for g in designs.SYMMETRIES}) == 48


@pytest.mark.parametrize("n", sorted(OPTIMAL))
def test_every_symmetric_equivalent_of_a_tabled_design_maps_to_the_table(n):
    table = _unit(list(OPTIMAL[n]))
    rng = np.random.default_rng(n)
    for g in GROUP:
        turned = (table @ g.T)[rng.permutation(n)]
        got = _unit(canonical_angles(turned))
        # the same poses, each to the table's rounding (not merely an equivalent design)
        d = _angle_deg(got, table)
        i, j = linear_sum_assignment(d)
        assert d[i, j].max() <= ROUNDING_DEG, (n, g.tolist())


def test_the_issues_case_optimal_5_turned_90_deg_in_roll():
    """Another machine gave optimal-5 with every roll shifted by -90 deg: the same design."""
    turned = [(t, (r - 90.0 + 180.0) % 360.0 - 180.0) for t, r in OPTIMAL[5]]
    assert _distance_up_to_symmetry(_unit(turned), _unit(list(OPTIMAL[5]))) < 1e-9
    got = canonical_angles(_unit(turned))
    assert np.max(np.abs(np.subtract(got, OPTIMAL[5]))) <= 0.011


def _turned_search(n: int, k: int, monkeypatch: pytest.MonkeyPatch) -> list[PoseSpec]:
    """The multistart search with every start point turned by the symmetry GROUP[k]: the search
    then lands on a turned optimum, as on a machine whose floating point breaks ties the other way."""
    g = GROUP[k]
    start = designs._start
    monkeypatch.setattr(designs, "_start", lambda m, rng: start(m, rng) @ g.T)
    return list(designs.optimal_design.__wrapped__(n))


@pytest.mark.parametrize("n", [3, 5])
@pytest.mark.parametrize("k", [5, 21, 40])
def test_a_search_that_lands_on_another_symmetric_optimum_writes_the_table(n, k, monkeypatch):
    got = _turned_search(n, k, monkeypatch)
    d = _angle_deg(_unit(_angles(got)), _unit(list(OPTIMAL[n])))
    i, j = linear_sum_assignment(d)
    assert d[i, j].max() <= ROUNDING_DEG


@pytest.mark.parametrize("k", [5, 21, 40])
def test_a_turned_search_that_finds_another_local_optimum_is_as_good(k, monkeypatch):
    """optimal-4's turned searches mostly stop at a neighbouring local optimum (0.50788 g against
    the table's 0.50794 g): not the same design, but equally good to the stated tolerance."""
    got = _turned_search(4, k, monkeypatch)
    assert min_separation(got) == pytest.approx(min_separation(get_design("optimal-4")), abs=1e-4)


@pytest.mark.parametrize("n", [3, 4, 5])
def test_a_search_from_scratch_matches_the_table_in_quality_and_up_to_symmetry(n):
    got = list(designs.optimal_design.__wrapped__(n))
    table = get_design(f"optimal-{n}")
    assert min_separation(got) == pytest.approx(min_separation(table), abs=1e-4)
    model = "12" if n >= 4 else "6"
    se_got = predict_stderr(got, model, 1e-3)["params"]
    se_tab = predict_stderr(table, model, 1e-3)["params"]
    # per-parameter standard errors are permuted by the symmetry: compare them as sorted sets
    np.testing.assert_allclose(np.sort(se_got), np.sort(se_tab), rtol=0.01)
    assert _distance_up_to_symmetry(_unit(_angles(got)), _unit(_angles(table))) <= 0.5


def test_canonical_form_does_not_depend_on_pose_order_or_float_noise():
    rng = np.random.default_rng(7)
    table = _unit(list(OPTIMAL[8]))
    noisy = table + rng.normal(scale=1e-10, size=table.shape)
    assert canonical_angles(noisy[rng.permutation(8)]) == canonical_angles(table)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_tie_between_distinct_optima_is_not_broken_by_float_noise(seed, monkeypatch):
    """optimal-4 has two optima not related by a symmetry (two rolls flip sign) whose separations
    tie to 1e-16 g; which start wins used to depend on the machine's last digits (seen under
    OPENBLAS_CORETYPE=Prescott with numpy's AVX2 dispatch off).  Another machine's digits are
    simulated by 1e-13 noise on every polished design: the tabled design must still come out."""
    rng = np.random.default_rng(seed)
    polish = designs._polish

    def noisy(u0: np.ndarray) -> np.ndarray:
        u = polish(u0) + rng.normal(scale=1e-13, size=u0.shape)
        return u / np.linalg.norm(u, axis=1, keepdims=True)

    monkeypatch.setattr(designs, "_polish", noisy)
    got = _unit(_angles(list(designs.optimal_design.__wrapped__(4))))
    d = _angle_deg(got, _unit(list(OPTIMAL[4])))
    i, j = linear_sum_assignment(d)
    assert d[i, j].max() <= ROUNDING_DEG

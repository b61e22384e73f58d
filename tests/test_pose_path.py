"""The station visits a design's poses along the shortest path on rotation angle (issue 51)."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from accelcal_station.conventions import pose_attitude
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.designs import get_design
from accelcal_station.fixtures.pose_path import path_angle_deg, shortest_order


def angle(a: PoseSpec, b: PoseSpec) -> float:
    """The rotation angle between two placements, from the trace (computed here apart from the module)."""
    r = pose_attitude(a.pitch_deg, a.roll_deg).T @ pose_attitude(b.pitch_deg, b.roll_deg)
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


@pytest.mark.parametrize("design", ["an4399-8", "an4399-6", "six-face", "an4399-4"])
def test_every_pose_once_no_longer_than_the_designs_order(design):
    poses = get_design(design)
    order = shortest_order(None, poses)
    assert sorted(p.name for p in order) == sorted(p.name for p in poses)
    assert path_angle_deg(None, order) <= path_angle_deg(None, poses) + 1e-9
    assert shortest_order(None, poses) == order  # deterministic


def test_exact_for_small_designs_against_every_permutation():
    poses = get_design("an4399-6")
    home = PoseSpec("home", 0.0, 0.0)

    def length(seq):
        s = [home, *seq]
        return sum(angle(a, b) for a, b in zip(s, s[1:], strict=False))

    best = min(length(p) for p in itertools.permutations(poses))
    assert length(shortest_order(None, poses)) == pytest.approx(best, abs=1e-6)


def test_large_designs_use_two_opt_and_keep_every_pose():
    poses = get_design("an4399-8") + [
        PoseSpec(f"q{i}", 10.0 * i, 25.0 * i) for i in range(5)]
    order = shortest_order(poses[0], poses[1:])
    assert len(order) == len(poses) - 1 and len({p.name for p in order}) == len(order)
    assert path_angle_deg(poses[0], order) <= path_angle_deg(poses[0], poses[1:]) + 1e-9


def test_starts_from_where_the_jig_stands():
    poses = get_design("an4399-8")[:3]
    here = poses[1]
    assert shortest_order(here, poses)[0] == here  # no move at all for the first

"""Issue 53: the unit and pose conventions pinned to outside values, each written here from its
source: AN4399 Eqn 22 (expected output of pitch/roll) and Eqns 25-26 (angles back), CODATA's
standard gravity 9.80665 m/s^2 and the Earth's 9.780-9.832 m/s^2 range, the data sheets'
"top side up reads +1 g on Z", and the 24 proper rotations of a cube."""
from __future__ import annotations

import math

import numpy as np
import pytest

from accelcal_station.conventions import (
    all_mounts,
    an4399_reference,
    angle_deg,
    attitude_for_up,
    check_units,
    fit_mount,
    mount_hint,
    mount_label,
    mount_matrix,
    mount_turn_words,
    nearest_face,
    placement_words,
    pose_attitude,
    reference_to_angles,
    specific_force_g,
    units_per_g,
    up_direction,
)
from accelcal_station.errors import UnitsError

S = math.sqrt(0.5)


@pytest.mark.parametrize("pitch,roll,want", [
    (0, 0, (0, 0, 1)), (90, 0, (-1, 0, 0)), (-90, 0, (1, 0, 0)), (0, 90, (0, 1, 0)), (0, -90, (0, -1, 0)),
    (0, 180, (0, 0, -1)), (45, 0, (-S, 0, S)), (0, 45, (0, S, S)), (30, 60, (-0.5, 0.75, math.sqrt(3) / 4)),
])
def test_an4399_eqn22_and_back(pitch, roll, want):
    r = an4399_reference(pitch, roll)
    np.testing.assert_allclose(r, want, atol=1e-12)
    if abs(pitch) < 90:  # roll is undefined at +-90 deg pitch
        p, q = reference_to_angles(np.array(want) * 2.5)  # any length: the angles of its direction
        assert (float(p), float(q)) == pytest.approx((pitch, roll), abs=1e-9)


def test_an4399_reference_is_vectorised():
    r = an4399_reference([0, 90], [0, 0])
    assert r.shape == (2, 3)
    np.testing.assert_allclose(r, [[0, 0, 1], [-1, 0, 0]], atol=1e-12)
    assert an4399_reference(0, [0, 90, 180]).shape == (3, 3)


def test_units_scales():
    assert units_per_g("g") == 1.0
    assert units_per_g("mps2") == 9.80665  # standard gravity (CGPM 1901)
    assert units_per_g("mps2", gravity_mps2=9.780) == 9.780 and units_per_g("mps2", gravity_mps2=9.832) == 9.832
    assert units_per_g("mps2", gravity_mps2=9.7) == 9.7 and units_per_g("mps2", gravity_mps2=9.9) == 9.9
    assert units_per_g("counts", counts_per_g=4096) == 4096.0  # MMA8451Q at +-2 g, 14 bit
    assert units_per_g("counts", counts_per_g=1e-9) == 1e-9
    for bad in ({"gravity_mps2": 9.69}, {"gravity_mps2": 9.91}, {"gravity_mps2": math.nan}):
        with pytest.raises(UnitsError, match="implausible; allowed 9.7 to 9.9"):
            units_per_g("mps2", **bad)
    for bad in (0, -4096, math.inf, math.nan):
        with pytest.raises(UnitsError, match="must be a positive number"):
            units_per_g("counts", counts_per_g=bad)
    with pytest.raises(UnitsError, match="counts need --counts-per-g"):
        units_per_g("counts")
    with pytest.raises(UnitsError, match="unknown units 'G'; allowed: counts, g, mps2"):
        units_per_g("G")
    assert check_units("counts") == "counts"


def test_physics_top_side_up_reads_plus_one_g_on_z():
    """MMA8451Q / MPU-6050: flat, component side up, the chip reads +1 g on Z."""
    np.testing.assert_allclose(specific_force_g(np.eye(3)), [0, 0, 1])
    np.testing.assert_allclose(specific_force_g(pose_attitude(0, 0)), [0, 0, 1], atol=1e-15)
    for pitch, roll in ((30, 60), (-50, 170), (90, 0), (10, -100)):
        np.testing.assert_allclose(specific_force_g(pose_attitude(pitch, roll)), an4399_reference(pitch, roll),
                                   atol=1e-12)
    np.testing.assert_allclose(up_direction([0, 0, -2.0]), [0, 0, -1])
    for up in ([0, 0, 1], [0, 0, -1], [1, 2, -3], [0.3, -0.2, 0.9]):
        R = attitude_for_up(up)
        np.testing.assert_allclose(R @ up_direction(up), [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    # the smallest rotation: a quarter tilt turns by 90 deg, not more
    R = attitude_for_up([1, 0, 0])
    assert math.degrees(math.acos((np.trace(R) - 1) / 2)) == pytest.approx(90.0)


def test_faces_and_words():
    assert nearest_face([0.1, -0.2, 0.97]).startswith("z+ up")
    assert nearest_face([-0.9, 0.3, 0.1]).startswith("x- up")
    assert nearest_face([0, -1, 0]).startswith("y- up")
    assert placement_words([0, 0, 1]) == "z+ up: lay it flat, component side up"
    assert placement_words([0, 0, 1.0]) == placement_words(an4399_reference(2, 0))  # within 3 deg: the face
    w = placement_words(an4399_reference(0, 45))  # roll 45: up halfway between +z and +y
    assert w.endswith("then tilt it 45 deg raising its +y side"), w
    w = placement_words([1, 1, 1])  # a cube vertex: 55 deg from the nearest face, raising a corner
    assert "tilt it 55 deg raising its" in w and "corner" in w, w
    assert placement_words([0, 0, 1], tr=str.upper) == "Z+ UP: LAY IT FLAT, COMPONENT SIDE UP"
    assert angle_deg([1, 0, 0], [0, 2, 0]) == pytest.approx(90.0)
    assert angle_deg([1, 0, 0], [-3, 0, 0]) == pytest.approx(180.0)
    assert angle_deg([1, 1, 0], [1, 0, 0]) == pytest.approx(45.0)


def test_the_24_mountings():
    m = all_mounts()
    assert m.shape == (24, 3, 3)
    np.testing.assert_array_equal(m[0], np.eye(3))
    assert len({tuple(p.ravel()) for p in m}) == 24
    assert np.allclose(np.linalg.det(m), 1.0)
    for p in m:
        assert mount_matrix(mount_label(p)).tolist() == p.tolist()
    np.testing.assert_array_equal(mount_matrix(["y", "-x", "z"]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert mount_label(mount_matrix(["+y", "-x", "z"])) == ["y", "-x", "z"]
    for bad, why in ((["x", "y"], "needs three chip axes"), (["x", "y", "w"], "allowed x, y, z"),
                     (["x", "--y", "z"], "allowed x, y, z"), (["y", "x", "z"], "not a proper rotation"),
                     (["x", "x", "z"], "not a proper rotation")):
        with pytest.raises(ValueError, match=why):
            mount_matrix(bad)


def test_turn_words():
    assert mount_turn_words(np.eye(3)) == "not turned"
    assert mount_turn_words(mount_matrix(["y", "-x", "z"])) == "turned 90 deg about z"
    assert mount_turn_words(mount_matrix(["-y", "x", "z"])) == "turned -90 deg about z"
    assert mount_turn_words(mount_matrix(["-x", "-y", "z"])) == "turned 180 deg about z"
    assert mount_turn_words(mount_matrix(["x", "-y", "-z"])) == "turned 180 deg about x"


def test_fit_mount_and_hint():
    refs = an4399_reference([0, 90, 0, -35], [0, 0, 90, 45])
    P = mount_matrix(["y", "-x", "z"])
    got, worst, unique = fit_mount(refs, refs @ P.T)
    np.testing.assert_array_equal(got, P)
    assert worst == pytest.approx(0.0, abs=1e-6) and unique
    # one flat pose cannot tell a turn about z: the smallest turn (none) among those that fit
    got, worst, unique = fit_mount([[0, 0, 1]], [[0, 0, 1]])
    np.testing.assert_array_equal(got, np.eye(3))
    assert not unique
    assert mount_hint(refs, refs) is None  # fits as configured
    hint = mount_hint([[1, 0, 0]], [[0, 1, 0]])
    assert hint is not None and hint.startswith("reads +y where the pose expects +x: the board looks turned")
    assert hint.endswith("(the smallest turn that fits); set device.mount: [y, -x, z]"), hint
    hint = mount_hint(refs, refs @ P.T, key="device.boards[2].mount")
    assert hint is not None and "poses expect" in hint and "turned 90 deg about z; set device.boards[2].mount: " \
        "[y, -x, z]" in hint, hint
    assert mount_hint(refs, -refs + [0.5, 0.3, 0.1]) is None  # nothing of the 24 fits within 15 deg


def test_directions_of_many_poses_and_the_fifth_of_a_length_rule():
    from accelcal_station.conventions import _signed_axes

    np.testing.assert_allclose(up_direction([[0, 0, 2.0], [3.0, 0, 4.0]]), [[0, 0, 1], [0.6, 0, 0.8]])
    y = np.sqrt(1 - 0.04)
    assert _signed_axes(np.array([0.2, y, 0.0])) == "+y"  # exactly a fifth of its length: not leaning along x
    assert _signed_axes(np.array([0.21, y, 0.0])) == "+x+y"
    assert _signed_axes(np.array([-0.5, 0.0, -0.5])) == "-x-z"

"""The pose table: exact round trip, metadata vs arguments, and one-line errors."""
from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accelcal_station.conventions import an4399_reference
from accelcal_station.data.posetable import read_pose_table, write_pose_table
from accelcal_station.errors import DataError, UnitsError
from accelcal_station.session import PoseRecord, Session

HEADER = "pose,pitch_deg,roll_deg,x,y,z"


def _write(tmp_path, text, name="t.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _assert_same(a: Session, b: Session):
    assert (a.units, a.counts_per_g, a.gravity_mps2, a.device) == (b.units, b.counts_per_g, b.gravity_mps2, b.device)
    assert a.metadata == b.metadata
    assert len(a) == len(b)
    for p, q in zip(a.poses, b.poses, strict=True):
        assert p.name == q.name
        assert np.array_equal(p.mean, q.mean)
        for f in ("std", "reference_g"):
            u, v = getattr(p, f), getattr(q, f)
            assert (u is None) == (v is None) and (u is None or np.array_equal(u, v)), f
        assert (p.n, p.pitch_deg, p.roll_deg, p.temp_c) == (q.n, q.pitch_deg, q.roll_deg, q.temp_c)


def test_round_trip_is_exact(tmp_path):
    poses = [
        PoseRecord("a", [-2434.354, -977.106, -2937.402], [3.1, 2.9, 4.0], 200, an4399_reference(39, -158), 39.0,
                   -158.0, 24.75),
        PoseRecord("b", [1 / 3, 2e-17, -1e300], None, None, [0.1, -0.2, 0.97], None, None, 85.0),
        PoseRecord("c, with comma", [1.0, 2.0, 3.0], [0.0, 0.5, 1.5], 7, an4399_reference(12.5, 0), 12.5, 0.0),
        PoseRecord("d", [4.0, 5.0, 6.0]),  # reference-free (model 9) pose
    ]
    s = Session(poses, "mps2", None, 9.80123, "mma8451", {"lot": "L42", "operator": "kim"})
    path = tmp_path / "rt.csv"
    write_pose_table(s, path)
    back = read_pose_table(path)
    _assert_same(s, back)
    write_pose_table(back, tmp_path / "rt2.csv")
    assert (tmp_path / "rt2.csv").read_text() == path.read_text()  # a fixed point


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.tuples(finite, finite, finite), st.one_of(st.none(), st.floats(-200, 300)),
                          st.one_of(st.none(), st.integers(1, 10**9))), min_size=1, max_size=6))
def test_round_trip_property(tmp_path_factory, rows):
    poses = [PoseRecord(f"p{i}", m, None, n, None, None, None, t) for i, (m, t, n) in enumerate(rows)]
    s = Session(poses, "counts", 16384.0)
    path = tmp_path_factory.mktemp("rt") / "p.csv"
    write_pose_table(s, path)
    _assert_same(s, read_pose_table(path))


def test_metadata_used_and_arguments_override(tmp_path):
    p = _write(tmp_path, "# device: mpu6050\n# units: counts\n# counts_per_g: 16384\n# station: line-3\n"
                         "# a plain comment\n" + HEADER + "\nq,0,0,1,2,16384\n")
    s = read_pose_table(p)
    assert (s.units, s.counts_per_g, s.device, s.metadata) == ("counts", 16384.0, "mpu6050", {"station": "line-3"})
    s2 = read_pose_table(p, units="counts", counts_per_g=8192)
    assert s2.counts_per_g == 8192
    s3 = read_pose_table(p, units="g")
    assert s3.units == "g"
    g = _write(tmp_path, "# units: mps2\n# gravity: 9.79\n" + HEADER + "\nq,0,0,0,0,9.79\n", "g.csv")
    assert read_pose_table(g).gravity_mps2 == 9.79
    assert read_pose_table(g, gravity_mps2=9.81).gravity_mps2 == 9.81
    assert read_pose_table(g).input_per_g == 9.79


def test_references_from_angles_and_ref_columns_override(tmp_path):
    p = _write(tmp_path, "# counts_per_g: 4096\n" + HEADER + ",ref_x,ref_y,ref_z\n"
                         "a,39,-158,1,2,3,,,\n"
                         "b,39,-158,1,2,3,0,0,-1\n"
                         "c,,,1,2,3,1,0,0\n"
                         "d,,,1,2,3,,,\n")
    s = read_pose_table(p)
    assert np.array_equal(s.poses[0].reference_g, an4399_reference(39, -158))
    assert np.array_equal(s.poses[1].reference_g, [0, 0, -1])  # overrides the angles
    assert s.poses[1].pitch_deg == 39
    assert np.array_equal(s.poses[2].reference_g, [1, 0, 0])
    assert s.poses[3].reference_g is None and not s.has_references
    with pytest.raises(DataError, match=r"t\.csv: line 6, column pitch_deg: pose 'd' has no reference"):
        read_pose_table(p, references=True)


def test_optional_pitch_roll_columns_and_comment_rows(tmp_path):
    p = _write(tmp_path, "pose,x,y,z,temp_c,n,std_x,std_y,std_z\n"
                         "a,1,2,3,20.5,100,1,1,1\n"
                         "\n"
                         "# b,9,9,9,20,1,1,1,1\n"
                         "c,4,5,6,,,,,\n")
    s = read_pose_table(p)
    assert s.names == ["a", "c"]
    assert s.poses[0].temp_c == 20.5 and s.poses[0].n == 100 and s.poses[1].std is None
    assert s.temps_c is None  # one pose has no temperature


@pytest.mark.parametrize("text, match", [
    ("", r"empty: no header"),
    ("# units: counts\n\n", r"empty: no header"),
    ("pose,x,y,x\n", r"line 1: column 'x' appears twice"),
    ("pose,x,y\n", r"line 1: missing column 'z'"),
    ("pose,pitch_deg,x,y,z\n", r"line 1: missing column 'roll_deg'"),
    ("pose,x,y,z,ref_x,ref_y\n", r"line 1: missing column 'ref_z'"),
    ("pose,x,y,z,colour\n", r"line 1: unknown column 'colour'; allowed: pose"),
    (HEADER + "\n", r"no pose rows"),
    (HEADER + "\na,0,0,1,2,nan\n", r"line 2, column z: 'nan'; allowed: a finite number"),
    (HEADER + "\na,0,0,1,2,inf\n", r"line 2, column z: 'inf'; allowed: a finite number"),
    (HEADER + "\na,0,0,1,two,3\n", r"line 2, column y: 'two' is not a number"),
    (HEADER + "\na,0,0,1,,3\n", r"line 2, column y: empty"),
    (HEADER + "\na,0,0,1,2\n", r"line 2: 5 fields; the header has 6"),
    (HEADER + "\n,0,0,1,2,3\n", r"line 2, column pose: empty"),
    (HEADER + "\na,10,,1,2,3\n", r"line 2, column roll_deg: empty while pitch_deg, roll_deg are partly given"),
    ("pose,x,y,z,n\n\na,1,2,3,2.5\n", r"line 3, column n: '2.5'; allowed: a whole number"),
    ("pose,x,y,z,std_x,std_y,std_z\na,1,2,3,1,-1,1\n", r"line 2, column std_y: '-1' out of range"),
    ("pose,x,y,z,ref_x,ref_y,ref_z\na,1,2,3,0,0,0\n", r"line 2, column ref_x: the reference is \(0, 0, 0\)"),
])
def test_errors_name_file_line_and_column(tmp_path, text, match):
    p = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as e:
        read_pose_table(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and "\n" not in msg


def test_units_errors(tmp_path):
    p = _write(tmp_path, "# units: furlongs\n" + HEADER + "\na,0,0,1,2,3\n")
    with pytest.raises(UnitsError, match=r"t\.csv: line 1: unknown units 'furlongs'; allowed: counts, g, mps2"):
        read_pose_table(p)
    assert read_pose_table(p, units="g").units == "g"  # the argument wins over bad metadata
    q = _write(tmp_path, "# counts_per_g: lots\n" + HEADER + "\na,0,0,1,2,3\n", "q.csv")
    with pytest.raises(UnitsError, match=r"q\.csv: line 1: counts_per_g: 'lots'; allowed: a positive number"):
        read_pose_table(q)


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(DataError, match=r"nope\.csv: cannot read"):
        read_pose_table(tmp_path / "nope.csv")
    b = tmp_path / "b.csv"
    b.write_bytes(b"\xff\xfe\x00\x81binary")
    with pytest.raises(DataError, match="not a text file"):
        read_pose_table(b)


def test_write_is_atomic_and_refuses_bad_sessions(tmp_path):
    path = tmp_path / "keep.csv"
    path.write_text("old contents\n")
    bad = Session([PoseRecord("a", [1, 2, 3]), PoseRecord("b", [1, np.nan, 3])], "g")
    with pytest.raises(DataError, match=r"pose 'b': y is not finite"):
        write_pose_table(bad, path)
    assert path.read_text() == "old contents\n"
    assert os.listdir(tmp_path) == ["keep.csv"]  # no temporary file left behind
    with pytest.raises(DataError, match="pose name '#x'"):
        write_pose_table(Session([PoseRecord("#x", [1, 2, 3])], "g"), path)
    with pytest.raises(DataError, match="cannot write"):
        write_pose_table(Session([PoseRecord("a", [1, 2, 3])], "g"), tmp_path / "no" / "dir.csv")
    assert os.listdir(tmp_path) == ["keep.csv"]

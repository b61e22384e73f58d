"""A large pose table is held as columns (session.PoseColumns): every figure a Session gives and every
fit are exactly those of the same poses held as PoseRecords (the list path is the reference)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from accelcal_station.api import fit
from accelcal_station.data.loader import load_pose_table
from accelcal_station.data.posetable import COLUMNS_FROM_ROWS, read_pose_table
from accelcal_station.session import PoseColumns, Session


def _table(path: Path, n: int, offset: float = 0.0, seed: int = 4, every: int = 7) -> Path:
    """Random orientations of a sensor with gain, cross-axis and offset (counts); every 7th row gives no
    std/n and carries pitch/roll instead of ref_* (both kinds of rows, as a table may mix them)."""
    rng = np.random.default_rng(seed)
    pitch, roll = rng.uniform(-89, 89, n), rng.uniform(-180, 180, n)
    th, ph = np.radians(pitch), np.radians(roll)
    ref = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)])
    counts = (ref @ (np.eye(3) + rng.normal(0, 0.01, (3, 3))).T + 0.02) * 4096 + rng.normal(0, 2, (n, 3)) + offset
    with path.open("w") as f:
        f.write("# counts_per_g: 4096\npose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,n,std_x,std_y,std_z\n")
        for i in range(n):
            x = ",".join(repr(float(v)) for v in counts[i])
            if every == 0 or i % every:
                r = ",".join(repr(float(v)) for v in ref[i])
                f.write(f"p{i},,,{x},{r},100,5,5,5\n")
            else:
                f.write(f"p{i},{float(pitch[i])!r},{float(roll[i])!r},{x},,,,,,,\n")
    return path


def _as_records(s: Session) -> Session:
    return Session(list(s.poses), s.units, s.counts_per_g, s.gravity_mps2, s.device, dict(s.metadata))


def test_columns_give_what_the_records_give(tmp_path):
    s = read_pose_table(_table(tmp_path / "t.csv", COLUMNS_FROM_ROWS), references=True)
    assert isinstance(s.poses, PoseColumns)
    r = _as_records(s)
    assert s.names == r.names and len(s) == len(r) == COLUMNS_FROM_ROWS
    for a, b in ((s.readings, r.readings), (s.references_g, r.references_g), (s.readings_g(), r.readings_g())):
        np.testing.assert_array_equal(a, b)
    assert s.noise() is None and r.noise() is None  # some rows give no std: no per-pose noise, either way
    assert s.temps_c is None and r.temps_c is None
    p = s.poses[-1]
    assert p.name == f"p{COLUMNS_FROM_ROWS - 1}" and p.n == 100 and p.pitch_deg is None and p.std is not None
    assert s.poses[0].std is None and s.poses[0].n is None and s.poses[0].pitch_deg is not None
    with pytest.raises(IndexError):
        s.poses[COLUMNS_FROM_ROWS]
    for model in ("12", "15"):
        a, b = fit(s, model).result, fit(r, model).result
        np.testing.assert_array_equal(a.W, b.W)
        np.testing.assert_array_equal(a.residuals_g, b.residuals_g)


def test_offset_binary_counts_are_shifted_in_the_columns(tmp_path):
    """Unsigned counts (every reading near mid-scale 32768) lose their offset as a list of records would."""
    path = _table(tmp_path / "u.csv", COLUMNS_FROM_ROWS, offset=32768.0)
    loaded = load_pose_table(path)
    assert loaded.units.offset_counts == 32768.0 and isinstance(loaded.session.poses, PoseColumns)
    raw = _as_records(read_pose_table(path))
    np.testing.assert_array_equal(loaded.session.readings, raw.readings - 32768.0)


def test_a_small_table_is_records_one_can_change(tmp_path):
    s = read_pose_table(_table(tmp_path / "s.csv", 50))
    assert isinstance(s.poses, list)
    s.poses[0].reference_g = None
    assert not s.has_references


def test_noise_of_columns_is_that_of_the_records(tmp_path):
    s = read_pose_table(_table(tmp_path / "n.csv", COLUMNS_FROM_ROWS, every=0))
    assert isinstance(s.poses, PoseColumns)
    nz, ref = s.noise(), _as_records(s).noise()
    assert nz is not None and ref is not None
    np.testing.assert_array_equal(nz, ref)
    np.testing.assert_allclose(nz, 0.5)  # std 5 over sqrt(100) samples

"""Calibration files across versions: a file from every format version ever shipped loads (each
written here by hand as that version's accelcal wrote it, not by today's writer), and a file from
a newer accelcal is refused in one line naming its version and the newest this one reads."""
from __future__ import annotations

import json

import numpy as np
import pytest

from accelcal_station.calibration import SCHEMA_VERSION, Calibration
from accelcal_station.errors import DataError

# Format 1, as the first release wrote it (git show e92be2e:accelcal_station/calibration.py,
# Calibration.to_dict + json.dumps(indent=2)): a model 12 fit in counts at 4096 counts/g.
V1_COUNTS = """{
  "schema": "accelcal.calibration",
  "version": 1,
  "model": "12",
  "input_units": "counts",
  "input_per_g": 4096.0,
  "W": [
    [1.02, 0.01, 0.0],
    [0.0, 0.98, -0.02],
    [0.0, 0.0, 1.0]
  ],
  "V": [0.05, -0.03, 0.01],
  "Gamma": [0.0, 0.0, 0.0],
  "temperature": null,
  "metadata": {"serial": "SN-0001", "station": "line-2"}
}
"""

# Format 1 with an AN4399 section 9 table (linear in temperature, two calibration temperatures);
# Gamma left out at the top level, as a reader of format 1 allows.
V1_TABLE = """{
  "schema": "accelcal.calibration",
  "version": 1,
  "model": "15",
  "input_units": "g",
  "input_per_g": 1.0,
  "W": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
  "V": [0, 0, 0],
  "temperature": {
    "method": "linear",
    "temps_c": [0.0, 50.0],
    "W": [[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]], [[1.1, 0, 0], [0, 1.0, 0], [0, 0, 0.9]]],
    "V": [[0.0, 0.0, 0.0], [0.02, 0.0, -0.04]],
    "Gamma": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.002]]
  },
  "metadata": {}
}
"""

# every format version ever shipped, each with a hand-written file of it
LEGACY = {1: [V1_COUNTS, V1_TABLE]}


def test_every_shipped_version_has_a_file_here():
    """A new format version must add a hand-written file of the one it replaces."""
    assert set(LEGACY) == set(range(1, SCHEMA_VERSION + 1))


def test_v1_counts_file_loads_and_applies(tmp_path):
    p = tmp_path / "cal.json"
    p.write_text(V1_COUNTS)
    cal = Calibration.load(p)
    assert cal.model == "12" and cal.counts_per_g == 4096.0 and cal.metadata["serial"] == "SN-0001"
    # 4096 counts on z and 2048 on x: G_f = (0.5, 0, 1) g; G = W G_f + V by hand
    out = cal.apply([2048.0, 0.0, 4096.0], units="counts")
    np.testing.assert_allclose(out, [1.02 * 0.5 + 0.05, -0.02 - 0.03, 1.0 + 0.01], rtol=0, atol=1e-12)


def test_v1_table_file_interpolates(tmp_path):
    p = tmp_path / "table.json"
    p.write_text(V1_TABLE)
    cal = Calibration.load(p)
    # at 25 C, half way: W diag (1.05, 1, 0.95), V (0.01, 0, -0.02), Gamma z 0.001; reading (0, 0, 1) g
    np.testing.assert_allclose(cal.apply([0.0, 0.0, 1.0], units="g", temp_c=25.0), [0.01, 0.0, 0.95 - 0.02 + 0.001],
                               rtol=0, atol=1e-12)


def test_todays_file_is_the_newest_version_and_round_trips(tmp_path):
    cal = Calibration.load(_written(tmp_path, V1_TABLE))
    p = tmp_path / "again.json"
    cal.save(p)
    d = json.loads(p.read_text())
    assert d["version"] == SCHEMA_VERSION
    again = Calibration.load(p)
    for t in (0.0, 12.5, 50.0):
        np.testing.assert_array_equal(again.apply([0.1, -0.2, 0.97], units="g", temp_c=t),
                                      cal.apply([0.1, -0.2, 0.97], units="g", temp_c=t))


def _written(tmp_path, text):
    p = tmp_path / "given.json"
    p.write_text(text)
    return p


def test_a_newer_file_is_one_clear_line(tmp_path):
    newer = json.loads(V1_COUNTS) | {"version": SCHEMA_VERSION + 1, "W_extra": "a field from the future"}
    p = tmp_path / "newer.json"
    p.write_text(json.dumps(newer))
    with pytest.raises(DataError) as e:
        Calibration.load(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg
    assert f"written by a newer accelcal (calibration format version {SCHEMA_VERSION + 1})" in msg
    assert f"reads up to version {SCHEMA_VERSION}" in msg and e.value.exit_code == 2


@pytest.mark.parametrize("version", [0, -1, "1", 1.0, True, None])
def test_a_version_no_accelcal_wrote_is_refused(tmp_path, version):
    d = json.loads(V1_COUNTS) | {"version": version}
    with pytest.raises(DataError, match="calibration version") as e:
        Calibration.from_dict(d, "cal.json")
    assert "\n" not in str(e.value)


def test_an_nvm_backup_from_a_newer_accelcal_is_one_clear_line(tmp_path):
    """`accelcal nvm restore` of a backup file whose format is newer than this accelcal reads: one
    line naming both versions, nothing written (the board's NVM read back unchanged)."""
    from click.testing import CliRunner

    from accelcal_station.cli import cli
    from accelcal_station.nvm.image_file import IMAGE_VERSION

    backup = tmp_path / "b.json"
    r = CliRunner().invoke(cli, ["nvm", "backup", "--out", str(backup)])
    assert r.exit_code == 0, r.output
    doc = json.loads(backup.read_text())
    doc["version"] = IMAGE_VERSION + 1
    backup.write_text(json.dumps(doc))
    r = CliRunner().invoke(cli, ["nvm", "restore", str(backup), "--backup-to", str(tmp_path / "before.json")])
    assert r.exit_code != 0 and len(r.output.strip().splitlines()) == 1, r.output
    assert f"written by a newer accelcal (NVM backup format version {IMAGE_VERSION + 1})" in r.output
    assert f"reads up to version {IMAGE_VERSION}" in r.output
    assert not (tmp_path / "before.json").exists()  # refused before anything was read or written

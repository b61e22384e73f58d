"""Bounded resources (issue 26): `fit` memory linear in the pose count; `simulate --raw` streams.

The full-size figures (fit on 100,000 rows, simulate --raw of 1e7 samples, peak RSS in a child)
are measured by benchmarks/bench_resources.py; these tests are the fast, scaled versions.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np

from accelcal_station import api
from accelcal_station.conventions import an4399_reference
from accelcal_station.identifiability import first_of_orientation


def write_table(path: Path, n: int, seed: int = 1) -> Path:
    """n poses in random orientations of a sensor with gain/cross-axis/offset errors and noise."""
    rng = np.random.default_rng(seed)
    pitch, roll = rng.uniform(-89, 89, n), rng.uniform(-180, 180, n)
    th, ph = np.radians(pitch), np.radians(roll)
    ref = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)])
    assert np.allclose(ref[0], an4399_reference(pitch[0], roll[0]))  # the convention, checked once
    K = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    counts = (ref @ K.T + 0.02) * 4096 + rng.normal(0, 2, (n, 3))
    body = np.column_stack([pitch, roll, counts, ref])
    lines = ["# units: counts", "# counts_per_g: 4096",
             "pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,n,std_x,std_y,std_z"]
    lines += [f"p{i}," + ",".join(repr(float(v)) for v in row) + ",100,5,5,5" for i, row in enumerate(body)]
    path.write_text("\n".join(lines) + "\n")
    return path


def fit_peak_mb(path: Path) -> float:
    """Peak traced memory (MB) of loading and fitting a pose table, beyond what was held before."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        res = api.fit(path)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert res.result.pose_count > 0 and res.result.residual_rms_g < 2e-3
    return peak / 1e6


def test_fit_memory_is_linear_in_the_pose_count(tmp_path):
    """4,000 and 16,000 rows: the peak grows ~4x (a P x P cosine matrix made it 16x: 2 GB at 16,000),
    and 16,000 rows stay under 32 MB, i.e. under 200 MB at 100,000 when scaled linearly."""
    small = fit_peak_mb(write_table(tmp_path / "p4k.csv", 4_000))
    big = fit_peak_mb(write_table(tmp_path / "p16k.csv", 16_000))
    assert big < 32.0, big
    assert big < 5.0 * small, (small, big)


def test_first_of_orientation_large_table_matches_the_pairwise_definition():
    """The cell-grid search for large tables gives exactly the all-pairs answer (revisits, a dense cluster)."""
    rng = np.random.default_rng(4)
    P = 3000
    u = rng.normal(size=(P, 3))
    u[::3] = u[: len(u[::3])]  # revisits of earlier orientations
    u[1::7] = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.02, (len(u[1::7]), 3))  # a dense cluster
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    got = first_of_orientation(u[None])[0]
    close = (u @ u.T) > np.cos(np.radians(5.0))  # the definition: no earlier pose within 5 degrees
    want = ~np.any(np.tril(close, k=-1), axis=1)
    assert np.array_equal(got, want) and 100 < want.sum() < P


# the child's own high-water mark (VmHWM belongs to the address space exec made; getrusage's
# ru_maxrss would carry over the peak of the forked copy of this test process)
CHILD = """
import sys
from accelcal_station.cli import cli
try:
    cli(sys.argv[1:], standalone_mode=False)
finally:
    hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM:")][0].split()[1]
    print("peak_rss_kb", hwm, file=sys.stderr)
"""


def peak_rss_mb(*args: str) -> float:
    """Run `accelcal ARGS` in a child; its peak resident memory (MB)."""
    r = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return int(r.stderr.split("peak_rss_kb")[1].split()[0]) / 1e3


def test_simulate_raw_streams(tmp_path):
    """1.2 million samples (six poses x 200,000): written a chunk at a time, the child's peak stays within
    50 MB of its start-up size (kept whole, the samples, their float copy and their text were ~150 MB more).  The raw
    log is complete: every sample of every pose."""
    out = tmp_path / "raw.csv"
    base = peak_rss_mb("simulate", "--poses", "six-face", "--raw", "--seed", "3", "--samples", "2000",
                       "--move-s", "0", "--out", str(tmp_path / "small.csv"))  # start-up and imports
    (tmp_path / "small.csv").unlink()
    peak = peak_rss_mb("simulate", "--poses", "six-face", "--raw", "--seed", "3", "--samples", "200000",
                       "--move-s", "0", "--out", str(out))
    assert peak - base < 50.0 and peak < 200.0, (base, peak)
    lines = out.read_text().splitlines()
    body = [ln for ln in lines if not ln.startswith("#")][1:]
    assert len(body) == 6 * 200_000
    x = np.array([float(ln.split(",")[1]) for ln in body[:200_000]])
    assert abs(x.mean() - 4096) < 2 and temps_left(tmp_path) == []


def temps_left(folder: Path) -> list[str]:
    return [n for n in os.listdir(folder) if n.endswith(".tmp")]


def test_pose_statistics_read_in_chunks_are_those_of_all_samples():
    """A pose of 150,000 samples is read in chunks of 65,536; the combined mean and std equal numpy's
    over the whole (kept) raw samples to rounding."""
    run = api.simulate("six-face", seed=5, samples=150_000, move_s=0.0, raw=True)
    first = np.concatenate([np.asarray(c, float) for c, t, _ in run.chunks])[:150_000]
    pose = run.session.poses[0]
    np.testing.assert_allclose(pose.mean, first.mean(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(pose.std, first.std(axis=0, ddof=1), rtol=1e-12)


def test_limits_are_checked_before_any_work(tmp_path):
    """simulate's samples x poses x temperatures and number of temperatures, and a pose table's angles:
    one line, exit 2, nothing written."""
    from click.testing import CliRunner

    from accelcal_station.cli import cli

    out = tmp_path / "raw.csv"
    r = CliRunner().invoke(cli, ["simulate", "--poses", "six-face", "--raw", "--samples", "10000000",
                                 "--temps", "0,10,20", "--out", str(out)])
    assert r.exit_code == 2 and "= 180000000 samples; allowed: at most 100000000" in r.stderr, r.output
    temps = ",".join(str(t) for t in range(17))
    r = CliRunner().invoke(cli, ["simulate", "--poses", "six-face", "--temps", temps, "--out", str(out)])
    assert r.exit_code == 2 and "17 temperatures; allowed: at most 16" in r.stderr, r.output
    assert os.listdir(tmp_path) == []
    table = write_table(tmp_path / "t.csv", 20)
    lines = table.read_text().splitlines()
    lines[5] = lines[5].split(",", 1)[0] + ",-1e308," + lines[5].split(",", 2)[2]
    table.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(cli, ["fit", str(table)])
    assert r.exit_code == 2 and r.stderr.strip() == (
        f"error: {table}: line 6, column pitch_deg: '-1e308' out of range; allowed -360 to 360"), r.output

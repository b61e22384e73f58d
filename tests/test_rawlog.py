"""Raw sample logs: reading, static-interval segmentation and `accelcal fit --raw`.

The logs are simulated here with numpy (fixed seeds): a board with offsets, gains and
symmetric cross-axis coupling, white noise and 1-LSB quantisation, held still at random
orientations for 2-4 s and moved smoothly (with some hand acceleration) in between.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from accelcal_station.cli import cli
from accelcal_station.data.rawlog import RawLog, read_raw_log
from accelcal_station.data.static_poses import detect_static, segment_static, to_session
from accelcal_station.errors import DataError

CPG = 4096.0
RATE = 100.0
NOISE_G = 0.002


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _slerp(a, b, s):
    om = np.arccos(np.clip(a @ b, -1.0, 1.0))
    return (np.outer(np.sin((1 - s) * om), a) + np.outer(np.sin(s * om), b)) / np.sin(om)


def make_log(seed=1, n_poses=32):
    """Counts (N, 3), hold intervals [(start, stop)], true S (symmetric) and offset b in g:
    raw_g = S g + b + noise, so the model-9 calibration is W = S^-1, V = -S^-1 b."""
    rng = np.random.default_rng(seed)
    dirs = _unit(rng, n_poses)
    for i in range(1, n_poses):  # consecutive poses at least 20 degrees apart
        while dirs[i] @ dirs[i - 1] > np.cos(np.deg2rad(20)):
            dirs[i] = _unit(rng, 1)[0]
    parts, holds, n0 = [], [], 0
    for i in range(n_poses):
        nh = int(RATE * rng.uniform(2.0, 4.0))
        holds.append((n0, n0 + nh))
        parts.append(np.tile(dirs[i], (nh, 1)))
        n0 += nh
        if i + 1 < n_poses:
            nm = int(RATE * rng.uniform(1.0, 2.0))
            u = np.arange(1, nm + 1) / (nm + 1)
            path = _slerp(dirs[i], dirs[i + 1], u * u * (3 - 2 * u))
            parts.append(path + 0.05 * np.sin(np.pi * u)[:, None] * _unit(rng, 1))
            n0 += nm
    g = np.concatenate(parts)
    S = np.eye(3) + np.diag(rng.uniform(-0.03, 0.03, 3))
    c = rng.uniform(-0.01, 0.01, 3)
    S[0, 1] = S[1, 0] = c[0]
    S[0, 2] = S[2, 0] = c[1]
    S[1, 2] = S[2, 1] = c[2]
    b = rng.uniform(-0.05, 0.05, 3)
    counts = np.round((g @ S.T + b + rng.normal(scale=NOISE_G, size=g.shape)) * CPG)
    return counts, holds, S, b


@pytest.fixture(scope="module")
def log32():
    return make_log(seed=7, n_poses=32)


def _run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    return r


def _check_segments(segs, holds):
    assert len(segs) == len(holds)
    for s, (a, b) in zip(segs, holds, strict=True):
        # used samples lie in the true hold (motion that is still below the noise at the
        # very start of a move may be included: allow 0.15 s) and cover most of it
        assert a - 15 <= s.start and s.stop <= b + 15, (s.ranges, (a, b))
        assert s.n >= 0.9 * (b - a)


def _check_truth(js, S, b, tol=1e-3):
    """Model-9 result against the simulated board, in the counts domain."""
    W = np.array(js["W"]) / js["input_per_g"] * CPG  # per g of true counts scale
    V = np.array(js["V"])
    # tol is > 8 standard errors of each coefficient (0.13 mg per pose mean, 32 poses):
    # false-failure rate below 1e-9
    np.testing.assert_allclose(W, np.linalg.inv(S), atol=tol)
    np.testing.assert_allclose(V, -np.linalg.inv(S) @ b, atol=tol)
    assert max(abs(p["norm_error_g"]) for p in js["poses"]) < 1e-3


def test_segmentation_finds_every_pose(log32):
    counts, holds, _, _ = log32
    det = detect_static(counts, RATE)
    _check_segments(det.segments, holds)
    # the noise floor is estimated from the log itself: true sigma is 0.002 g = 8.19 counts
    # (plus quantisation); 10 % is > 5 standard errors of the estimate
    np.testing.assert_allclose(det.noise_sigma, NOISE_G * CPG, rtol=0.1)
    # segmentation depends on neither the units nor an offset of the data
    key = [s.ranges for s in det.segments]
    assert [s.ranges for s in segment_static(np.arange(len(counts)) / RATE, counts / CPG)] == key
    assert [s.ranges for s in segment_static(None, counts / CPG * 9.80665, rate_hz=RATE)] == key
    assert [s.ranges for s in segment_static(None, counts + 32768, rate_hz=RATE)] == key


def test_to_session_carries_segment_statistics(log32):
    counts, holds, _, _ = log32
    t = np.arange(len(counts)) / RATE
    log = RawLog(t, counts, np.arange(len(counts)) + 1, "mem", ["t", "x", "y", "z"], RATE, True)
    det = detect_static(log.xyz, log.rate_hz)
    s = to_session(log, det.segments)
    assert len(s) == 32 and not s.has_references and s.metadata == {"source": "mem"}
    for p, seg in zip(s.poses, det.segments, strict=True):
        used = np.concatenate([counts[a:b] for a, b in seg.ranges])
        assert np.array_equal(p.mean, used.mean(axis=0)) and p.n == len(used) == seg.n
        assert p.t_start == t[seg.start] and p.t_end == t[seg.stop - 1]
    # per-sample std of a still pose is the noise (10 mg-level motion would show)
    np.testing.assert_allclose([p.std for p in s.poses], NOISE_G * CPG, rtol=0.25)


def test_cli_raw_csv_with_time_fits_model_9(tmp_path, log32):
    counts, holds, S, b = log32
    t = np.arange(len(counts)) / RATE
    f = tmp_path / "log.csv"
    np.savetxt(f, np.column_stack([t, counts]), fmt=["%.4f", "%d", "%d", "%d"], delimiter=",",
               header="time,acc_x,acc_y,acc_z", comments="")
    r = _run("fit", "--raw", f, "--model", "9", "--json")
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["model"] == "9" and js["pose_count"] == 32
    seg = js["segmentation"]
    assert seg["count"] == 32 and seg["columns"] == ["t", "x", "y", "z"]
    assert abs(seg["rate_hz"] - RATE) < 1e-6
    assert all(a - 15 <= s["start"] and s["stop"] <= b_ + 15 for s, (a, b_) in zip(seg["segments"], holds, strict=True))
    assert js["crossval_rms_g"] is not None and js["crossval_rms_g"] < 1e-3
    _check_truth(js, S, b)
    # the human summary says how many intervals were found and which samples were used
    h = _run("fit", "--raw", f)
    assert h.exit_code == 0, h.stderr
    assert "found 32 static intervals" in h.stdout
    first = seg["segments"][0]
    assert f"s01: samples {first['start']}-{first['stop'] - 1} ({first['n']} used" in h.stdout
    assert "model 9, 32 poses" in h.stdout


def test_cli_raw_whitespace_headerless_with_ignored_column(tmp_path, log32):
    counts, holds, S, b = log32
    f = tmp_path / "log.txt"
    idx = np.arange(len(counts))
    np.savetxt(f, np.column_stack([idx, counts]), fmt="%d", delimiter="   ")
    r = _run("fit", "--raw", f, "--columns", "-,x,y,z", "--rate", "100", "--json")
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["segmentation"]["count"] == 32
    _check_truth(js, S, b)
    # skip-rows: two junk lines on top are skipped, giving the same result
    g = tmp_path / "junk.txt"
    g.write_text("logger v1.2 boot\nlots of words here\n" + f.read_text())
    r2 = _run("fit", "--raw", g, "--columns", "-,x,y,z", "--rate", "100", "--skip-rows", "2", "--json")
    assert r2.exit_code == 0, r2.stderr
    assert json.loads(r2.stdout)["W"] == js["W"]


def test_cli_raw_16bit_unsigned_counts_no_flags(tmp_path, log32):
    counts, holds, S, b = log32
    u16 = counts + 32768
    assert u16.min() > 0 and u16.max() < 65536
    f = tmp_path / "u16.csv"
    np.savetxt(f, u16, fmt="%d", delimiter=",")
    r = _run("fit", "--raw", f, "--json")  # no rate, no units, no scale: model 9 by default
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["segmentation"]["count"] == 32 and js["segmentation"]["rate_hz"] is None
    W = np.array(js["W"]) / js["input_per_g"] * CPG
    np.testing.assert_allclose(W, np.linalg.inv(S), atol=1e-3)
    # unsigned counts: the loader subtracts the mid-scale code, so V is the board's own offset
    assert js["inferred"]["offset_counts"] == 32768 and js["inferred"]["counts_per_g"] == CPG
    np.testing.assert_allclose(js["V"], -np.linalg.inv(S) @ b, atol=2e-3)


@pytest.mark.parametrize("scale, units", [(1 / CPG, None), (1 / CPG, "g"), (9.80665 / CPG, "mps2")])
def test_cli_raw_in_g_and_mps2(tmp_path, log32, scale, units):
    counts, holds, S, b = log32
    f = tmp_path / "log.csv"
    np.savetxt(f, counts * scale, fmt="%.7f", delimiter=",", header="ax,ay,az", comments="")
    args = ["fit", "--raw", f, "--rate", "100", "--json"] + (["--units", units] if units else [])
    r = _run(*args)
    assert r.exit_code == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["segmentation"]["count"] == 32
    assert js["units"] == (units or "g")  # judged from the norm when not given
    W = np.array(js["W"]) * scale * CPG / js["input_per_g"]  # the data are counts * scale
    np.testing.assert_allclose(W, np.linalg.inv(S), atol=1e-3)
    np.testing.assert_allclose(js["V"], -np.linalg.inv(S) @ b, atol=1e-3)


def test_read_raw_log_columns_and_header_detection(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("# comment\nTime (s),Acc_X [g],Acc_Y [g],Acc_Z [g],Gyr_X\n" +
                 "".join(f"{i / 50:.2f},0.{i},0,1,5\n" for i in range(20)))
    log = read_raw_log(f)
    assert log.columns == ["t", "x", "y", "z", "-"] and log.has_time and abs(log.rate_hz - 50) < 1e-9
    assert log.line[0] == 3 and log.xyz.shape == (20, 3) and log.xyz[3, 0] == 0.3
    g = tmp_path / "b.txt"
    g.write_text("".join(f"{i} 1 2 3\n" for i in range(20)))
    log = read_raw_log(g)
    assert log.columns == ["t", "x", "y", "z"] and log.rate_hz == 1.0
    log = read_raw_log(g, columns="-,z,y,x", rate_hz=10)
    assert np.array_equal(log.xyz[0], [3, 2, 1]) and log.t[10] == 1.0 and not log.has_time


@pytest.mark.parametrize("text, kw, match", [
    ("x,y,z\n" + "1,2,3\n" * 9 + "1,nan,3\n", {}, r"line 11, column 2 \(y\): 'nan'; allowed: a finite number"),
    ("1 2 3\n" * 12 + "1 2 abc\n", {}, r"line 13, column 3 \(z\): 'abc' is not a number"),
    ("1 2 3\n" * 12 + "1 2\n", {}, r"line 13: 2 fields; expected 3"),
    ("1,2,3,4,5\n" * 12, {}, r"line 1: 5 columns and no header; give --columns"),
    ("1,2,3\n" * 12, {"columns": "t,x,y,z"}, r"line 1: 3 fields but --columns names 4"),
    ("1,2,3\n" * 12, {"columns": "x,y,w"}, r"'w' is not a column name; allowed: t, x, y, z, -"),
    ("1,2,3\n" * 12, {"columns": "x,y,-"}, r"no 'z' column"),
    ("a,b,c\n" + "1,2,3\n" * 12, {}, r"line 1: cannot tell which header column is x"),
    ("".join(f"{10 - i},1,2,3\n" for i in range(12)), {}, r"line 2, column 1 \(t\): time goes backwards"),
    ("0,1,2,3\n" * 12, {"rate_hz": 100}, r"has a time column; --rate is only for logs without one"),
    ("1,2,3\n" * 5, {}, r"5 samples; a raw log needs at least 10"),
    ("# only comments\n", {}, r"no data lines"),
])
def test_read_raw_log_errors(tmp_path, text, kw, match):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(DataError, match=match) as e:
        read_raw_log(f, **kw)
    assert "\n" not in str(e.value)


def test_cli_raw_errors_are_one_line(tmp_path):
    rng = np.random.default_rng(3)
    moving = tmp_path / "moving.csv"  # a log that never stops moving
    ang = np.cumsum(rng.normal(scale=0.05, size=3000))
    np.savetxt(moving, np.column_stack([np.cos(ang), np.sin(ang), np.sin(3 * ang)]) * 4096, fmt="%.0f",
               delimiter=",")
    nan = tmp_path / "nan.csv"
    nan.write_text("t,x,y,z\n" + "0,1,2,3\n" * 20 + "1,NaN,2,3\n")
    cases = [
        (["fit", "--raw", tmp_path / "missing.csv"], "missing.csv: cannot read"),
        (["fit", "--raw", moving, "--rate", "100"], "moving.csv: no static interval of 100 samples or more"),
        (["fit", "--raw", nan], "nan.csv: line 22, column 2 (x): 'NaN'; allowed: a finite number"),
        (["fit", "--raw", nan, "--rate", "abc"], "--rate 'abc'; allowed: a positive number"),
        (["fit", "--raw", nan, "--skip-rows", "-1"], "--skip-rows '-1'; allowed: a non-negative whole number"),
        (["fit", nan, "--columns", "t,x,y,z"], "--columns is for raw sample logs; add --raw"),
    ]
    for args, msg in cases:
        r = _run(*args)
        assert r.exit_code != 0, args
        assert r.stderr.count("\n") == 1 and msg in r.stderr, (args, r.stderr)
        assert "Traceback" not in r.stderr + r.stdout

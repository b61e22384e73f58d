"""Temporary files of the one atomic writer (accelcal_station/atomic.py): never hijacked through a
planted symlink, never left behind by a killed run (issue 26)."""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from click.testing import CliRunner

from accelcal_station.atomic import TAG, WriteError, atomic_write, remove_stale
from accelcal_station.cli import cli as main
from accelcal_station.lot.synthetic import write_lot


def temps(folder: Path, name: str) -> list[str]:
    return sorted(n for n in os.listdir(folder) if n.startswith(f".{name}.") and n.endswith(".tmp"))


def test_symlink_at_every_temp_name_the_batch_could_use_is_never_followed(tmp_path, monkeypatch):
    """The temp name is drawn by tempfile's name sequence; seeding a copy of it tells us the names the
    batch will try, in order.  A symlink planted at each of the first 200 (and at the old predictable
    ``.R.<pid>.tmp``) is skipped by O_EXCL: the victims are untouched and the results are whole."""
    lot = write_lot(tmp_path / "lot.csv", 40, seed=3)
    out = tmp_path / "r.csv"
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    absent = tmp_path / "absent.txt"  # a dangling link: following it would create this file
    seq, planned = tempfile._RandomNameSequence(), tempfile._RandomNameSequence()  # stdlib's generator,
    for s in (seq, planned):  # seeded twice alike: ``planned`` says in advance the names ``seq`` will give
        s._rng, s._rng_pid = random.Random(1234), os.getpid()
    prefix = f".{out.name}.{TAG}-{os.getpid()}-"
    for i in range(200):
        name = prefix + next(planned) + ".tmp"
        (tmp_path / name).symlink_to(victim if i % 2 else absent)
    (tmp_path / f".{out.name}.{os.getpid()}.tmp").symlink_to(victim)  # the old predictable name
    monkeypatch.setattr(tempfile, "_name_sequence", seq)
    r = CliRunner().invoke(main, ["batch", str(lot), "--out", str(out), "--chunk-boards", "8"])
    assert r.exit_code == 0, r.output
    assert victim.read_text() == "precious\n" and not absent.exists()
    assert out.read_text().count("\n") == 41 and not out.is_symlink()
    # every planted link is still a link (none was replaced or written through); no other temp is left
    left = temps(tmp_path, out.name)
    # the writer drew exactly the 200 planted names (each refused by O_EXCL) and one more
    next(planned)
    assert next(seq) == next(planned)
    assert len(left) == 201 and all((tmp_path / n).is_symlink() for n in left)


def test_writer_refuses_a_symlinked_target_and_cleans_up(tmp_path):
    target = tmp_path / "cal.json"
    victim = tmp_path / "victim"
    victim.write_text("x")
    target.symlink_to(victim)
    with pytest.raises(WriteError, match="cal.json: cannot write .*symbolic link"):
        atomic_write(target, "{}")
    assert victim.read_text() == "x" and temps(tmp_path, "cal.json") == []
    with pytest.raises(ZeroDivisionError), atomic_write(tmp_path / "t.csv") as f:  # an error mid-stream
        f.write("half")
        raise ZeroDivisionError
    assert not (tmp_path / "t.csv").exists() and temps(tmp_path, "t.csv") == []


def test_stale_temp_of_a_dead_process_is_removed_but_a_live_ones_is_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)  # exited: its temps are stale (a pid is not reused within this test's moments)
    stale = tmp_path / f".r.csv.{TAG}-{pid}-abcdefgh.tmp"
    live = tmp_path / f".r.csv.{TAG}-{os.getpid()}-abcdefgh.tmp"
    other = tmp_path / f".q.csv.{TAG}-{pid}-abcdefgh.tmp"  # another output's temp: not ours to judge
    for p in (stale, live, other):
        p.write_text("partial")
    assert remove_stale(tmp_path / "r.csv") == [stale]
    assert live.exists() and other.exists() and not stale.exists()


def test_kill_9_mid_batch_then_rerun_leaves_no_temp(tmp_path):
    """A batch killed while its results temp exists; the next run of the same command removes it."""
    lot = write_lot(tmp_path / "lot.csv", 3000, seed=5)
    out = tmp_path / "r.csv"
    cmd = [sys.executable, "-m", "accelcal_station", "batch", str(lot), "--out", str(out), "--chunk-boards", "4"]
    seen: list[str] = []
    for _ in range(5):  # the window is ~0.3 s of a run; the temp is polled every millisecond
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline and not seen:
            seen = temps(tmp_path, out.name)
            if seen:
                os.kill(proc.pid, signal.SIGKILL)
            time.sleep(0.001)
        proc.wait()
        if seen and proc.returncode == -signal.SIGKILL:
            break
        out.unlink(missing_ok=True)
        seen = []
    assert seen and temps(tmp_path, out.name), "the batch was never caught mid-write"
    assert not out.exists()  # killed before the rename: no half table
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert temps(tmp_path, out.name) == [] and out.read_text().count("\n") == 3001

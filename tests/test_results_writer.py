"""The results table written behind the fit on a second CPU (data/results_table.ResultsWriter):
the same bytes as written in line, and a write that fails is one line with nothing left."""
from __future__ import annotations

import json

import pytest

from accelcal_station.lot.streaming import recalibrate_lot
from accelcal_station.lot.synthetic import write_lot


def _pinned(cpus: int):
    """A preexec_fn: the child may run on ``cpus`` CPUs only."""
    import os

    return lambda: os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:cpus])


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_results_written_behind_the_fit_on_a_second_cpu_are_the_same_bytes(tmp_path, suffix):
    """With two CPUs the results table is written by its own thread while the next chunk is fitted
    (Arrow formats without the GIL); the table is the same, byte for byte, as a one-CPU run's,
    where nothing is written behind (no thread)."""
    pytest.importorskip("pyarrow.csv", reason="the optional pyarrow is not installed")
    import os
    import subprocess
    import sys
    import threading

    if not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs two CPUs this process may use (Linux affinity)")
    lot = write_lot(tmp_path / "lot.csv", 3000, seed=12)
    names: set[str] = set()
    before = threading.gettrace()
    threading.settrace(lambda *_: names.add(threading.current_thread().name))  # type: ignore[arg-type, func-returns-value]
    try:
        recalibrate_lot(lot, tmp_path / f"here{suffix}", "12", chunk_boards=500)
    finally:
        threading.settrace(before)  # type: ignore[arg-type]
    assert any(n.startswith("accelcal-results") for n in names), names
    done = subprocess.run([sys.executable, "-m", "accelcal_station", "batch", str(lot), "--model", "12",
                           "--chunk-boards", "500", "--out", str(tmp_path / f"pinned{suffix}")],
                          capture_output=True, text=True, timeout=120, preexec_fn=_pinned(1))
    assert done.returncode == 0 and "3000 of 3000 boards" in done.stdout, done.stderr
    if suffix == ".csv":
        assert (tmp_path / "pinned.csv").read_bytes() == (tmp_path / "here.csv").read_bytes()
    else:  # Parquet files carry the writer's metadata: compare the tables
        import pyarrow.parquet as pq

        assert pq.read_table(tmp_path / "pinned.parquet").equals(pq.read_table(tmp_path / "here.parquet"))


@pytest.mark.parametrize("boards", [6000, 500])
@pytest.mark.parametrize("cpus", [1, 2])
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_results_write_that_fails_is_one_line_and_leaves_nothing(tmp_path, suffix, cpus, boards):
    """A real write failure (the file size limit, EFBIG, as a full disk would fail it), part-way
    through a lot of 12 chunks or at the one chunk of a lot of 500 boards (the last write, still
    pending when the lot ends), on one CPU (written in line) and on two (written behind the fit,
    raised at the next chunk or at the end): one line, exit 2, no results file and no temporary
    file left."""
    pytest.importorskip("pyarrow.csv", reason="the optional pyarrow is not installed")
    import os
    import resource
    import signal
    import subprocess
    import sys

    if not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < cpus:
        pytest.skip(f"needs {cpus} CPUs this process may use (Linux affinity)")
    lot = write_lot(tmp_path / "lot.csv", boards, seed=13)
    out = tmp_path / "out" / f"r{suffix}"
    out.parent.mkdir()
    limit = 20_000  # bytes: the results of 500 boards take ~200 kB as CSV, ~100 kB as Parquet

    def child() -> None:
        _pinned(cpus)()
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead of a signal
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    for extra in ([], ["--json"]):
        done = subprocess.run([sys.executable, "-m", "accelcal_station", "batch", str(lot), "--model", "12",
                               "--chunk-boards", "500", "--out", str(out), *extra],
                              capture_output=True, text=True, timeout=120, preexec_fn=child)
        said = (done.stdout if extra else done.stderr).strip()
        assert done.returncode == 2, (done.stdout, done.stderr)
        assert "Traceback" not in done.stderr and len(said.splitlines()) == 1, said
        if extra:
            assert "cannot write" in json.loads(said)["error"]
        else:
            assert said.startswith(f"error: --out {out}: cannot write"), said
        assert list(out.parent.iterdir()) == []

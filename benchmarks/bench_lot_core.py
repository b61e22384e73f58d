"""Issue 35's lot-path target, measured as it is stated: `accelcal batch` on a 200,000-board
model-12 lot, boards per second on ONE core.

    python benchmarks/bench_lot_core.py [--boards 200000] [--repeats 5] [--cpu N] [--formats csv:csv,...] [--small]

Each run is a fresh child process, ``accelcal batch LOT --model 12 --out OUT --json``, pinned to one
CPU (``os.sched_setaffinity`` before exec, what ``taskset -c N`` does) with BLAS held to one thread, so
the read-ahead thread and model 12's second fitting thread find no second core (``models/threads.py``
sees one CPU and starts neither).  Per run:

- **in process**: the command's own ``boards_per_s`` (from opening the lot to the results file
  renamed into place);
- **whole process**: boards per CPU-second of the child (user + system time from ``os.wait4``),
  Python start-up and imports included;
- wall time.

Lot input CSV or Parquet, results CSV or Parquet (``--formats``), run interleaved (every format once
per repeat, the order rotated) so a host whose speed drifts slows all alike; the in-repo numpy
reference (``reference_lot.py``, pyarrow read, normal equations, ``np.savetxt``) runs pinned the
same way in each repeat for a like-for-like ratio.  The load average before and after is printed:
the target is for an idle core, and a busy host's figures say so.  Lots come from
``lot.synthetic.write_lot(path, boards, "an4399-8", seed=35)``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TARGET = 100_000  # boards/s per core (issue 35)
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class Runs:
    """One format pair's runs: boards/s in process, boards per CPU-second, wall seconds."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.in_process: list[float] = []
        self.per_cpu_s: list[float] = []
        self.wall_s: list[float] = []

    def line(self) -> str:
        def mmm(v: list[float]) -> str:
            return f"{min(v):>9,.0f} {statistics.median(v):>9,.0f} {max(v):>9,.0f}" if v else " " * 29
        wall = statistics.median(self.wall_s)
        return f"{self.label:<24} {mmm(self.in_process)} | {mmm(self.per_cpu_s)} | {wall:6.2f}"


def pinned(cmd: list[str], cpu: int) -> tuple[str, float, float]:
    """Run ``cmd`` on CPU ``cpu`` alone: (stdout, the child's CPU seconds, wall seconds)."""
    env = {**os.environ, **ONE_THREAD}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=out, stderr=err, env=env,
                             preexec_fn=lambda: os.sched_setaffinity(0, {cpu}))
        _, status, usage = os.wait4(p.pid, 0)  # this child's own rusage, not all children's
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        if p.returncode:
            raise SystemExit(f"{' '.join(cmd)}: exit {p.returncode}: {err.read().decode(errors='replace')[-300:]}")
        return out.read().decode(), usage.ru_utime + usage.ru_stime, wall


def accelcal() -> list[str]:
    exe = Path(sys.executable).with_name("accelcal")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "accelcal_station"]


def make_lots(tmp: Path, boards: int, formats: list[tuple[str, str]]) -> dict[str, Path]:
    from accelcal_station.lot.synthetic import write_lot

    lots = {}
    for kind in sorted({i for i, _ in formats}):
        lots[kind] = write_lot(tmp / f"lot.{kind}", boards, "an4399-8", seed=35, parquet=kind == "parquet")
    return lots


def reference_cmd(lot: Path, out: Path) -> list[str]:
    from gate import LIMITS  # the gate's limits: the reference judges as it does there

    code = (f"import sys; sys.path.insert(0, {str(HERE)!r}); import reference_lot; "
            f"reference_lot.run({str(lot)!r}, {str(out)!r}, {LIMITS!r})")
    return [sys.executable, "-c", code]


def measure(boards: int, repeats: int, cpu: int, formats: list[tuple[str, str]], tmp: Path) -> list[Runs]:
    lots = make_lots(tmp, boards, formats)
    runs = [Runs(f"{i} -> {o}") for i, o in formats]
    ref = Runs("numpy reference csv->csv") if "csv" in lots else None
    jobs: list[tuple[Runs, list[str]]] = [
        (r, [*accelcal(), "batch", str(lots[i]), "--model", "12", "--out", str(tmp / f"out.{o}"), "--json"])
        for r, (i, o) in zip(runs, formats, strict=True)]
    if ref is not None:
        jobs.append((ref, reference_cmd(lots["csv"], tmp / "ref.csv")))
    for k in range(repeats):
        for r, cmd in jobs[k % len(jobs):] + jobs[:k % len(jobs)]:
            out, cpu_s, wall = pinned(cmd, cpu)
            if r is not ref:
                report = json.loads(out)
                assert report["fitted"] == boards, f"{r.label}: {report['fitted']} of {boards} fitted"
                r.in_process.append(report["boards_per_s"])
            r.per_cpu_s.append(boards / cpu_s)
            r.wall_s.append(wall)
    return runs + ([ref] if ref else [])


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--boards", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--small", action="store_true", help="a quick run: 2,000 boards, one run each")
    ap.add_argument("--cpu", type=int, default=None, help="the CPU to pin to (default: the last one allowed)")
    ap.add_argument("--formats", default="csv:csv,csv:parquet,parquet:csv,parquet:parquet",
                    help="lot:results pairs, comma-separated (csv or parquet)")
    a = ap.parse_args(argv)
    if a.small:
        a.boards, a.repeats = 2000, 1
    if not hasattr(os, "sched_setaffinity"):
        print("bench_lot_core: needs os.sched_setaffinity (Linux) to pin a run to one core")
        return 2
    formats = [tuple(p.split(":")) for p in a.formats.split(",")]
    if any(len(p) != 2 or not set(p) <= {"csv", "parquet"} for p in formats):
        print(f"--formats {a.formats}: allowed: lot:results pairs of csv or parquet, e.g. csv:csv,parquet:csv")
        return 2
    cpu = a.cpu if a.cpu is not None else max(os.sched_getaffinity(0))
    sys.path.insert(0, str(HERE))
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        runs = measure(a.boards, a.repeats, cpu, formats, Path(d))
    load1 = os.getloadavg()
    print(f"{a.boards:,} boards, model 12, one core (CPU {cpu} of {os.cpu_count()}, {cpu_model()}), "
          f"{a.repeats} runs each, interleaved; load average {load0[0]:.2f} before, {load1[0]:.2f} after")
    print(f"{'lot -> results':<24} {'boards/s in process':^29} | {'boards per CPU-second':^29} | wall s")
    print(f"{'':<24} {'min':>9} {'median':>9} {'max':>9} | {'min':>9} {'median':>9} {'max':>9} |")
    for r in runs:
        print(r.line())
    csv_runs = runs[0] if runs and runs[0].label == "csv -> csv" else None
    if csv_runs and runs[-1].label.startswith("numpy reference"):
        ratio = statistics.median(csv_runs.per_cpu_s) / statistics.median(runs[-1].per_cpu_s)
        print(f"csv -> csv against the numpy reference, per CPU-second, same core: {ratio:.2f}x")
    if csv_runs:
        med = statistics.median(csv_runs.in_process)
        print(f"target {TARGET:,} boards/s per core: median in process {med:,.0f} "
              f"({'met' if med >= TARGET else 'NOT met'}), whole process "
              f"{statistics.median(csv_runs.per_cpu_s):,.0f} per CPU-second")
    return 0


if __name__ == "__main__":
    sys.exit(main())

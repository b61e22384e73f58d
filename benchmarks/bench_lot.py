"""A whole lot on one machine: fit rates, end-to-end boards/s and peak memory, in one run.

    python benchmarks/bench_lot.py [--boards 100000] [--boards9 100000] [--rss 100000,1000000] [--small]

1. Fits per second per model: the stacked fitters (models/stacked.py, what a lot file
   uses) beside today's batched fitters (models/linear.py fit_linear_batch,
   models/gravity_norm.py fit_norm_batch: what `accelcal batch` on pose tables uses)
   and beside a per-board loop of ``models.fit``.  Every fitter gives W, V, Gamma,
   standard errors, leave-one-out RMS and the condition number.  Linear models on
   AN4399 Table 5 (8 poses), model 9 on 12 poses (optimal-12).  Today's model 9 and
   the loops run on subsets; rates are per board, so the ratios are like for like.
   The stacked rate is the best of --repeats runs (other processes on a shared machine
   only slow a run down); the target column is the issue's goal on a 2-core machine.
   Then blocks of models 9 and 12 in one thread in fresh processes, with glibc's default
   heap thresholds and with those fit_stacked sets (heap.py): fits/s and page faults per block.
2. End-to-end boards/s, model 12: a lot file (CSV) to one results CSV; pose-table
   files to calibration JSONs + a summary CSV (today's path); runs in an SQLite
   results store to recalibration events in it.
3. Peak RSS of ``accelcal batch LOT.csv --model 12 --out results.csv`` (a child
   process, ru_maxrss) at each --rss lot size, and the 10 M extrapolation (the larger
   peak plus the growth per board between the two largest sizes, never negative).
Lots come from accelcal_station.lot.synthetic (random gain/cross-axis 1 %, offset 30 mg, 1 mg noise).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from accelcal_station.data.posetable import write_pose_table
from accelcal_station.fixtures.designs import get_design, references
from accelcal_station.lot.batch import (
    recalibrate,
    record_in_store,
    sessions_from_files,
    sessions_from_store,
    summary_csv,
    write_calibrations,
)
from accelcal_station.lot.streaming import recalibrate_lot
from accelcal_station.lot.synthetic import write_lot
from accelcal_station.models.fitting import fit
from accelcal_station.models.gravity_norm import fit_norm_batch
from accelcal_station.models.linear import fit_linear_batch
from accelcal_station.models.stacked import fit_stacked
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store


def boards(D: int, ref: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    K = np.eye(3) + rng.normal(0, 0.01, (D, 3, 3))
    return np.einsum("dij,pj->dpi", K, ref) + rng.normal(0, 0.03, (D, 1, 3)) + rng.normal(0, 1e-3, (D,) + ref.shape)


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


TARGET = {"12": 1_000_000, "9": 100_000}  # fits/s at 100k boards (model 9: at --boards9)


def best_rate(n: int, fn, repeats: int) -> float:
    return n / min(timed(fn) for _ in range(max(1, repeats)))


def fit_rates(n: int, n9: int, n_today9: int, n_loop: int, repeats: int = 3) -> None:
    print(f"1. fits/s (stacked and today's at {n} boards, model 9 stacked at {n9}, today's model 9 at "
          f"{n_today9}, per-board loops at {n_loop})")
    print(f"   {'model':5} {'stacked':>12} {'today':>12} {'loop':>10} {'stacked/today':>14} {'stacked/loop':>13}"
          f" {'target':>10}")
    ref8 = references(get_design("an4399-8"))
    ref12 = references(get_design("optimal-12"))
    for model in ("6", "12", "15", "9"):
        ref = ref12 if model == "9" else ref8
        N = n9 if model == "9" else n
        x = boards(N, ref, seed=1)
        r_new = best_rate(N, lambda x=x, ref=ref, model=model: fit_stacked(x, None if model == "9" else ref, model),
                          repeats)
        Nt = n_today9 if model == "9" else N
        today = ((lambda x=x, Nt=Nt: fit_norm_batch(x[:Nt])) if model == "9"
                 else (lambda x=x, ref=ref, model=model: fit_linear_batch(x, ref, model)))
        r_old = Nt / timed(today)
        L = n_loop
        r_loop = L / timed(lambda x=x, ref=ref, model=model, L=L:
                           [fit(x[d], None if model == "9" else ref, model) for d in range(L)])
        goal = (f"{TARGET[model]:>10,} ({'met' if r_new >= TARGET[model] else 'not met'})"
                if model in TARGET else "")
        print(f"   {model:5} {r_new:12,.0f} {r_old:12,.0f} {r_loop:10,.0f} {r_new / r_old:14.1f} {r_new / r_loop:13.0f}"
              f" {goal}".rstrip())


HEAP_HELPER = """
import resource, sys, time
import numpy as np
from accelcal_station.fixtures.designs import get_design, references
from accelcal_station.models.heap import keep_block_memory
from accelcal_station.models.stacked import BLOCK, fit12
from accelcal_station.models.stacked_norm import fit9
sys.path.insert(0, sys.argv[3])
from bench_lot import boards
if sys.argv[1] == "kept":
    keep_block_memory()
model = sys.argv[2]
ref = references(get_design("optimal-12" if model == "9" else "an4399-8"))
n, blocks = BLOCK[model], 6 if model == "9" else 60
x = boards(n, ref, seed=1)
run = (lambda: fit9(x)) if model == "9" else (lambda: fit12(x, ref))
run()
r0, t0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.perf_counter()
for _ in range(blocks):
    run()
dt, faults = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0
print(n * blocks / dt, faults / blocks)
"""


def heap_effect() -> None:
    """Blocks of models 9 and 12 in one thread, in a fresh process with glibc's default heap
    thresholds and in one with heap.keep_block_memory (what fit_stacked sets)."""
    print("   one thread, blocks of BLOCK[model] boards in a fresh process (glibc heap defaults -> kept):")
    for model in ("9", "12"):
        got = {}
        for mode in ("default", "kept"):
            out = subprocess.run([sys.executable, "-c", HEAP_HELPER, mode, model, str(Path(__file__).parent)],
                                 capture_output=True, text=True).stdout.split()
            got[mode] = (float(out[0]), float(out[1])) if len(out) == 2 else (float("nan"), float("nan"))
        (r0, f0), (r1, f1) = got["default"], got["kept"]
        print(f"   model {model:2} {r0:10,.0f} -> {r1:10,.0f} fits/s ({r1 / r0:.2f}x); page faults per block "
              f"{f0:,.0f} -> {f1:,.0f}")


def _sessions(n: int) -> list[Session]:
    ref = references(get_design("an4399-8"))
    x = boards(n, ref, seed=2) * 4096
    names = [p.name for p in get_design("an4399-8")]
    return [Session([PoseRecord(nm, x[d, i], np.full(3, 4.0), 200, ref[i]) for i, nm in enumerate(names)],
                    "counts", 4096.0, None, f"SN{d}") for d in range(n)]


def end_to_end(work: Path, n_lot: int, n_files: int) -> None:
    print(f"2. end to end, model 12 (lot of {n_lot} boards; {n_files} pose tables; {n_files} stored runs)")
    lot = write_lot(work / "e2e.csv", n_lot, seed=3)
    dt = timed(lambda: recalibrate_lot(lot, work / "e2e-results.csv"))
    print(f"   lot file -> one results CSV:            {n_lot / dt:10,.0f} boards/s")
    tables = work / "tables"
    tables.mkdir()
    for i, s in enumerate(_sessions(n_files)):
        write_pose_table(s, tables / f"b{i:05d}.csv", {"serial": f"SN{i}"})
    paths = sorted(tables.glob("*.csv"))

    def files():
        rep = recalibrate(sessions_from_files(paths, model="12"), "12")
        write_calibrations(rep, work / "cals")
        summary_csv(rep, work / "summary.csv")
        return rep

    rep = None
    t0 = time.perf_counter()
    rep = files()
    dt = time.perf_counter() - t0
    print(f"   pose tables -> calibration JSONs + CSV: {n_files / dt:10,.0f} boards/s")
    db = work / "runs.sqlite"
    with Store(db) as st:
        record_in_store(rep, st)

    def stored():
        with Store(db) as st:
            r = recalibrate(sessions_from_store(st), "12")
            record_in_store(r, st, source_store=db)

    dt = timed(stored)
    print(f"   store runs -> recalibration events:     {n_files / dt:10,.0f} boards/s")


RSS_HELPER = """
import os, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)
_, status, ru = os.wait4(p.pid, 0)
print(os.waitstatus_to_exitcode(status), time.perf_counter() - t0, ru.ru_maxrss / 1024)
"""


def peak_rss(work: Path, sizes: list[int]) -> None:
    print("3. peak RSS of `accelcal batch LOT.csv --model 12 --out results.csv` (child process)")
    got = []
    for n in sizes:
        lot = write_lot(work / f"rss-{n}.csv", n, seed=4)
        cmd = [sys.executable, "-m", "accelcal_station", "batch", str(lot), "--model", "12",
               "--out", str(work / f"rss-{n}-results.csv")]
        # ru_maxrss survives exec, and a child forked from this (large) process starts with its pages:
        # a small helper process starts the command and reports the command's own peak
        out = subprocess.run([sys.executable, "-c", RSS_HELPER, *cmd], capture_output=True, text=True).stdout
        status, dt, mb = out.split()[-3:]
        dt, mb = float(dt), float(mb)
        got.append((n, mb))
        print(f"   {n:>10,} boards: peak RSS {mb:7.0f} MB, {n / dt:8,.0f} boards/s (process wall time, "
              f"exit {status})")
        lot.unlink()
    if len(got) >= 2:
        (n1, m1), (n2, m2) = got[-2], got[-1]
        slope = max(0.0, (m2 - m1) / (n2 - n1))  # a peak that fell is not extrapolated downwards
        print(f"   ratio {n2 // n1}x boards -> {m2 / m1:.2f}x peak RSS; 10,000,000 boards extrapolated "
              f"(linear growth, clamped at >= 0): {max(m1, m2) + slope * (10_000_000 - n2):.0f} MB")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=100_000)
    ap.add_argument("--boards9", type=int, default=100_000)
    ap.add_argument("--today9", type=int, default=2_000)
    ap.add_argument("--loop-boards", type=int, default=300)
    ap.add_argument("--lot-boards", type=int, default=100_000)
    ap.add_argument("--files", type=int, default=2_000)
    ap.add_argument("--rss", default="100000,1000000", help="lot sizes for peak RSS, comma separated")
    ap.add_argument("--repeats", type=int, default=3, help="stacked fit runs per model (the best is shown)")
    ap.add_argument("--small", action="store_true", help="a quick run (smoke test sizes)")
    a = ap.parse_args(argv)
    if a.small:
        a.boards, a.boards9, a.today9, a.loop_boards = 2000, 500, 100, 20
        a.lot_boards, a.files, a.rss = 2000, 50, "1000,4000"
    sizes = [int(s) for s in a.rss.split(",") if s.strip()]
    print(f"bench_lot: {os.cpu_count()} CPU(s), numpy {np.__version__}, load average at start "
          f"{os.getloadavg()[0]:.1f} (other processes on the machine)")
    fit_rates(a.boards, a.boards9, a.today9, a.loop_boards, a.repeats)
    heap_effect()
    with tempfile.TemporaryDirectory(prefix="accelcal-bench-lot-") as d:
        end_to_end(Path(d), a.lot_boards, a.files)
        peak_rss(Path(d), sizes)
    print(f"load average at end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

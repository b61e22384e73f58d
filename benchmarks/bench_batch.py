"""Batch recalibration end to end (pose tables or stored runs in, calibrations out) and its memory.

    python benchmarks/bench_batch.py [--boards 2000] [--loop-boards 300] [--memory-boards 100000] [--small]

End to end, model ``--model`` (default 12):

* files: ``--boards`` pose tables (CSV session files, counts, 8 poses each) in a
  temporary folder; ``accelcal batch``'s path -- ``batch.sessions_from_files``,
  ``batch.recalibrate`` (stacked ``fit_batch`` per group of 256), one calibration
  JSON per board (``batch.write_calibrations``; each file is fsynced so it is
  whole or absent) -- beside a per-board loop of ``read_pose_table`` ->
  ``models.fit_session`` -> ``Calibration.save``; and the same batch writing one
  summary CSV (``batch.summary_csv``) instead of a file per board;
* store: the same boards as complete runs in a results store (SQLite);
  ``batch.sessions_from_store`` -> ``recalibrate`` -> calibration JSONs.

Memory, each figure in a fresh subprocess, for ``--memory-boards`` boards:

* ``fit_batch`` per model (tracemalloc peak above the input array, results
  included: numpy reports its buffers to tracemalloc);
* ``batch.recalibrate`` on that many in-memory sessions, as read from a store
  (resource.getrusage ru_maxrss: the peak resident set, above the process with
  the sessions built, and the sessions themselves above the bare interpreter).

Fits per second per model against per-device loops: benchmarks/bench_batch_fit.py.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import design_refs, table

from accelcal_station.data.posetable import read_pose_table, write_pose_table
from accelcal_station.fixtures.designs import get_design
from accelcal_station.lot.batch import (
    expand_paths,
    recalibrate,
    sessions_from_files,
    sessions_from_store,
    summary_csv,
    write_calibrations,
)
from accelcal_station.models.fitting import fit_batch, fit_session
from accelcal_station.session import PoseRecord, Session
from accelcal_station.store.runs import Store

CPG = 4096.0  # MMA8451 at 2 g
SAMPLES = 256
MEMORY_DESIGN = {"6": "an4399-8", "12": "an4399-8", "15": "an4399-8", "9": "nine-position"}


def lot(D: int, design: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """D boards' pose means in counts (D, P, 3) and references (P, 3): random W, V, cubic,
    the mean of SAMPLES samples of 0.7 mg noise."""
    rng = np.random.default_rng(seed)
    ref = design_refs(design)
    K = np.eye(3) + rng.normal(0, 0.01, (D, 3, 3))
    g = np.einsum("dij,pj->dpi", K, ref) + rng.normal(0, 0.02, (D, 1, 3)) + 0.002 * ref**3
    g += rng.normal(0, 7e-4 / np.sqrt(SAMPLES), g.shape)
    return g * CPG, ref


def sessions(D: int, design: str, seed: int) -> list[Session]:
    x, _ = lot(D, design, seed)
    poses = get_design(design)
    std = np.full(3, 2.9)
    return [Session([PoseRecord(p.name, x[d, i], std, SAMPLES, p.reference_g, p.pitch_deg, p.roll_deg)
                     for i, p in enumerate(poses)], "counts", CPG, device="mma8451",
                    metadata={"serial": f"SN{d:06d}"}) for d in range(D)]


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def end_to_end(D: int, L: int, model: str, store_boards: int, seed: int) -> list[list]:
    ss = sessions(D, "an4399-8", seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="accelcal-bench-") as tmp:
        tmp = Path(tmp)
        (tmp / "in").mkdir()
        for s in ss:
            write_pose_table(s, tmp / "in" / f"{s.metadata['serial']}.csv")
        paths = expand_paths([str(tmp / "in")])
        src, t_read = timed(lambda: sessions_from_files(paths, model=model))
        rep, t_fit = timed(lambda: recalibrate(src, model))
        out, t_write = timed(lambda: write_calibrations(rep, tmp / "out"))
        assert len(out) == D, f"{D - len(out)} boards not fitted: {rep.skipped[:1]}"
        total = t_read + t_fit + t_write
        rate = D / total
        rows.append(["files", "accelcal batch (read, stacked fit, write JSON)", D, f"{rate:.0f}",
                     f"{t_read / total:.0%} / {t_fit / total:.0%} / {t_write / total:.0%}", "1.0"])
        _, t_csv = timed(lambda: summary_csv(rep, tmp / "summary.csv"))
        total_csv = t_read + t_fit + t_csv
        rows.append(["files", "  same, one summary CSV instead of JSON files", D, f"{D / total_csv:.0f}",
                     f"{t_read / total_csv:.0%} / {t_fit / total_csv:.0%} / {t_csv / total_csv:.0%}", ""])

        def loop():
            (tmp / "loop").mkdir()
            for p in paths[:L]:
                fit_session(read_pose_table(p, references=model != "9"), model).calibration.save(
                    tmp / "loop" / f"{p.stem}.json")
        _, t = timed(loop)
        rows.append(["files", "per-board loop (read_pose_table, fit_session, save)", L, f"{L / t:.0f}", "",
                     f"{rate / (L / t):.1f}"])

        n = min(store_boards, D)
        if n:
            with Store(tmp / "runs.sqlite") as st:
                for s in ss[:n]:
                    rid = st.start_run(device_serial=s.metadata["serial"], chip="mma8451", station_id="bench",
                                       model=model, units="counts", counts_per_g=CPG)
                    st.finish_run(rid, session=s, calibration=None, verdict=None, model=model)
                src, t_read = timed(lambda: sessions_from_store(st))
            rep, t_fit = timed(lambda: recalibrate(src, model))
            out, t_write = timed(lambda: write_calibrations(rep, tmp / "out-store"))
            assert len(out) == n
            total = t_read + t_fit + t_write
            rows.append(["store", "accelcal batch (query, stacked fit, write JSON)", n, f"{n / total:.0f}",
                         f"{t_read / total:.0%} / {t_fit / total:.0%} / {t_write / total:.0%}", ""])
    return rows


def child(kind: str, model: str, D: int) -> dict:
    """Runs in a fresh interpreter: one memory figure, as a JSON-able dict."""
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB
    if kind == "fit":
        x, ref = lot(D, MEMORY_DESIGN[model], 1)
        x = x / CPG
        tracemalloc.start()
        fit_batch(x, None if model == "9" else ref, model)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return {"input_bytes": x.nbytes, "peak_bytes": peak}
    ss = sessions(D, "an4399-8", 1)
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    rep = recalibrate([(f"run {i}", s) for i, s in enumerate(ss)], model)
    rss2 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {"sessions_bytes": rss1 - rss0, "peak_bytes": rss2 - rss1, "fitted": len(rep.fitted)}


def run_child(kind: str, model: str, D: int) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", kind, "--model", model, "--boards", str(D)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"memory child {kind} {model} failed: {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=2000, help="pose tables end to end (default 2000)")
    ap.add_argument("--loop-boards", type=int, default=300, help="boards in the per-board loop (default 300)")
    ap.add_argument("--store-boards", type=int, default=500, help="runs in the results store (default 500)")
    ap.add_argument("--memory-boards", type=int, default=100_000, help="boards for the memory figures")
    ap.add_argument("--model", default="12", choices=["6", "9", "12", "15"])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--small", action="store_true", help="a quick run: 100 boards, 1000 for memory")
    ap.add_argument("--child", choices=["fit", "recal"], help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(a.child, a.model, a.boards)))
        return 0
    if a.small:
        a.boards, a.loop_boards, a.store_boards = min(a.boards, 100), min(a.loop_boards, 30), min(a.store_boards, 30)
        a.memory_boards = min(a.memory_boards, 1000)
    if a.boards < 1 or a.loop_boards < 1 or a.memory_boards < 1 or a.store_boards < 0:
        print("error: --boards, --loop-boards, --memory-boards >= 1 and --store-boards >= 0", file=sys.stderr)
        return 2
    L = min(a.loop_boards, a.boards)
    print(f"batch recalibration end to end: model {a.model}, 8-pose sessions (an4399-8, counts), "
          f"{a.boards} pose tables, {min(a.store_boards, a.boards)} stored runs; loop on {L}")
    rows = end_to_end(a.boards, L, a.model, a.store_boards, a.seed)
    print(table(["source", "method", "boards", "boards/s", "read / fit / write", "ratio"], rows))
    print("ratio: the batch rate divided by the loop's (fits per second per model: benchmarks/bench_batch_fit.py)")

    D = a.memory_boards
    print(f"\npeak memory for {D} boards (each in a fresh subprocess)")
    mrows = []
    for model in ("6", "12", "15", "9"):
        m = run_child("fit", model, D)
        mrows.append([f"fit_batch model {model} ({MEMORY_DESIGN[model]})", "tracemalloc peak",
                      f"{m['peak_bytes'] / D:.0f}", f"{m['peak_bytes'] / 2**20:.1f}", f"{m['input_bytes'] / D:.0f}"])
    m = run_child("recal", a.model, D)
    if m["fitted"] != D:
        print(f"error: recalibrate fitted {m['fitted']} of {D} boards", file=sys.stderr)
        return 1
    mrows.append([f"batch.recalibrate model {a.model} (an4399-8)", "ru_maxrss delta", f"{m['peak_bytes'] / D:.0f}",
                  f"{m['peak_bytes'] / 2**20:.1f}", f"{m['sessions_bytes'] / D:.0f}"])
    print(table(["what", "measured by", "bytes/board", "MiB total", "input bytes/board"], mrows))
    print("input: the (boards, poses, 3) float64 array for fit_batch; the Session objects for recalibrate "
          "(ru_maxrss delta after building them)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Peak memory of `accelcal fit` on large pose tables and `accelcal simulate --raw` of many samples.

    python benchmarks/bench_resources.py [--fit-rows 12000,100000,200000] [--raw-samples 1000000,10000000]
                                         [--twin-boards 10000,100000] [--lot-boards 50000,200000] [--small]

Each command runs in its own child process, started by a small helper process (ru_maxrss
survives exec, and a child forked from a large process would start with its pages), and the
helper prints the command's own peak resident set (``os.wait4``'s ru_maxrss) and wall time.

1. ``accelcal fit TABLE --model 12``, ``accelcal fit TABLE`` (the model chosen from the data:
   15 for these tables) and ``accelcal fit TABLE --json`` (chosen too), on tables of random
   orientations (issue 26: 12,000 rows reached 1.34 GB, 100,000 asked for 74.5 GiB; the limit
   is 200 MB).
2. ``accelcal simulate --poses six-face --raw --samples N`` (issue 26: 10,000,000 took 108 s and
   7.3 GB; the limit is 200 MB).  The raw log (six poses of N samples, ~23 bytes a sample) is
   written to a temporary folder and removed.
3. ``accelcal twin fit LOT`` on lots of 10,000 and 100,000 boards (tests/twin_lots.py's generator,
   as benchmarks/twin_scale.py), against issue 51's 256 MB (benchmarks/bench_memory.py measures
   100,000 and 1,000,000 boards: 216 / 226 MB; issue 35 measured 319-326 MB).
4. ``accelcal batch LOT --out R.csv --model 12`` on lots of 50,000 and 200,000 boards
   (lot.synthetic.write_lot, an4399-8): memory flat in the lot size (issue 35: the two peaks
   within 10 %), with the wall time.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

LIMIT_MB = 200.0
TWIN_LIMIT_MB = 256.0  # `twin fit` up to 1,000,000 boards: issue 51's bound
RSS_HELPER = """
import os, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
err = p.stderr.read()
_, status, ru = os.wait4(p.pid, 0)
print(os.waitstatus_to_exitcode(status), time.perf_counter() - t0, ru.ru_maxrss / 1024)
sys.stderr.write(err.decode(errors="replace")[-500:])
"""


def write_table(path: Path, n: int, seed: int = 1) -> Path:
    """n poses at random orientations of a sensor with gain, cross-axis, offset and noise (counts)."""
    rng = np.random.default_rng(seed)
    pitch, roll = rng.uniform(-89, 89, n), rng.uniform(-180, 180, n)
    th, ph = np.radians(pitch), np.radians(roll)
    ref = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)])  # AN4399
    K = np.eye(3) + rng.normal(0, 0.01, (3, 3))
    counts = (ref @ K.T + 0.02) * 4096 + rng.normal(0, 2, (n, 3))
    body = np.column_stack([pitch, roll, counts, ref])
    with path.open("w") as f:
        f.write("# units: counts\n# counts_per_g: 4096\n"
                "pose,pitch_deg,roll_deg,x,y,z,ref_x,ref_y,ref_z,n,std_x,std_y,std_z\n")
        for i, row in enumerate(body):
            f.write(f"p{i}," + ",".join(repr(float(v)) for v in row) + ",100,5,5,5\n")
    return path


def measure(args: list[str]) -> tuple[int, float, float]:
    """(exit status, wall s, peak RSS MB) of `accelcal ARGS` in a fresh child."""
    cmd = [sys.executable, "-m", "accelcal_station", *args]
    r = subprocess.run([sys.executable, "-c", RSS_HELPER, *cmd], capture_output=True, text=True)
    status, dt, mb = r.stdout.split()[-3:]
    if int(status) != 0:
        print(f"   (exit {status}: {r.stderr.strip()[-300:]})")
    return int(status), float(dt), float(mb)


def row(what: str, n: int, status: int, dt: float, mb: float, limit: float = LIMIT_MB) -> None:
    verdict = "under" if mb < limit else "OVER"
    print(f"{what:<38}  {n:>12,}  {mb:>9.0f}  {verdict + ' ' + format(limit, '.0f'):>9}  {dt:>7.1f}  {status:>4}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fit-rows", default="12000,100000,200000", help="pose table sizes, comma separated")
    ap.add_argument("--raw-samples", default="1000000,10000000", help="simulate --samples values")
    ap.add_argument("--twin-boards", default="10000,100000", help="twin fit lot sizes, comma separated")
    ap.add_argument("--lot-boards", default="50000,200000", help="accelcal batch lot sizes, comma separated")
    ap.add_argument("--small", action="store_true", help="a quick run (smoke test sizes)")
    a = ap.parse_args(argv)
    if a.small:
        a.fit_rows, a.raw_samples, a.twin_boards, a.lot_boards = "500,2000", "2000,20000", "2000", "2000"
    fit_rows = [int(s) for s in a.fit_rows.split(",") if s.strip()]
    raw_samples = [int(s) for s in a.raw_samples.split(",") if s.strip()]
    print(f"bench_resources: {os.cpu_count()} CPU(s), load average at start {os.getloadavg()[0]:.1f}; "
          f"peak RSS of each command in its own process (limit {LIMIT_MB:.0f} MB)")
    print(f"{'command':<38}  {'size':>12}  {'peak MB':>9}  {'limit':>9}  {'wall s':>7}  {'exit':>4}")
    print(f"{'-' * 38}  {'-' * 12}  {'-' * 9}  {'-' * 9}  {'-' * 7}  {'-' * 4}")
    with tempfile.TemporaryDirectory(prefix="accelcal-bench-resources-") as d:
        work = Path(d)
        for n in fit_rows:
            table = write_table(work / f"poses-{n}.csv", n)
            row("fit TABLE --model 12 (rows)", n, *measure(["fit", str(table), "--model", "12"]))
            row("fit TABLE, model chosen (rows)", n, *measure(["fit", str(table)]))
            row("fit TABLE --json, model chosen (rows)", n, *measure(["fit", str(table), "--json"]))
            table.unlink()
        for n in raw_samples:
            out = work / f"raw-{n}.csv"
            row("simulate six-face --raw (samples)", n,
                *measure(["simulate", "--poses", "six-face", "--raw", "--seed", "1", "--samples", str(n),
                          "--out", str(out)]))
            out.unlink(missing_ok=True)
        for n in [int(s) for s in a.twin_boards.split(",") if s.strip()]:
            sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
            from twin_lots import write_line_lot

            lot = write_line_lot(work / f"lot-{n}.csv", n, step_at=int(n * 0.6))
            row("twin fit LOT (boards)", n, *measure(["twin", "fit", str(lot), "-o", str(work / "twin.yaml")]),
                limit=TWIN_LIMIT_MB)
            Path(lot).unlink()
        lot_peaks(work, [int(s) for s in a.lot_boards.split(",") if s.strip()])
    print(f"load average at end {os.getloadavg()[0]:.1f}")
    return 0


def lot_peaks(work: Path, sizes: list[int]) -> None:
    """`accelcal batch` on CSV and Parquet lots of each size: its peak RSS must not grow with the lot."""
    from accelcal_station.data.lotarrow import arrow_available
    from accelcal_station.lot.synthetic import write_lot

    for kind in ("csv", "parquet") if arrow_available() else ("csv",):
        peaks = []
        for n in sizes:
            lot = write_lot(work / f"lot-{n}.{kind}", n, "an4399-8", seed=35, parquet=kind == "parquet")
            status, dt, mb = measure(["batch", str(lot), "--out", str(work / "r.csv"), "--model", "12"])
            row(f"batch LOT.{kind} --out R.csv (boards)", n, status, dt, mb)
            peaks.append(mb)
            lot.unlink()
        if len(peaks) > 1:
            print(f"batch LOT.{kind} peak RSS, largest / smallest lot: {max(peaks) / min(peaks):.3f}")


if __name__ == "__main__":
    raise SystemExit(main())

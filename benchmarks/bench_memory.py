"""The memory figures of benchmarks/README.md, measured (issue 51): peak RSS of whole processes.

    python benchmarks/bench_memory.py [--batch-boards 50000,200000] [--twin-boards 100000,1000000]
                                      [--lots DIR] [--small]

Each command runs in a fresh child started by a small helper (bench_resources.RSS_HELPER), which
reports the command's own peak resident set (``os.wait4``'s ru_maxrss, the RUSAGE_CHILDREN figure
of that one child: start-up, imports and every page it touched) and its wall time.

1. ``accelcal batch LOT --model 12 --out R.csv`` on CSV and Parquet lots (lot.synthetic.write_lot,
   an4399-8) of each ``--batch-boards`` size: flat in the lot size (a chunk's memory).
2. ``accelcal twin fit LOT -o TWIN.yaml`` on lots of each ``--twin-boards`` size (tests/twin_lots.py's
   line lot, as benchmarks/twin_scale.py): against the 256 MB issue 51 asks at 1,000,000 boards.

``--lots DIR`` keeps the lot files there and reuses them on the next run (a 1,000,000-board twin lot
takes 3-5 minutes to write); without it they are written to a temporary folder and removed.
Prints the date, the machine (CPUs, memory, load average) and one row per figure.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_resources import measure  # noqa: E402 - the sibling benchmark's child-process helper

TWIN_TARGET_MB = 256.0  # issue 51: twin fit at 1,000,000 boards


def _machine() -> str:
    mem_kb = next((int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines()
                   if line.startswith("MemTotal:")), 0) if Path("/proc/meminfo").exists() else 0
    return (f"{platform.machine()}, {os.cpu_count()} CPUs, {mem_kb / 2**20:.0f} GiB, Python "
            f"{platform.python_version()}, load average {os.getloadavg()[0]:.1f}")


def _lot(folder: Path, kind: str, boards: int) -> Path:
    """The lot file of this kind and size in ``folder``, written unless it is there already."""
    if kind == "twin":
        path = folder / f"twin-lot-{boards}.csv"
        if not path.exists():
            sys.path.insert(0, str(HERE.parent / "tests"))
            from twin_lots import write_line_lot

            write_line_lot(path, boards, step_at=int(boards * 0.6))
        return path
    from accelcal_station.lot.synthetic import write_lot

    path = folder / f"lot-{boards}.{kind}"
    return path if path.exists() else write_lot(path, boards, "an4399-8", seed=35, parquet=kind == "parquet")


def _row(what: str, boards: int, status: int, wall_s: float, mb: float, note: str = "") -> float:
    print(f"{what:<34} {boards:>10,} {mb:>9.0f} {wall_s:>8.1f} {status:>5}  {note}")
    return mb


def run(batch_boards: list[int], twin_boards: list[int], folder: Path, keep: bool) -> None:
    from accelcal_station.data.lotarrow import arrow_available

    print(f"bench_memory: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {_machine()}")
    print(f"{'command':<34} {'boards':>10} {'peak MB':>9} {'wall s':>8} {'exit':>5}")
    for kind in ("csv", "parquet") if arrow_available() else ("csv",):
        peaks = []
        for n in batch_boards:
            lot = _lot(folder, kind, n)
            peaks.append(_row(f"batch LOT.{kind} --out R.csv", n,
                              *measure(["batch", str(lot), "--model", "12", "--out", str(folder / "r.csv"),
                                        "--force"])))
            if not keep:
                lot.unlink()
        if len(peaks) > 1:
            print(f"  batch LOT.{kind}: largest / smallest lot {max(peaks) / min(peaks):.3f}")
    for n in twin_boards:
        lot = _lot(folder, "twin", n)
        status, wall_s, mb = measure(["twin", "fit", str(lot), "-o", str(folder / "twin.yaml"), "--force"])
        _row("twin fit LOT", n, status, wall_s, mb,
             f"{'under' if mb < TWIN_TARGET_MB else 'OVER'} {TWIN_TARGET_MB:.0f} MB")
        if not keep:
            lot.unlink()
    print(f"load average at end {os.getloadavg()[0]:.1f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch-boards", default="50000,200000", help="accelcal batch lot sizes, comma separated")
    ap.add_argument("--twin-boards", default="100000,1000000", help="twin fit lot sizes, comma separated")
    ap.add_argument("--lots", default=None, help="keep (and reuse) the lot files in this folder")
    ap.add_argument("--small", action="store_true", help="a quick run (smoke test sizes)")
    a = ap.parse_args(argv)
    if a.small:
        a.batch_boards, a.twin_boards = "500,1000", "600"
    sizes = [[int(s) for s in v.split(",") if s.strip()] for v in (a.batch_boards, a.twin_boards)]
    if a.lots is not None:
        Path(a.lots).mkdir(parents=True, exist_ok=True)
        run(*sizes, Path(a.lots), keep=True)
    else:
        with tempfile.TemporaryDirectory(prefix="accelcal-bench-memory-") as d:
            run(*sizes, Path(d), keep=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

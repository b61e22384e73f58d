"""`accelcal twin fit` at line scale: time and peak memory for 100,000 and 1,000,000 boards.

Writes each lot file first (tests/twin_lots.py's generator: a 10 % cubic subpopulation, a
step in the x offset at 60 % of the lot, correlated and heavy-tailed parameters), then runs
``accelcal twin fit`` in a child process and reads the child's peak resident memory
(getrusage RUSAGE_CHILDREN, one child per size).  Prints both figures and their ratio; the
issue asks for < 1 GB at 1,000,000 boards and within 1.3x of the 100,000-board figure.

    python benchmarks/twin_scale.py [--sizes 100000,1000000] [--dir /tmp]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CHILD = """
import json, resource, subprocess, sys, time
t = time.perf_counter()
r = subprocess.run([sys.executable, "-m", "accelcal_station", "twin", "fit", sys.argv[1], "-o", sys.argv[2], "--json"],
                   capture_output=True, text=True)
dt = time.perf_counter() - t
peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"rc": r.returncode, "s": dt, "peak_mb": peak_kb / 1024, "out": r.stdout,
                  "err": r.stderr[-500:]}))
"""


def one(boards: int, d: Path) -> dict:
    sys.path.insert(0, str(HERE.parent / "tests"))
    from twin_lots import write_line_lot

    lot = d / f"lot-{boards}.csv"
    t = time.perf_counter()
    write_line_lot(lot, boards, step_at=int(boards * 0.6))
    gen_s = time.perf_counter() - t
    r = subprocess.run([sys.executable, "-c", CHILD, str(lot), str(d / f"twin-{boards}.yaml")],
                       capture_output=True, text=True, check=True)
    res = json.loads(r.stdout)
    lot.unlink()
    if res["rc"] != 0:
        raise SystemExit(f"twin fit failed on {boards} boards: {res['out']} {res['err']}")
    found = json.loads(res["out"]) if res["out"].startswith("{") else {}
    return {"boards": boards, "generate_s": gen_s, "fit_s": res["s"], "peak_mb": res["peak_mb"],
            "components": [round(c["weight"], 4) for c in found.get("components", [])],
            "changes": [(c["quantity"], c["at_board"]) for c in found.get("changes", [])]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100000,1000000", help="comma-separated lot sizes (boards)")
    ap.add_argument("--dir", default=None, help="folder for the temporary lot files")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=a.dir) as tmp:
        rows = [one(int(n), Path(tmp)) for n in a.sizes.split(",")]
    for r in rows:
        print(f"{r['boards']:>9} boards: twin fit {r['fit_s']:.1f} s, peak {r['peak_mb']:.0f} MB "
              f"(lot written in {r['generate_s']:.1f} s); components {r['components']}; changes {r['changes']}")
    if len(rows) >= 2:
        print(f"peak memory ratio {rows[-1]['boards']} / {rows[0]['boards']} boards: "
              f"{rows[-1]['peak_mb'] / rows[0]['peak_mb']:.2f}x (target <= 1.3x, and < 1024 MB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

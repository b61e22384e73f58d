"""Hit rate and false-naming rate of `accelcal diagnose` over many seeds per self-test case.

Every case of accelcal_station.diagnosis.selftest (each catalog effect, each off-catalog
effect, the two-effect cases, the null cases) is run at SEEDS seeds on forward-physics
boards.  hit: the case's pass rule holds (module doc of diagnose_selftest).  false naming:
the diagnosis names an effect that the board does not have (for off-catalog and null
cases: names anything).  Prints a Markdown table; not run in CI (minutes).

    python benchmarks/bench_diagnose.py [SEEDS] [PROCESSES]
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from multiprocessing import Pool

from accelcal_station.diagnosis.loading import load_simulator
from accelcal_station.diagnosis.selftest import _cases, run_case

LOG = os.environ.get("BENCH_DIAGNOSE_LOG")  # optional: one JSON line per run, for partial results


def _one(args):
    k, seed = args
    sim0 = load_simulator(None)
    case = _cases()[k]
    r = run_case(sim0.device, sim0.model.to_config(), case, 1000 * seed + k)
    withheld = set(case[2])
    false = [e for e in r["selected"] if e not in withheld]
    return k, r["pass"], bool(false), r["verdict"]


def main(seeds: int = 50, procs: int = 2) -> None:
    cases = _cases()
    jobs = [(k, s) for s in range(1, seeds + 1) for k in range(len(cases))]
    t0 = time.time()
    hits = [0] * len(cases)
    falses = [0] * len(cases)
    verdicts: list[dict] = [{} for _ in cases]
    with (open(LOG, "a") if LOG else contextlib.nullcontext()) as log, Pool(procs) as pool:
        for k, ok, false, verdict in pool.imap(_one, jobs, chunksize=1):
            if log:
                log.write(json.dumps([k, ok, false, verdict]) + "\n")
                log.flush()
            hits[k] += ok
            falses[k] += false
            verdicts[k][verdict] = verdicts[k].get(verdict, 0) + 1
    print(f"{seeds} seeds per case, {time.time() - t0:.0f} s on {procs} processes")
    print("| case | data | expect | hit rate | false-naming rate | verdicts |")
    print("|---|---|---|---|---|---|")
    for k, (name, kind, _, _, expect) in enumerate(cases):
        v = ", ".join(f"{a} {b}" for a, b in sorted(verdicts[k].items(), key=lambda x: -x[1]))
        print(f"| {name} | {kind} | {expect} | {hits[k] / seeds:.2f} | {falses[k] / seeds:.2f} | {v} |")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 50, int(sys.argv[2]) if len(sys.argv) > 2 else 2)

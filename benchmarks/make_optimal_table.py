"""Write fixtures/optimal_table.py: the optimal-N designs for N = 2..MAX_OPTIMAL_N, computed once.

    python benchmarks/make_optimal_table.py               # a fresh multistart search for every N
    python benchmarks/make_optimal_table.py --from-table  # re-polish the tabled designs, canonical form

optimal_design(N) is a deterministic multistart SLSQP (fixed seed) costing ~N^3 a start: optimal-24
takes some 10 s of CPU.  The station looks the designs up in the table instead.  Every design is
written in its canonical form (fixtures/designs.py, canonical_angles: one fixed representative of
the 48 signed axis permutations), so a search that lands on a symmetric equivalent of the optimum
on another machine writes the same table; distinct optima whose separations tie (within 1e-9 g)
go to the smallest canonical angles, not to floating-point noise.  ``--from-table`` polishes each
tabled design to its local optimum (SLSQP from the tabled angles) and canonicalises it: the same
designs, no new search.
"""
from __future__ import annotations

import sys
from pathlib import Path

from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.designs import (
    MAX_OPTIMAL_N,
    canonical_angles,
    min_separation,
    optimal_design,
    polish_design,
    references,
)

OUT = Path(__file__).resolve().parents[1] / "fixtures" / "optimal_table.py"


def _from_table(n: int) -> list[tuple[float, float]]:
    from accelcal_station.fixtures.optimal_table import OPTIMAL

    ref = references([PoseSpec(f"p{i + 1}", t, r) for i, (t, r) in enumerate(OPTIMAL[n])])
    polished = canonical_angles(polish_design(ref))
    kept = canonical_angles(ref)
    # never trade a tabled design for a worse one (rounding to 0.01 deg costs ~1e-4 g either way)
    return polished if _separation(polished) >= _separation(kept) else kept


def _separation(angles: list[tuple[float, float]]) -> float:
    return min_separation(references([PoseSpec(f"p{i + 1}", t, r) for i, (t, r) in enumerate(angles)]))


def main(argv: list[str]) -> None:
    from_table = "--from-table" in argv
    lines = ['"""The optimal-N pose designs (fixtures/designs.py, optimal_design) for N = 2..24, as computed by',
             "benchmarks/make_optimal_table.py, in canonical form (designs.canonical_angles): (pitch_deg, roll_deg)",
             'per pose; looked up, not recomputed.', '"""',
             "from __future__ import annotations", "", "OPTIMAL: dict[int, tuple[tuple[float, float], ...]] = {"]
    for n in range(2, MAX_OPTIMAL_N + 1):
        angles = _from_table(n) if from_table else [(p.pitch_deg, p.roll_deg) for p in optimal_design(n)]
        poses = [f"({t!r}, {r!r})" for t, r in angles]
        lines.append(f"    {n}: (")
        lines.extend("        " + ", ".join(poses[k:k + 4]) + "," for k in range(0, len(poses), 4))
        lines.append("    ),")
    lines.append("}")
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main(sys.argv[1:])

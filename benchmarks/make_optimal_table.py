"""Write fixtures/optimal_table.py: the optimal-N designs for N = 2..MAX_OPTIMAL_N, computed once.

    python benchmarks/make_optimal_table.py

optimal_design(N) is a deterministic multistart SLSQP (fixed seed) costing ~N^3 a start: optimal-24
takes some 10 s of CPU.  The station looks the designs up in the table instead (the same numbers,
tests/test_hostile_files.py checks the small ones against a fresh computation).
"""
from __future__ import annotations

from pathlib import Path

from accelcal_station.fixtures.designs import MAX_OPTIMAL_N, optimal_design

OUT = Path(__file__).resolve().parents[1] / "fixtures" / "optimal_table.py"


def main() -> None:
    lines = ['"""The optimal-N pose designs (fixtures/designs.py, optimal_design) for N = 2..24, as computed by',
             "benchmarks/make_optimal_table.py: (pitch_deg, roll_deg) per pose; looked up, not recomputed.", '"""',
             "from __future__ import annotations", "", "OPTIMAL: dict[int, tuple[tuple[float, float], ...]] = {"]
    for n in range(2, MAX_OPTIMAL_N + 1):
        poses = [f"({p.pitch_deg!r}, {p.roll_deg!r})" for p in optimal_design(n)]
        lines.append(f"    {n}: (")
        lines.extend("        " + ", ".join(poses[k:k + 4]) + "," for k in range(0, len(poses), 4))
        lines.append("    ),")
    lines.append("}")
    OUT.write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()

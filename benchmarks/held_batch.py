"""Held terms at lot scale: fit_batch (the one front of `accelcal batch` and lot files) on 20,000
boards of issue 22's ten-pose design (six faces and four tilts in the x-z and y-z planes: M_xy
held at 0 by the stacked Gauss-Newton with a free mask) against the same boards with two more
poses between +x and +y (nothing held).  Forward model: symmetric K = I + N(0, 0.01), offset
N(0, 30 mg), 1 mg noise per pose mean.  Prints boards/s, how many were held and refused, the
median leave-one-out, and the time the hold decision (held.hold_plans) takes alone.

    python benchmarks/held_batch.py
"""
from __future__ import annotations

import time
from collections import Counter

import numpy as np

from accelcal_station.conventions import an4399_reference
from accelcal_station.models.fitting import fit_batch
from accelcal_station.models.held import hold_plans

FACES = [(-90.0, 0.0), (90.0, 0.0), (0.0, 90.0), (0.0, -90.0), (0.0, 0.0), (0.0, 180.0)]
TILTS = [(-45.0, 0.0), (45.0, 180.0), (0.0, 45.0), (0.0, -135.0)]
XY = [(-45.0, 90.0), (45.0, -90.0)]
BOARDS = 20_000


def lot(poses: list[tuple[float, float]], D: int, rng: np.random.Generator) -> np.ndarray:
    ref = np.array([an4399_reference(p, r) for p, r in poses])
    K = np.eye(3) + rng.normal(0, 0.01, (D, 3, 3))
    K = 0.5 * (K + K.transpose(0, 2, 1))
    return np.einsum("dij,pj->dpi", K, ref) + rng.normal(0, 0.03, (D, 1, 3)) + rng.normal(0, 1e-3, (D, len(poses), 3))


def main() -> None:
    rng = np.random.default_rng(0)
    for name, poses in (("ten poses (M_xy weak)", FACES + TILTS), ("twelve poses (x-y tilts)", FACES + TILTS + XY)):
        x = lot(poses, BOARDS, rng)
        fit_batch(x[:100], None, "9")  # warm-up
        t = time.perf_counter()
        plan = hold_plans(x, "9")
        t_plan = time.perf_counter() - t
        t = time.perf_counter()
        b = fit_batch(x, None, "9")
        dt = time.perf_counter() - t
        held = Counter(", ".join(h.term for h in hs) or "nothing" for hs in b.held)
        print(f"{name}: {BOARDS} boards in {dt:.2f} s ({BOARDS / dt:.0f} boards/s; hold decision alone "
              f"{t_plan:.2f} s); fitted {int(b.ok.sum())}; held {dict(held)}; refused "
              f"{dict(Counter(m for m, o in zip(b.messages, b.ok, strict=True) if not o))}; "
              f"median leave-one-out {np.nanmedian(b.crossval_rms_g) * 1e3:.3f} mg; plan refusals "
              f"{sum(bool(r) for r in plan.refused)}")


if __name__ == "__main__":
    main()

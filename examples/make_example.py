"""Generate examples/poses.csv: a simulated 14-pose session of one MMA8451 board.

Deterministic (fixed seed), so the shipped table is exactly what this script writes:
  python examples/make_example.py
Then fit it:  accelcal fit examples/poses.csv   (fit picks model 15: the board has a cubic term)

The board: 4096 counts/g, gain errors of a few percent, cross-axis coupling, offsets
of tens of mg and a small cubic term; 256 samples per pose with 1.5 mg noise.  Poses:
the six faces plus the eight cube vertices (AN4399 pitch/roll).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from accelcal_station.conventions import an4399_reference
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.session import PoseRecord, Session

COUNTS_PER_G = 4096
N_SAMPLES = 256
NOISE_G = 0.0015
FACES = [(0, 0), (0, 180), (-90, 0), (90, 0), (0, 90), (0, -90)]
VERTEX_PITCH = float(np.round(np.rad2deg(np.arcsin(1 / np.sqrt(3))), 3))
VERTICES = [(s * VERTEX_PITCH, r) for s in (1, -1) for r in (45, 135, -45, -135)]


def make_session(seed: int = 4399) -> Session:
    rng = np.random.default_rng(seed)
    S = np.array([[1.021, 0.012, -0.004], [0.009, 0.987, 0.015], [-0.006, 0.011, 1.034]])
    offset_g = np.array([0.031, -0.018, 0.042])
    cubic = np.array([0.004, -0.006, 0.003])
    poses = []
    for i, (pitch, roll) in enumerate(FACES + VERTICES):
        g = an4399_reference(pitch, roll)
        raw_g = S @ g + offset_g + cubic * g**3
        samples = np.round((raw_g + rng.normal(scale=NOISE_G, size=(N_SAMPLES, 3))) * COUNTS_PER_G)
        poses.append(PoseRecord(f"p{i + 1:02d}", np.round(samples.mean(axis=0), 3),
                                np.round(samples.std(axis=0, ddof=1), 2), N_SAMPLES,
                                pitch_deg=pitch, roll_deg=roll, temp_c=25.0))
    return Session(poses, "counts", COUNTS_PER_G, device="mma8451 (simulated)")


def main(out: Path) -> None:
    write_pose_table(make_session(), out, {"note": "simulated by examples/make_example.py; AN4399 angles, z down"})


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("poses.csv"))

"""Write the derived pose tables of tests/data from the transcribed originals (see README.md).

    python tests/data/make_tables.py

Deterministic: the tables hold the originals' numbers exactly (shortest round-trip floats).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from accelcal_station.data.posetable import write_pose_table
from accelcal_station.session import PoseRecord, Session

HERE = Path(__file__).resolve().parent


def nine_position_faces() -> Session:
    """The paper's Table 3: six MPU6050 faces in m/s^2, references = expected gravity direction."""
    src = yaml.safe_load((HERE / "nine_position_paper.yaml").read_text())
    poses = [PoseRecord(name, np.array(p["reading"], float), reference_g=np.array(p["expected"], float))
             for name, p in src["positions"].items()]
    return Session(poses, "mps2", None, 9.79, "mpu6050",
                   {"source": "nine-position calibration paper, Table 3 (tests/data/nine_position_paper.yaml)"})


def calibraxis_set(key: str) -> Session:
    src = yaml.safe_load((HERE / "calibraxis_points.yaml").read_text())
    poses = [PoseRecord(f"c{i + 1:02d}", np.array(m, float)) for i, m in enumerate(src[key])]
    return Session(poses, "counts", None, None, None,
                   {"source": f"hbldh/calibraxis tests, {key} (tests/data/calibraxis_points.yaml)"})


TABLES = {
    "nine_position_paper_faces.csv": nine_position_faces,
    "calibraxis_set_1.csv": lambda: calibraxis_set("set_1_counts"),
    "calibraxis_set_2.csv": lambda: calibraxis_set("set_2_counts"),
}

if __name__ == "__main__":
    for name, make in TABLES.items():
        write_pose_table(make(), HERE / name)
        print(HERE / name)

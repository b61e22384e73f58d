"""Thermal calibration time per board: soak, sampling floor and the rest, on the emulated chamber.

    python benchmarks/bench_thermal_time.py [--boards 3] [--config configs/thermal-sim.yaml]

Runs the thermal plan of ``--config`` (default: -20, 25, 70 C calibration, 45 C
verification, MPU6050 at 100 Hz, an4399-8, the chamber emulator's first-order air and
board) for ``--boards`` boards (fixed seeds).  Time is the board's virtual clock: the
soak (the chamber's air time constant and the board's lag against the soak rule), the
sampling floor (samples averaged / ODR) and the rest (jig moves, samples read while
waiting for stillness, EEPROM writes).  Each board starts in a chamber at room
temperature, so the first set point's pull-down is counted.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import table  # noqa: E402

from accelcal_station.drivers import make_driver  # noqa: E402
from accelcal_station.station import StationConfig  # noqa: E402
from accelcal_station.thermal import ThermalStation  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PARTS = ("soak_s", "sampling_floor_s", "rest_s", "board_time_s")
LABELS = {"soak_s": "soak (all set points)", "sampling_floor_s": "sampling floor (averaged / ODR)",
          "rest_s": "rest (moves, gating, EEPROM)", "board_time_s": "total per board"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=3)
    ap.add_argument("--config", default=str(REPO / "configs" / "thermal-sim.yaml"))
    ap.add_argument("--seed", type=int, default=100)
    a = ap.parse_args(argv)
    acc = {k: [] for k in PARTS}
    verdicts = []
    with tempfile.TemporaryDirectory() as d:
        cfg = StationConfig.load(a.config, store_override=Path(d) / "runs.sqlite")
        for i in range(a.boards):
            driver = make_driver({**cfg.raw["device"], "seed": a.seed + i})
            rep = ThermalStation(cfg, echo=lambda *_: None, driver=driver).run()
            verdicts.append(rep.verdict)
            for k in PARTS:
                acc[k].append(rep.timing[k])
    mean = {k: float(np.mean(v)) for k, v in acc.items()}
    total = mean["board_time_s"]
    rows = [[LABELS[k], f"{mean[k]:.0f}" if k != "sampling_floor_s" else f"{mean[k]:.1f}", f"{mean[k] / total:.3f}"]
            for k in PARTS]
    rows.append(["ratio: total / sampling floor", f"{total / mean['sampling_floor_s']:.1f}", ""])
    print(f"thermal plan {Path(a.config).name}: {a.boards} board(s), one at a time (virtual clock, s)")
    print(table(["per board", "seconds", "share"], rows))
    print(f"verdicts: {', '.join(sorted(set(verdicts)))}")
    print("panel: this station calibrates one board per plan; a panel's per-board figure is not measured here")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

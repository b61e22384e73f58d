"""Thermal calibration time per board: soak, sampling floor and the rest, one board and a panel.

    python benchmarks/bench_thermal_time.py [--boards 1] [--panel 16]

Runs, in one process, the thermal plan of configs/thermal-sim.yaml on ``--boards`` single
boards, one at a time (fixed seeds), and of configs/thermal-panel-sim.yaml on a panel of
``--panel`` boards (the same plan, chamber and board: -20, 25, 70 C calibration, 45 C
verification, MPU6050 at 100 Hz, an4399-8).  Time is the boards' virtual clock: the soak
(the chamber's air time constant and the board's lag against the soak rule), the sampling
floor (samples averaged / ODR; on a panel, per pose the longest board's, since the boards
are captured at once) and the rest (jig moves, samples read while waiting for stillness,
EEPROM writes).  A panel's per-board figure is its time divided by its boards: it soaks
once for all of them.  Each run starts in a chamber at room temperature, so the first set
point's pull-down is counted.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import table

from accelcal_station.drivers.factory import make_driver
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig

REPO = Path(__file__).resolve().parents[1]
PARTS = ("soak_s", "sampling_floor_s", "rest_s", "board_time_s")
LABELS = {"soak_s": "soak (all set points)", "sampling_floor_s": "sampling floor (averaged / ODR)",
          "rest_s": "rest (moves, gating, EEPROM)", "board_time_s": "total per board"}


def single_boards(config: str, boards: int, seed: int, store: Path) -> tuple[dict[str, float], list[str]]:
    """Mean split over ``boards`` single-board runs (s per board)."""
    acc: dict[str, list[float]] = {k: [] for k in PARTS}
    verdicts = []
    cfg = StationConfig.load(config, store_override=store)
    for i in range(boards):
        driver = make_driver(cfg.device.model_copy(update={"seed": seed + i}))
        rep = make_flow(cfg, echo=lambda *_: None, driver=driver).run()[0]
        verdicts.append(rep.verdict)
        for k in PARTS:
            acc[k].append(rep.timing[k])
    return {k: float(np.mean(v)) for k, v in acc.items()}, verdicts


def panel(config: str, boards: int, store: Path) -> tuple[dict[str, float], list[str]]:
    """The panel's split divided by its boards (s per board)."""
    cfg = StationConfig.load(config, store_override=store)
    cfg = cfg.with_sections(device=cfg.device.model_copy(update={"boards": boards}))
    station = make_flow(cfg, echo=lambda *_: None)
    reps = station.run()
    return dict(station.timing["per_board"]), [r.verdict for r in reps]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=1, help="single boards, one at a time (mean)")
    ap.add_argument("--panel", type=int, default=16, help="boards on the panel")
    ap.add_argument("--seed", type=int, default=100)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        one, v1 = single_boards(str(REPO / "configs" / "thermal-sim.yaml"), a.boards, a.seed, Path(d) / "one.sqlite")
        pan, vp = panel(str(REPO / "configs" / "thermal-panel-sim.yaml"), a.panel, Path(d) / "panel.sqlite")
    rows = []
    for k in PARTS:
        fmt = (lambda x: f"{x:.1f}") if k == "sampling_floor_s" else (lambda x: f"{x:.0f}")
        rows.append([LABELS[k], fmt(one[k]), f"{one[k] / one['board_time_s']:.3f}", fmt(pan[k]),
                     f"{pan[k] / pan['board_time_s']:.3f}", f"{one[k] / pan[k]:.1f}"])
    print(f"thermal plan, time per board (virtual clock, s): {a.boards} single board(s) one at a time "
          f"vs a {a.panel}-board panel in one chamber")
    print(table(["per board", "one board", "share", f"{a.panel}-board panel", "share", "one / panel"], rows))
    print(f"ratio total / sampling floor: one board {one['board_time_s'] / one['sampling_floor_s']:.1f}, "
          f"panel {pan['board_time_s'] / pan['sampling_floor_s']:.1f}")
    print(f"verdicts: one board {', '.join(sorted(set(v1)))}; panel {', '.join(sorted(set(vp)))} "
          f"({vp.count('PASS')}/{len(vp)} PASS)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

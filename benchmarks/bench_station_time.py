"""Station time per board against its floor (the time budget, station/time_budget.py), simulated board.

    python benchmarks/bench_station_time.py [--boards 10] [--panel 16] [--config configs/sim.yaml] [--small]

Runs ``accelcal run``'s Station on the default simulated configuration (MMA8451
at 100 Hz, 8 poses an4399-8, model 12, 3 verification poses, NVM burn, SQLite
store) for ``--boards`` boards (fixed seeds) and prints each board's time budget
(RunReport.time_budget, station/time_budget.py; mean over the boards): sampling,
stillness, verification, jig moves (settle + angle / rated speed, along the shortest
path), EEPROM, host compute not hidden under a move, and the floor for the configured
quality (sampling to the capture target at the measured noise and n_eff, the jig's
shortest travel, the EEPROM's write cycles) with the ratio total / floor.  Time is
*virtual*: the board's clock advances by n / ODR per n samples, by each move and by
the EEPROM's write cycles, without waiting; host compute is wall time.

Panel (``--panel N``, default 16): the same configuration as a panel of N boards on one
jig (panel.py): the panel's budget (the slowest board's device parts, the whole panel's
host compute) with the I2C bus time to read N boards through a TCA9548A, per board
beside (single-board time / N).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import table

from accelcal_station.config.schema import DeviceSection, VerifySection
from accelcal_station.drivers.factory import make_driver
from accelcal_station.station.capture import DEFAULT_SEM_MG
from accelcal_station.station.flow import make_flow
from accelcal_station.station.settings import StationConfig
from accelcal_station.station.time_budget import COMPONENTS, bus_limit_boards

LABELS = {
    "warmup_s": "warm-up (capture.warmup)",
    "self_test_s": "self-test",
    "sampling_s": "sampling: fit poses (averaged / ODR)",
    "stillness_s": "waiting for stillness, the hold",
    "verification_s": "verification poses",
    "jig_moves_s": "jig moves (settle + angle / rated speed)",
    "eeprom_s": "EEPROM write cycles, read-back",
    "host_compute_s": "host compute not under a move (wall)",
    "operator_s": "operator",
}


def seeded(cfg: StationConfig, seed: int) -> DeviceSection:
    """The config's device section with its seed set."""
    return cfg.device.model_copy(update={"seed": seed})


def capture_target(cfg: StationConfig) -> str:
    """The capture's stopping rule in words: the parameter targets (sequential capture) or the per-pose SEM."""
    c = cfg.capture
    if c.target_offset_u_mg is None and c.target_gain_u is None:
        return f"target {c.target_sem_mg or DEFAULT_SEM_MG:g} mg a pose"
    parts = [f"offset u {c.target_offset_u_mg:g} mg" if c.target_offset_u_mg is not None else "",
             f"gain u {c.target_gain_u:g}" if c.target_gain_u is not None else ""]
    return "to parameter targets: " + ", ".join(p for p in parts if p)


def run_boards(cfg: StationConfig, boards: int, seed: int) -> tuple[dict[str, float], dict]:
    """Mean time budget (station/time_budget.py) over ``boards`` runs, and facts of the runs.

    One extra board runs first and is not counted: it pays the process's one-time
    imports, which no later board pays.
    """
    acc: dict[str, list[float]] = {}
    facts: dict = {"verdicts": [], "stderr_offset_mg": [], "verify_mg": []}
    make_flow(cfg, echo=lambda *_: None, driver=make_driver(seeded(cfg, seed - 1))).run()
    for i in range(boards):
        rep = make_flow(cfg, echo=lambda *_: None, driver=make_driver(seeded(cfg, seed + i))).run()[0]
        for k, v in rep.time_budget.items():
            acc.setdefault(k, []).append(float(v))  # type: ignore[arg-type]
        facts["verdicts"].append(rep.verdict)
        facts["stderr_offset_mg"].append(rep.measured.get("stderr_offset_max_mg", float("nan")))
        facts["verify_mg"].append(rep.verify_error_max_mg or float("nan"))
        facts["odr_hz"] = rep.timing["odr_hz"]
    return {k: float(np.mean(v)) for k, v in acc.items()}, facts


def run_panel(cfg: StationConfig, boards: int, seed: int) -> tuple[dict, list]:
    """One panel of ``boards`` boards (seeds from ``seed``): the panel's timing and its boards' reports."""
    panel_cfg = cfg.with_sections(device=cfg.device.model_copy(update={"boards": boards, "seed": seed}))
    st = make_flow(panel_cfg, echo=lambda *_: None)
    reports = st.run()
    return dict(st.timing), reports


def budget_rows(res: dict[str, float]) -> list[list[str]]:
    """The budget's rows: each component, the total, the floor and the ratio."""
    rows = [[LABELS[k], f"{res.get(k, 0.0):.2f}", f"{res.get(k, 0.0) / res['total_s']:.0%}"] for k in COMPONENTS]
    rows.append(["total", f"{res['total_s']:.2f}", "100%"])
    rows.append([f"floor (sampling {res['floor_sampling_s']:.2f} + jig {res['floor_jig_s']:.2f} + EEPROM "
                 f"{res['floor_eeprom_s']:.2f})", f"{res['floor_s']:.2f}", ""])
    rows.append(["ratio: total / floor", f"{res['total_s'] / res['floor_s']:.2f}", ""])
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=10, help="boards per configuration (default 10)")
    ap.add_argument("--config", default=None, help="station configuration (default: configs/sim.yaml)")
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--panel", type=int, default=16, help="boards on the panel (default 16; 0: no panel)")
    ap.add_argument("--small", action="store_true", help="a quick run: 2 boards per configuration")
    a = ap.parse_args(argv)
    if a.small:
        a.boards = min(a.boards, 2)
    if a.boards < 1:
        print("error: --boards must be >= 1", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="accelcal-bench-") as tmp:
        cfg = StationConfig.load(a.config, store_override=Path(tmp) / "runs.sqlite")
        if cfg.device.driver != "simulated" or cfg.jig.type != "simulated":
            print("error: --config: this benchmark needs device.driver: simulated and jig.type: simulated",
                  file=sys.stderr)
            return 2
        res, facts = run_boards(cfg, a.boards, a.seed)
        panel = run_panel(cfg, a.panel, a.seed) if a.panel > 0 else None
    print(f"station time per board (virtual time: device clock + host wall compute), mean of {a.boards} simulated "
          f"boards: {cfg.device.chip or 'mma8451'} at {facts['odr_hz']:g} Hz, design {cfg.design} + "
          f"{cfg.verify_poses} verification poses ({(cfg.schema.verify or VerifySection()).mode}), model {cfg.model}, "
          f"capture {capture_target(cfg)}")
    print(f"verdicts: {', '.join(sorted(set(facts['verdicts'])))}; offset standard error max "
          f"{np.nanmax(facts['stderr_offset_mg']):.4f} mg; verification error max "
          f"{np.nanmax(facts['verify_mg']):.3f} mg")
    print(table(["seconds per board", "single", "share"], budget_rows(res)))
    if panel is not None:
        t, reports = panel
        pb = t["time_budget"]
        verdicts = sorted({r.verdict for r in reports})
        se = max(r.measured.get("stderr_offset_max_mg", float("nan")) for r in reports)
        ve = max(r.verify_error_max_mg or float("nan") for r in reports)
        print(f"panel of {a.panel} boards on one jig (verdicts: {', '.join(verdicts)}; offset standard error max "
              f"{se:.4f} mg; verification error max {ve:.3f} mg): {pb['total_s']:.2f} s, "
              f"{pb['per_board_s']:.2f} s a board")
        rows = budget_rows(dict(pb))
        rows.insert(-2, [f"I2C bus time ({a.panel} boards x samples, TCA9548A, 400 kHz)",
                         f"{pb['bus_time_s']:.2f}", ""])
        print(table(["seconds per panel", "panel", "share"], rows))
        print(table(["seconds per board", "value"], [
            ["single board (mean above)", f"{res['total_s']:.2f}"],
            [f"single board / {a.panel}", f"{res['total_s'] / a.panel:.2f}"],
            [f"panel of {a.panel}, per board", f"{pb['per_board_s']:.2f}"],
            [f"ratio: panel per board / (single / {a.panel}), goal <= 1.2",
             f"{pb['per_board_s'] / (res['total_s'] / a.panel):.2f}"]]))
        print(f"the bus sets the pace beyond {bus_limit_boards(facts['odr_hz'])} boards a bus at "
              f"{facts['odr_hz']:g} Hz (docs/timing.md)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

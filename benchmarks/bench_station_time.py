"""Station time per board against the sampling floor, on the simulated board at its real data rate.

    python benchmarks/bench_station_time.py [--boards 10] [--panel 16] [--config configs/sim.yaml] [--small]

Runs ``accelcal run``'s Station on the default simulated configuration (MMA8451
at 100 Hz, 8 poses an4399-8, model 12, 3 verification poses, NVM burn, SQLite
store) for ``--boards`` boards (fixed seeds), and again with the jig's
``move_time_s`` set to 0, which leaves the station's own overhead.  Time is
*virtual*: the board's clock advances by n / ODR per n samples, by the jig's
move time per pose and by the EEPROM's write cycles, without waiting; a board's
time is that device time plus the host's wall-clock compute (RunReport.timing:
board_time_s = device_time_s + host_compute_s).

Split per board (mean): the sampling floor (samples averaged / ODR, fit and
verification poses), samples read but not averaged (waiting for stillness and
the hold time), jig moves (poses presented x move_time_s), other device time
(EEPROM write cycles and read-back), host compute (fit, simulation, store).
The floor itself is set by the capture targets: with parameter targets (sequential capture,
station/sequential_capture.py) the fit poses need the samples models/allocation.py allocates at
the chip's known noise (tau_int = 1); a per-pose target ``capture.target_sem_mg`` (the compat rule,
and every verification capture: 0.05 mg when unset) needs (sigma / target)^2 samples per pose.

Panel (``--panel N``, default 16): the same configuration as a panel of N boards on one
jig (panel.py): every pose presented once and captured on all boards at once.  Its time
is the longest board's device time plus the host's wall time for the whole panel (fits,
simulation and store of all N boards); per board it is that divided by N, printed beside
(single-board time / N) and their ratio, all measured in this run.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import table

from accelcal_station.config.schema import DeviceSection
from accelcal_station.drivers.factory import make_driver
from accelcal_station.fixtures.designs import get_design
from accelcal_station.models.allocation import allocate, block_variance
from accelcal_station.station.capture import DEFAULT_SEM_MG
from accelcal_station.station.flow import make_flow
from accelcal_station.station.sequential_capture import plan_for
from accelcal_station.station.settings import StationConfig

COMPONENTS = ("floor_fit", "floor_verify", "gating", "moves", "other_device", "host")
LABELS = {
    "floor_fit": "sampling floor: fit poses (averaged / ODR)",
    "floor_verify": "sampling floor: verification poses",
    "gating": "samples read, not averaged (stillness, hold)",
    "moves": "jig moves (poses presented x move_time_s)",
    "other_device": "other device time (EEPROM writes, read-back)",
    "host": "host compute (fit, simulator, store; wall)",
}


def seeded(cfg: StationConfig, seed: int) -> DeviceSection:
    """The config's device section with its seed set."""
    return cfg.device.model_copy(update={"seed": seed})


def run_boards(cfg: StationConfig, boards: int, seed: int) -> tuple[dict, dict]:
    """Mean seconds per component over ``boards`` runs, and facts of the runs.

    One extra board runs first and is not counted: it pays the process's one-time
    imports (scipy.stats for the capture gate), which no later board pays.
    """
    move = cfg.jig.move_time_s
    acc = {k: [] for k in COMPONENTS + ("total", "device")}
    facts = {"verdicts": [], "samples_per_pose": [], "stderr_offset_mg": []}
    make_flow(cfg, echo=lambda *_: None, driver=make_driver(seeded(cfg, seed - 1))).run()
    for i in range(boards):
        driver = make_driver(seeded(cfg, seed + i))
        rep = make_flow(cfg, echo=lambda *_: None, driver=driver).run()[0]
        t = rep.timing
        odr = t["odr_hz"]
        n_fit = sum(p["n"] for p in rep.poses)
        n_verify = t["samples_averaged"] - n_fit
        reused = 1 if rep.verify_mode == "fit-poses" else 0  # the first fit-pose verification needs no move
        presented = len(rep.poses) + (cfg.verify_poses - reused if rep.verify_error_max_mg is not None else 0)
        moves = presented * move
        acc["floor_fit"].append(n_fit / odr)
        acc["floor_verify"].append(n_verify / odr)
        acc["gating"].append((t["samples_read"] - t["samples_averaged"]) / odr)
        acc["moves"].append(moves)
        acc["other_device"].append(t["device_time_s"] - t["sampling_s"] - moves)
        acc["host"].append(t["host_compute_s"])
        acc["device"].append(t["device_time_s"])
        acc["total"].append(t["board_time_s"])
        facts["verdicts"].append(rep.verdict)
        facts["samples_per_pose"] += [p["n"] for p in rep.poses]
        facts["stderr_offset_mg"].append(rep.measured.get("stderr_offset_max_mg", float("nan")))
        facts["odr_hz"] = odr
    return {k: float(np.mean(v)) for k, v in acc.items()}, facts


def run_panel(cfg: StationConfig, boards: int, seed: int) -> tuple[dict, list[str]]:
    """One panel of ``boards`` boards (seeds from ``seed``): the panel's timing and the verdicts."""
    panel_cfg = cfg.with_sections(device=cfg.device.model_copy(update={"boards": boards, "seed": seed}))
    st = make_flow(panel_cfg, echo=lambda *_: None)
    reports = st.run()
    return st.timing, [r.verdict for r in reports]


def needed_samples(cfg: StationConfig) -> tuple[float, float]:
    """Samples the fit poses need in all and one verification pose needs, per the simulated chip's
    noise (white noise and the LSB^2/12 of quantization, tau_int = 1): the sequential plan's allocation
    with parameter targets, else (sigma / target_sem)^2 per pose."""
    board = make_driver(seeded(cfg, 0)).board
    var = (np.asarray(board.noise_sigma_counts, dtype=float) ** 2 + 1.0 / 12.0) / board.counts_per_g**2  # g^2
    sem = cfg.capture.target_sem_mg or DEFAULT_SEM_MG
    per_pose = float(np.max(var)) / (sem * 1e-3) ** 2
    design = get_design(cfg.design)
    plan = plan_for(cfg.model, cfg.capture, [p.reference_g for p in design], board.counts_per_g, 1e9)
    if plan is None:
        return per_pose * len(design), per_pose
    alloc = allocate(plan.rows, np.zeros(plan.rows.A.shape[:2]), block_variance(plan.rows, var),
                     np.ones(len(design), dtype=bool), plan.target_var, 1, 10**9)
    fit = float(np.sum(alloc.n))
    if cfg.capture.target_sem_mg is not None:  # a floor every pose reaches as well
        fit = float(np.sum(np.maximum(alloc.n, per_pose)))
    return fit, per_pose


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
        cfg0 = cfg.with_sections(jig=cfg.jig.model_copy(update={"move_time_s": 0.0}))
        res, facts = run_boards(cfg, a.boards, a.seed)
        res0, _ = run_boards(cfg0, a.boards, a.seed)
        panel = run_panel(cfg, a.panel, a.seed) if a.panel > 0 else None
    n_fit, n_verify = needed_samples(cfg)
    poses = len(get_design(cfg.design)) + cfg.verify_poses
    n_need = (n_fit + cfg.verify_poses * n_verify) / poses
    theory = poses * n_need / facts["odr_hz"]
    print(f"station time per board (virtual time: device clock + host wall compute), mean of {a.boards} simulated "
          f"boards per column: {cfg.device.chip or 'mma8451'} at {facts['odr_hz']:g} Hz, design "
          f"{cfg.design} + {cfg.verify_poses} verification poses, model {cfg.model}, capture targets "
          f"offset u {cfg.capture.target_offset_u_mg} mg, gain u {cfg.capture.target_gain_u}, per-pose SEM "
          f"{cfg.capture.target_sem_mg} mg")
    print(f"fitted offset standard error, largest axis: mean {np.mean(facts['stderr_offset_mg']):.4f} mg, "
          f"max {np.max(facts['stderr_offset_mg']):.4f} mg")
    print(f"verdicts: {', '.join(sorted(set(facts['verdicts'])))}; samples averaged per pose: mean "
          f"{np.mean(facts['samples_per_pose']):.0f} (the noise needs {n_need:.0f} a pose for the targets)")
    rows = [[LABELS[k], f"{res[k]:.2f}", f"{res[k] / res['total']:.0%}", f"{res0[k]:.2f}",
             f"{res0[k] / res0['total']:.0%}"] for k in COMPONENTS]
    floor, floor0 = res["floor_fit"] + res["floor_verify"], res0["floor_fit"] + res0["floor_verify"]
    rows.append(["total board time", f"{res['total']:.2f}", "100%", f"{res0['total']:.2f}", "100%"])
    rows.append(["ratio: total / sampling floor", f"{res['total'] / floor:.2f}", "",
                 f"{res0['total'] / floor0:.2f}", ""])
    rows.append(["ratio: total / noise-limited floor", f"{res['total'] / theory:.2f}", "",
                 f"{res0['total'] / theory:.2f}", ""])
    print(table(["seconds per board", f"moves {cfg.jig.move_time_s:g} s", "share", "moves 0 s", "share"], rows))
    print(f"noise-limited floor: {poses} poses x {n_need:.0f} samples / {facts['odr_hz']:g} Hz = {theory:.2f} s")
    if panel is not None:
        t, verdicts = panel
        share = res["total"] / a.panel
        print(f"panel of {a.panel} boards on one jig (verdicts: {', '.join(sorted(set(verdicts)))}): "
              f"{t['panel_time_s']:.2f} s (device {t['device_time_s']:.2f} s + host {t['host_compute_s']:.2f} s)")
        print(table(["seconds per board", "value"], [
            ["single board (mean above)", f"{res['total']:.2f}"],
            [f"single board / {a.panel}", f"{share:.2f}"],
            [f"panel of {a.panel}, per board", f"{t['per_board_s']:.2f}"],
            [f"ratio: panel per board / (single / {a.panel}), goal <= 1.2", f"{t['per_board_s'] / share:.2f}"]]))
    return 0


if __name__ == "__main__":
    sys.exit(main())

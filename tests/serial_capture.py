"""Raw logs written as a test engineer saves them from a serial monitor (an FXOS8700 sketch's
style): a banner and a sensor description, a header, then ``>>> Place accelerometer ...`` prompt
lines between the data, values in m/s^2 printed with 6 decimals.  The samples come from the
project's forward simulator (an MMA8451, the FXOS8700's accelerometer twin: 14 bits, 4096 LSB/g
at +-2 g, 0.244 mg per LSB, 99 ug/sqrt(Hz)), 18 poses (optimal-18) at 100 Hz."""
from __future__ import annotations

import numpy as np

from accelcal_station.drivers.simulated import SimulatedBoard
from accelcal_station.fixtures.simulated_run import run_design

MPS2_PER_LSB = 9.80665 / 4096
BANNER = ["Adafruit FXOS8700 accelerometer capture", "------------------------------------",
          "Sensor:       FXOS8700", "Driver Ver:   1", "Unique ID:    0x8700A", "Max Value:    78.4532 m/s^2",
          "Min Value:    -78.4532 m/s^2", "Resolution:   0.0024 m/s^2", "------------------------------------",
          "", "Sampling every 10 ms; accelerations in m/s^2", "Press any key to start", ""]


def capture(seed: int = 1, repeat: int = 1) -> tuple[list[str], object]:
    """The capture's lines (the header on line 13, a prompt on line 14) and the simulated run;
    ``repeat`` > 1 logs each conversion that many times in a row (3 or 4, a host polling faster
    than the chip updates), with the host's own time column."""
    board = SimulatedBoard.from_config({"chip": "mma8451", "simulator": {"effects": {
        "offset": {"offset_mg": [22.0, -31.0, 45.0]}, "gain": {"gain": [1.01, 0.995, 1.02]},
        "noise": {"density_ug_per_rthz": [99.0] * 3}, "quantization": {"lsb_counts": 1}}}}, seed=seed)
    run = run_design(board, "optimal-18", samples=300, raw=True, move_s=1.5)
    lines = [*BANNER[:12], "time_ms,ax,ay,az"]
    rng = np.random.default_rng(seed)
    t_ms, pose = 0.0, 0
    step_ms = 10.0 / repeat  # the host's polling period
    for c, _t, _ in run.chunks:
        counts = np.asarray(c)
        if len(counts) == MOVE_SAMPLES:  # a move (1.5 s at 100 Hz): the prompt comes first
            pose += 1
            lines.append(f">>> Place accelerometer in pose {pose} of 18, then hold it still <<<")
        times = rng.integers(repeat - 1, repeat + 2, len(counts)) if repeat > 1 else np.ones(len(counts), int)
        for row, n in zip(counts, times, strict=True):
            x, y, z = (float(v) * MPS2_PER_LSB for v in row)
            for _ in range(int(n)):
                lines.append(f"{t_ms:.0f},{x:.6f},{y:.6f},{z:.6f}")
                t_ms += step_ms
    lines.append(">>> Done: 18 poses captured. Copy this log into a file <<<")
    return lines, run


MOVE_SAMPLES = 150


def write(path, seed: int = 1, repeat: int = 1):
    lines, run = capture(seed, repeat)
    path.write_text("\n".join(lines) + "\n")
    return path, run

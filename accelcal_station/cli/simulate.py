"""`accelcal simulate`: run a pose design on a simulated board and write what it measured.

Writes a pose table (the format `accelcal fit` reads, with ``counts_per_g`` in its
metadata) or, with ``--raw``, a raw sample log ``t,x,y,z`` in counts with the
jig's motion between the static poses.  ``--truth-out`` writes the simulator's
ground truth as a calibration JSON (``W``, ``V``, ``Gamma`` at the top level, as
`accelcal fit --json` has them; with several ``--temps`` a temperature table).
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import click
import numpy as np

from ..atomic import atomic_write_text
from ..calibration import Calibration, TemperatureTable
from ..config.sections import device_section
from ..data.posetable import write_pose_table
from ..drivers.simulated import SimulatedBoard
from ..errors import ConfigError, DataError
from ..fixtures.designs import get_design
from ..fixtures.simulated_jig import SimulatedJig
from ..session import PoseRecord, Session


def parse_temps(text: str | None) -> list[float] | None:
    if text is None:
        return None
    out = []
    for part in text.split(","):
        try:
            v = float(part)
        except ValueError:
            v = float("nan")
        if not np.isfinite(v) or not -60.0 <= v <= 150.0:
            raise DataError(f"--temps {text!r}: {part.strip()!r}; allowed: comma-separated temperatures "
                            "in C between -60 and 150, e.g. 0,25,50")
        out.append(v)
    if len(set(out)) != len(out):
        raise DataError(f"--temps {text!r}: a temperature repeats; each must be distinct")
    return out


def load_board(config: str | None, seed: int | None) -> SimulatedBoard:
    """The simulated board of a station config's ``device:`` section (driver: simulated)."""
    if config is None:
        return SimulatedBoard.from_config(None, seed=seed)
    section = device_section(config)
    if section.get("driver") != "simulated":
        raise ConfigError(f"{config}: device.driver is {section.get('driver')!r}; "
                          "accelcal simulate needs driver: simulated")
    section.pop("driver")
    return SimulatedBoard.from_config(section, seed=seed, path=f"{config}: device")


def truth_calibration(board: SimulatedBoard, temps: list[float], meta: dict) -> Calibration:
    """The board's truth at one die temperature, or a table of it at several (exact at each)."""
    cals = [board.truth(t) for t in temps]
    table = None
    if len(temps) > 1:
        table = TemperatureTable(temps, [c.W for c in cals], [c.V for c in cals], [c.Gamma for c in cals])
        cals = [cals[int(np.argmin(temps))]]
    c = cals[0]
    return Calibration("15", c.W, c.V, c.Gamma, "counts", c.input_per_g, table, {**c.metadata, **meta})


@click.command("simulate")
@click.option("--config", "config", type=click.Path(dir_okay=False), default=None,
              help="Station YAML whose device: section has driver: simulated (e.g. configs/sim.yaml). "
                   "Default: an ideal MMA8451 (datasheet noise, quantization and saturation only).")
@click.option("--poses", "design", required=True, help="Pose design: six-face, an4399-8, nine-position, optimal-N, ...")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Pose table (or raw log) to write.")
@click.option("--raw", is_flag=True, help="Write a raw sample log t,x,y,z (counts) with motion between poses.")
@click.option("--seed", type=click.IntRange(0, None), default=None,
              help="Random seed (default: the config's, else fresh; the seed used is printed and kept in the output).")
@click.option("--temps", default=None, help="Comma-separated temperatures in C to run the design at (e.g. 0,25,50).")
@click.option("--samples", type=click.IntRange(2, 10**7), default=1000, show_default=True,
              help="Samples averaged (or logged) per pose.")
@click.option("--move-s", "move_s", type=click.FloatRange(0.0, 3600.0), default=2.0, show_default=True,
              help="Seconds the jig takes to move between poses (virtual time).")
@click.option("--truth-out", type=click.Path(dir_okay=False), default=None,
              help="Write the simulator's ground-truth calibration (W, V, Gamma) as JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
def command(config, design, out, raw, seed, temps, samples, move_s, truth_out, as_json) -> None:
    """Simulate a calibration run and write its pose table (or raw log) and ground truth."""
    poses = get_design(design)
    temp_list = parse_temps(temps)
    for path in (out, truth_out):  # refuse before writing anything, so no file is left alone
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise DataError(f"{path}: cannot write (no such directory {Path(path).parent})")
    board = load_board(config, seed)
    temp_list = temp_list or [board.ambient_c]
    jig = SimulatedJig(board, move_time_s=move_s, record_motion=raw)
    records, chunks, die_temps = [], [], []
    for temp in temp_list:
        board.set_temperature(temp)
        die_temps.append(board.temperature_c)
        for pose in poses:
            jig.present(pose)
            if raw and jig.motion:
                chunks.append((*jig.motion.pop(), temp))
            counts, t = board.read(samples)
            chunks.append((counts, t, temp))
            c = np.asarray(counts, dtype=float)
            name = pose.name if len(temp_list) == 1 else f"{pose.name}@{temp:g}C"
            records.append(PoseRecord(name, c.mean(axis=0), c.std(axis=0, ddof=1), samples, pose.reference_g,
                                      pose.pitch_deg, pose.roll_deg, board.temperature_c,
                                      t_start=float(t[0]), t_end=float(t[-1])))
    meta = {"source": "accelcal simulate", "design": design, "seed": board.seed, "serial": board.serial,
            "chip": board.chip.name, "range_g": board.range_g, "odr_hz": board.odr_hz,
            "effects": " ".join(board.model.enabled) or "none"}
    if raw:
        buf = io.StringIO()
        head = {"units": "counts", "counts_per_g": f"{board.counts_per_g:g}", "device": board.chip.name, **meta}
        for k, v in head.items():
            buf.write(f"# {k}: {v}\n")
        multi = len(temp_list) > 1
        buf.write("t,x,y,z" + (",temp_c\n" if multi else "\n"))
        x_all = np.concatenate([np.asarray(c) for c, _, _ in chunks])
        cols = [np.concatenate([t for _, t, _ in chunks]), x_all]
        if multi:
            cols.append(np.concatenate([np.full(len(t), temp) for _, t, temp in chunks]))
        fmt = "%d" if np.issubdtype(x_all.dtype, np.integer) else "%.6f"
        np.savetxt(buf, np.column_stack(cols), fmt=["%.6f", fmt, fmt, fmt] + (["%g"] if multi else []),
                   delimiter=",")
        atomic_write_text(out, buf.getvalue())
    else:
        session = Session(records, "counts", board.counts_per_g, None, board.chip.name)
        write_pose_table(session, out, meta)
    if truth_out is not None:
        cal = truth_calibration(board, die_temps, {"seed": board.seed, "design": design})
        atomic_write_text(truth_out, json.dumps(cal.to_dict(), indent=2) + "\n")
    summary = {"out": out, "raw": raw, "poses": len(records), "samples_per_pose": samples,
               "counts_per_g": board.counts_per_g, "seed": board.seed, "temps_c": temp_list,
               "effects": list(board.model.enabled), "simulated_s": board.clock.now(), "truth_out": truth_out}
    if as_json:
        click.echo(json.dumps(summary))
    else:
        what = "raw log" if raw else "pose table"
        click.echo(f"wrote {what} {out}: {len(records)} poses x {samples} samples of a simulated {board.chip.name} "
                   f"({board.counts_per_g:g} counts/g, seed {board.seed}, {board.clock.now():.1f} s simulated)"
                   + (f"; truth {truth_out}" if truth_out else ""))

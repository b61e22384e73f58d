"""`accelcal simulate`: run a pose design on a simulated board and write what it measured.

Writes a pose table (the format `accelcal fit` reads, with ``counts_per_g`` in its
metadata) or, with ``--raw``, a raw sample log ``t,x,y,z`` in counts with the
jig's motion between the static poses.  ``--truth-out`` writes the simulator's
ground truth as a calibration JSON (``W``, ``V``, ``Gamma`` at the top level, as
`accelcal fit --json` has them; with several ``--temps`` a temperature table).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, TypedDict

import click
import numpy as np

from ..api import MAX_SAMPLES_PER_POSE, MAX_TOTAL_SAMPLES, simulate
from ..atomic import atomic_write
from ..config.sections import default_config_path
from ..data.posetable import write_pose_table
from ..drivers.simulated import SimulatedBoard
from ..errors import DataError
from ..fileguard.kind import DESCRIBED
from ..fileguard.numbers import decimal_float
from ..fixtures.designs import get_design
from ..fixtures.simulated_run import SimulatedRun, run_metadata
from ..lot.synthetic import LotSpec, write_population_lot
from ..twin.simlot import load_device
from ._common import MAX_SEED, Finite, Whole, force_option, output_kind
from ._outputs import refuse_output


def parse_temps(text: str | None) -> list[float] | None:
    if text is None:
        return None
    out = []
    for part in text.split(","):
        try:
            v = decimal_float(part)
        except ValueError:
            v = float("nan")
        if not np.isfinite(v) or not -60.0 <= v <= 150.0:
            raise DataError(f"--temps {text!r}: {part.strip()!r}; allowed: comma-separated temperatures "
                            "in C between -60 and 150, e.g. 0,25,50")
        out.append(v)
    if len(set(out)) != len(out):
        raise DataError(f"--temps {text!r}: a temperature repeats; each must be distinct")
    return out


class _RawLog:
    """The raw log, streamed: its provenance as ``# key: value`` lines, then t,x,y,z (and temp_c)
    in counts, a chunk at a time into the atomic writer's temporary file (memory stays bounded)."""

    def __init__(self, f: IO[str], design: str, multi: bool) -> None:
        self.f, self.design, self.multi = f, design, multi

    def header(self, board: SimulatedBoard) -> None:
        head = {"units": "counts", "counts_per_g": f"{board.counts_per_g:g}", "device": board.chip.name,
                **run_metadata(board, self.design)}
        self.f.write("".join(f"# {k}: {v}\n" for k, v in head.items()))
        self.f.write("t,x,y,z" + (",temp_c\n" if self.multi else "\n"))

    def chunk(self, counts: np.ndarray, t: np.ndarray, temp: float) -> None:
        whole = np.issubdtype(np.asarray(counts).dtype, np.integer)
        row = "%.6f," + (",".join(["%d" if whole else "%.6f"] * 3)) + (",%g" if self.multi else "") + "\n"
        cols = [t, *np.asarray(counts).T] + ([np.full(len(t), temp)] if self.multi else [])
        self.f.write((row * len(t)) % tuple(np.column_stack(cols).ravel().tolist()))


class SimulateSummary(TypedDict):
    """simulate --json: what was written, from which simulated board (its seed) and how long it took."""

    out: str
    raw: bool
    poses: int
    samples_per_pose: int
    counts_per_g: float
    seed: int
    temps_c: list[float]
    effects: list[str]
    simulated_s: float
    truth_out: str | None


def _summary(run: SimulatedRun, out: str, raw: bool, truth_out: str | None) -> tuple[SimulateSummary, str]:
    b = run.board
    summary: SimulateSummary = {
        "out": out, "raw": raw, "poses": len(run.session), "samples_per_pose": run.samples_per_pose,
        "counts_per_g": b.counts_per_g, "seed": b.seed, "temps_c": run.temps_c,
        "effects": list(b.model.enabled), "simulated_s": b.clock.now(), "truth_out": truth_out}
    what = "raw log" if raw else "pose table"
    line = (f"wrote {what} {out}: {len(run.session)} poses x {run.samples_per_pose} samples of a simulated "
            f"{b.chip.name} ({b.counts_per_g:g} counts/g, seed {b.seed}, {b.clock.now():.1f} s simulated)"
            + (f"; truth {truth_out}" if truth_out else ""))
    return summary, line


def _check_suffixes(out: str, truth_out: str | None) -> None:
    """--out is CSV text (a pose table, raw log or lot file) and --truth-out JSON: a name that says
    another format (x.parquet, x.json) is refused, never written in the wrong one."""
    others = ".parquet, .json, .jsonl, .yaml, .html, .png"
    for flag, path, kind, allowed in (("--out", out, "csv", f".csv or another text name (not {others})"),
                                      ("--truth-out", truth_out, "json", ".json or a name without one")):
        if path is not None and output_kind(path, kind) != kind:
            raise DataError(f"{flag} {path}: simulate writes {DESCRIBED[kind]} there, not "
                            f"{DESCRIBED[output_kind(path)]}; allowed: {allowed}")


@click.command("simulate")
@click.option("--config", "config", type=click.Path(dir_okay=False), default=None,
              help="Station YAML whose device: section has driver: simulated (e.g. configs/sim.yaml). "
                   "Default: an ideal MMA8451 (datasheet noise, quantization and saturation only).")
@click.option("--poses", "--design", "design", required=True,
              help="Pose design: six-face, an4399-8, nine-position, optimal-N, ...")
@click.option("--lot", "lot", type=Whole(1, 10**8), default=None,
              help="Write a lot file of this many boards drawn from the config's population (accelcal batch reads it).")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False), help="Pose table (or raw log) to write.")
@click.option("--raw", is_flag=True, help="Write a raw sample log t,x,y,z (counts) with motion between poses.")
@click.option("--seed", type=Whole(0, MAX_SEED), default=None,
              help="Random seed (default: the config's, else fresh; the seed used is printed and kept in the output).")
@click.option("--temps", default=None, help="Comma-separated temperatures in C to run the design at (e.g. 0,25,50).")
@click.option("--samples", type=Whole(2, MAX_SAMPLES_PER_POSE), default=1000, show_default=True,
              help=f"Samples averaged (or logged) per pose; at most {MAX_TOTAL_SAMPLES} in all (poses x "
                   "temperatures x samples).")
@click.option("--move-s", "move_s", type=Finite(0.0, 3600.0), default=2.0, show_default=True,
              help="Seconds the jig takes to move between poses (virtual time).")
@click.option("--truth-out", type=click.Path(dir_okay=False), default=None,
              help="Write the simulator's ground-truth calibration (W, V, Gamma) as JSON.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON summary.")
@force_option
def command(**opts: Any) -> None:
    """Simulate a calibration run and write its pose table (or raw log) and ground truth."""
    _simulate(SimulateCommand.from_click(opts))


@dataclass(frozen=True)
class SimulateCommand:
    """`accelcal simulate`'s options: the board (config, seed), the design and how it is run (temperatures,
    samples, move time), what is written (a pose table, a raw log, a lot file; the truth)."""

    config: str | None
    design: str
    lot: int | None
    out: str
    raw: bool
    seed: int | None
    temps: str | None
    samples: int
    move_s: float
    truth_out: str | None
    as_json: bool
    force: bool

    @classmethod
    def from_click(cls, o: Mapping[str, Any]) -> SimulateCommand:
        return cls(config=o["config"], design=o["design"], lot=o["lot"], out=o["out"], raw=o["raw"], seed=o["seed"],
                   temps=o["temps"], samples=o["samples"], move_s=o["move_s"], truth_out=o["truth_out"],
                   as_json=o["as_json"], force=o["force"])


def _simulate(o: SimulateCommand) -> None:
    config, design, lot, out, seed, samples = o.config, o.design, o.lot, o.out, o.seed, o.samples
    truth_out, as_json, move_s = o.truth_out, o.as_json, o.move_s
    refuse_output([("--out", out, "csv"), ("--truth-out", truth_out, "json")], [("--config", config)], o.force,
                  config=config)
    _check_suffixes(out, truth_out)
    get_design(design)
    if lot is not None:
        _write_lot(config, design, lot, out, seed, samples, as_json)
        return
    temp_list = parse_temps(o.temps)
    for path in (out, truth_out):  # refuse before writing anything, so no file is left alone
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise DataError(f"{path}: cannot write (no such directory {Path(path).parent})")
    if o.raw:
        with atomic_write(out) as f:
            log = _RawLog(f, design, temp_list is not None and len(temp_list) > 1)
            run = simulate(design, config=config, seed=seed, samples=samples, temps_c=temp_list, move_s=move_s,
                           raw=True, sink=log.chunk, on_board=log.header)
    else:
        run = simulate(design, config=config, seed=seed, samples=samples, temps_c=temp_list, move_s=move_s)
        write_pose_table(run.session, out, run.metadata)
    if truth_out is not None:
        atomic_write(truth_out, json.dumps(run.truth().to_dict(), indent=2) + "\n")
    summary, line = _summary(run, out, o.raw, truth_out)
    click.echo(json.dumps(summary) if as_json else line)


def _write_lot(config: str | None, design: str, boards: int, out: str, seed: int | None, samples: int,
               as_json: bool) -> None:
    """--lot: a lot file of boards drawn from the config's population (sim/population.py)."""
    if not Path(out).resolve().parent.is_dir():
        raise DataError(f"{out}: cannot write (no such directory {Path(out).parent})")
    cfg = config or str(default_config_path())
    model, pop, range_g, _ = load_device(cfg)
    seed = 0 if seed is None else seed
    write_population_lot(out, LotSpec(boards, design, seed=seed, samples=samples, range_g=range_g), model, pop)
    summary = {"out": out, "boards": boards, "design": design, "seed": seed, "samples_per_pose": samples,
               "population": pop is not None, "config": cfg}
    click.echo(json.dumps(summary) if as_json else
               f"wrote lot file {out}: {boards} boards x {design} ({samples} samples per pose, seed {seed}, "
               f"{'drawn from the population' if pop is not None else 'one fixed board'} of {cfg})")

"""Pose designs and boards for the diagnosis's order tests (tests/test_diagnose_competition.py,
test_diagnose_verdicts.py): N orientations spread evenly over the sphere (a Fibonacci lattice, whose z
values are evenly spaced, so a design taken in order of z has u_z linear in row number, as the issue's
blind generator's had), taken in order of z, shuffled, revisited, or split across files; pose tables
made by the project's forward simulator (configs/sim.yaml plus the catalog effect named)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from accelcal_station.conventions import reference_to_angles
from accelcal_station.data.posetable import write_pose_table
from accelcal_station.fixtures.base import PoseSpec
from accelcal_station.fixtures.simulated_run import run_poses, simulated_board

REPO = Path(__file__).resolve().parents[1]


def config(d: Path, effects: dict, name: str) -> str:
    """configs/sim.yaml with ``effects`` added under simulator.effects, written to d/name."""
    cfg = yaml.safe_load((REPO / "configs" / "sim.yaml").read_text())
    cfg["device"]["simulator"]["effects"].update(effects)
    (d / name).write_text(yaml.safe_dump(cfg))
    return str(d / name)


def sphere(n: int, order: str, seed: int = 0) -> list[PoseSpec]:
    """n poses over the sphere: ``z`` (descending z), ``shuffled``, or ``revisited`` (in order of z, then
    every third pose again at the end of the run)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    a = np.pi * (1.0 + np.sqrt(5.0)) * i
    u = np.stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z], axis=1)
    pitch, roll = reference_to_angles(u)
    poses = [PoseSpec(f"p{k + 1}", float(t), float(r)) for k, (t, r) in enumerate(zip(pitch, roll, strict=True))]
    by_z = sorted(poses, key=lambda p: -p.reference_g[2])
    if order == "z":
        return by_z
    if order == "shuffled":
        return [poses[k] for k in np.random.default_rng(seed).permutation(n)]
    if order == "revisited":
        return by_z + [PoseSpec(p.name + "r", p.pitch_deg, p.roll_deg) for p in by_z[::3]]
    raise ValueError(order)


def tables(cfg: str, poses: list[PoseSpec], seed: int, path: Path, files: int = 1) -> list[Path]:
    """The poses run on board ``seed`` (200 samples a pose), as ``files`` pose tables of consecutive poses."""
    out = []
    for k, part in enumerate(np.array_split(np.arange(len(poses)), files)):
        run = run_poses(simulated_board(cfg, seed), [poses[j] for j in part], "sphere", samples=200)
        out.append(path.with_name(f"{path.stem}-{k}.csv"))
        write_pose_table(run.session, out[-1])
    return out

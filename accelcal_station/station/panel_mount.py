"""How each board of a panel sits: ``device.mount`` for every board, a board's own
``device.boards[i].mount`` over it (panel_config.panel_sections merges the two).

Each board is expected to read ``P r`` at a pose (P its mounting, chip = P @ board; r the
pose's reference in board axes): its right-face check, its pose table and its fit use ``P r``,
so each board is fitted against references turned by its own mounting.

A board that reads a wrong pose one of the 24 mountings explains is read on through the next
poses (its neighbours are in place, and placing the panel again would not turn one board) until
its readings single one mounting out, or the design ends.  It then fails naming the first
wrong pose, the mounting and the line that sets it: ``device.mount`` when every board of the
panel looks turned alike and none sets its own, else that board's ``device.boards[i].mount``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import AccelcalError
from .capture import MountMismatch, Seen, WrongPose, named_mounting, with_mounting

# a board's failure at a pose: (the pose's name, the error)
Failure = tuple[str, AccelcalError]


@dataclass
class BoardMount:
    """One board's mounting, where it is set, and what the board has read so far."""

    matrix: np.ndarray  # chip = matrix @ board (the board's BoardSteps.mount)
    path: str  # the board's key path, e.g. device.boards[2]
    own: bool = False  # its own mapping sets mount: device.mount does not reach it
    seen: Seen = field(default_factory=list)  # (pose reference in board axes, mean reading) so far
    first_wrong: tuple[str, WrongPose] | None = None  # the first wrong pose read on past

    @property
    def own_key(self) -> str:
        return f"{self.path}.mount"

    @property
    def shared_key(self) -> str:
        return self.path.split(".boards[")[0] + ".mount"


def explained(mounts: dict[int, BoardMount], reference_g: np.ndarray, errors: dict[int, AccelcalError],
              tolerance_deg: float) -> bool:
    """Every board's wrong pose is one its readings so far single another mounting out for: the boards
    are turned, not the panel misplaced (placing it again would not help)."""
    return bool(errors) and all(
        isinstance(e, WrongPose)
        and isinstance(with_mounting(mounts[i].seen, reference_g, e, mounts[i].matrix, tolerance_deg), MountMismatch)
        for i, e in errors.items())


def sort_wrong_poses(mounts: dict[int, BoardMount], everyone: list[BoardMount], pose_name: str,
                     reference_g: np.ndarray, readings: dict[int, np.ndarray], errors: dict[int, AccelcalError],
                     read_on: bool, tolerance_deg: float) -> dict[int, Failure]:
    """The boards that fail at this pose and why; a wrong pose a mounting may explain is read on past
    (``read_on``: the design's poses) unless the readings single the mounting out already.

    ``readings``: the mean reading of every board captured at the pose; ``errors``: the others'.
    """
    for i, m in readings.items():
        mounts[i].seen.append((reference_g, m))
    out: dict[int, Failure] = {}
    to_name: dict[int, tuple[str, WrongPose]] = {}
    for i, e in errors.items():
        if not isinstance(e, WrongPose):
            out[i] = (pose_name, e)
            continue
        bm = mounts[i]
        named = with_mounting(bm.seen, reference_g, e, bm.matrix, tolerance_deg)
        bm.seen.append((reference_g, e.measured))
        if named.hint is None:
            out[i] = bm.first_wrong or (pose_name, e)
        elif read_on and not isinstance(named, MountMismatch):
            bm.first_wrong = bm.first_wrong or (pose_name, e)
        else:
            to_name[i] = bm.first_wrong or (pose_name, e)
    out.update(name_mountings(to_name, mounts, everyone, tolerance_deg))
    return out


def end_of_design(mounts: dict[int, BoardMount], everyone: list[BoardMount], tolerance_deg: float
                  ) -> dict[int, Failure]:
    """The boards still read on past a wrong pose when the design ends: each fails with the mounting
    that fits all it read (the smallest turn when several do), or its first wrong pose as it was."""
    todo = {i: bm.first_wrong for i, bm in mounts.items() if bm.first_wrong is not None}
    return name_mountings({i: w for i, w in todo.items() if w is not None}, mounts, everyone, tolerance_deg)


def name_mountings(to_name: dict[int, tuple[str, WrongPose]], mounts: dict[int, BoardMount],
                   everyone: list[BoardMount], tolerance_deg: float) -> dict[int, Failure]:
    """Each board's first wrong pose with the mounting that fits everything it read, and the line that
    sets it: device.mount when every board of the panel is named here with the same mounting and none
    sets its own (following it turns no board that reads right), else the board's own key."""
    fitted = {i: named_mounting(mounts[i].seen, e, mounts[i].matrix, tolerance_deg) for i, (_, e) in to_name.items()}
    found = [f.mount for f in fitted.values() if f.mount is not None]
    shared = (len(found) == len(everyone) > 0 and all(np.array_equal(p, found[0]) for p in found)
              and not any(mounts[i].own for i in to_name))
    out: dict[int, Failure] = {}
    for i, (name, e) in to_name.items():
        bm = mounts[i]
        key = bm.shared_key if shared else bm.own_key
        out[i] = (name, named_mounting(bm.seen, e, bm.matrix, tolerance_deg, key))
        bm.first_wrong = None
    return out

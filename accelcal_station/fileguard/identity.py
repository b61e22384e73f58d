"""An output is never the same file as an input or the results store.

Compared by identity, not by name: two paths name the same file when ``os.stat`` gives
the same device and inode (an alias, ``./``, ``..``, a symlink or a hard link), or, when
the output does not exist yet, when both resolve to the same path.  Every command that
writes a file calls :func:`refuse_overwrite` before doing any work, so a refusal leaves
every file as it was.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable
from pathlib import Path

from ..errors import DataError
from .kind import refuse_kind

Named = tuple[str, str | Path | None]  # (what it is: "--out", "input", "the store"; its path or None)
# an output may also say what it writes: (label, path, kind), kind as in kind.COMPATIBLE
Output = Named | tuple[str, str | Path | None, str | None]


def _keys(p: str | Path) -> list[tuple[object, ...]]:
    """What identifies the file ``p`` names: its device and inode when it exists, and its resolved path."""
    keys: list[tuple[object, ...]] = []
    with contextlib.suppress(OSError, ValueError):  # absent (or a NUL in the name): no inode
        st = os.stat(p)
        keys.append(("inode", st.st_dev, st.st_ino))
    with contextlib.suppress(OSError, ValueError):
        keys.append(("path", os.path.realpath(p)))
    return keys


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` are one file: same device and inode, or the same resolved path."""
    return bool(set(_keys(a)) & set(_keys(b)))


def refuse_overwrite(outputs: Iterable[Output], inputs: Iterable[Named], force: bool = False) -> None:
    """One DataError (exit 2) when an output is an input, the store or another output, or (unless
    ``force``) an existing SQLite database or a file of another kind than it writes (kind.refuse_kind).

    ``outputs``: (label, path) or (label, path, kind); ``inputs``: (label, path); a None path is
    skipped (option not given).  Each file is looked at once: a batch of thousands of boards is
    checked in linear time.
    """
    seen: dict[tuple[object, ...], tuple[str, str | Path]] = {}
    for label, p in inputs:
        if p is not None:
            for k in _keys(p):
                seen.setdefault(k, (label, p))
    for label, out, *kind in outputs:
        if out is None or str(out) == "-":
            continue
        keys = _keys(out)
        hit = next((seen[k] for k in keys if k in seen), None)
        if hit is not None:  # never allowed, --force or not: the command reads it
            raise DataError(f"{label} {out}: the same file as {hit[0]} {hit[1]}; refusing to overwrite "
                            "it (nothing written); choose another output file")
        refuse_kind(label, out, kind[0] if kind else None, force)
        for k in keys:
            seen.setdefault(k, (label, out))

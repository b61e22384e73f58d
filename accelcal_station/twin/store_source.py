"""A results store as a twin's source: its complete runs with poses, in store order, as lot chunks
(the boards of a line's stations: the same fitting and judging as a lot file's)."""
from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..acceptance.rules import Limits
from ..conventions import an4399_reference
from ..data.lotfile import LotChunk
from ..errors import DataError
from ..session import Session
from ..store.location import store_target
from ..store.reader import StoreReader
from .stream import LotStats, collect, richest_model

log = logging.getLogger(__name__)


def _chunk(sessions: list[Session]) -> LotChunk:
    """Sessions (same pose count) as one lot chunk: readings in their units, references in g."""
    P = len(sessions[0])
    rows = [p for s in sessions for p in s.poses]
    mean = np.array([p.mean for p in rows], dtype=float).reshape(-1, 3)
    nan3 = np.full(3, np.nan)
    ref = np.array([p.reference_g if p.reference_g is not None else
                    an4399_reference(p.pitch_deg, p.roll_deg) if p.pitch_deg is not None and p.roll_deg is not None
                    else nan3 for p in rows], dtype=float).reshape(-1, 3)
    std = np.array([nan3 if p.std is None else p.std for p in rows], dtype=float).reshape(-1, 3)
    n = np.array([np.nan if p.n is None else p.n for p in rows], dtype=float)
    cols = {"x": mean[:, 0], "y": mean[:, 1], "z": mean[:, 2], "ref_x": ref[:, 0], "ref_y": ref[:, 1],
            "ref_z": ref[:, 2], "std_x": std[:, 0], "std_y": std[:, 1], "std_z": std[:, 2], "n": n}
    D = len(sessions)
    return LotChunk([str(s.device or s.metadata.get("run_id")) for s in sessions], np.arange(D + 1) * P, cols,
                    np.array([p.name for p in rows]), [None] * D, np.arange(D) * P + 1)


def store_stats(db: str, limits: Limits | None, reservoir: int = 50_000, chunk_boards: int = 4096,
                skips: list[tuple[str, str]] | None = None, **filters: Any) -> tuple[LotStats, float | None]:
    """One pass over the store's matching runs; returns the stats and the runs' input units per g.
    A damaged run is appended to ``skips`` ("run ID", "damaged_row: ...") and counted in ``skipped``."""
    damaged: list[tuple[str, str]] = []
    with StoreReader(store_target(Path(db) if "://" not in db else db)) as st:  # read-only: never stamped
        if st.notice:
            log.warning(st.notice)
        sessions = st.sessions_for_batch(damaged, **{k: v for k, v in filters.items() if v is not None})
    if skips is not None:
        skips += damaged
    sessions = [s for s in sessions if s.units == "counts" and s.counts_per_g]
    if not sessions:
        raise DataError(f"{db}: no complete runs with poses in counts match (try without --since/--station)")
    P = len(sessions[0])
    same = [s for s in sessions if len(s) == P]
    per_g = float(same[0].counts_per_g or 0.0)
    same = [s for s in same if s.counts_per_g == per_g]

    def chunks() -> Iterator[LotChunk]:
        for a in range(0, len(same), chunk_boards):
            yield _chunk(same[a:a + chunk_boards])

    it = chunks()
    first = next(it)
    model = richest_model(first)

    def all_chunks() -> Iterator[LotChunk]:
        yield first
        yield from it

    stats = collect(all_chunks(), model, per_g, "counts", limits, reservoir)
    stats.skipped += len(sessions) - len(same) + len(damaged)  # another pose count or scale; damaged runs
    return stats, per_g

"""One pass over a lot in chunks: per-board fits and measures, kept in bounded memory.

Every chunk is fitted with the stacked fitters (lot.streaming.fit_chunk) and judged
(lot.streaming.judge_chunk).  What is kept, whatever the lot size:

- a uniform reservoir sample (Vitter's algorithm R) of ``reservoir`` boards' rows
  (board index, effect quantities, fitted parameters, residual and leave-one-out RMS,
  verdict and reason codes);
- per block of ``block`` consecutive boards, the count, sum and sum of squares of each
  effect quantity (the sufficient statistics of a change in the mean along the lot);
- counts of verdicts and of reason codes over the whole lot, the median noise and samples.

Effect quantities from a fitted AN4399 calibration (W, V, Gamma): the simulator's
``f = K^-1 (G - o) - c G^3`` (sensor_model stage 3) gives ``K = W^-1``, ``o = -K V``,
``c = -Gamma``; with no package rotation ``K = diag(gain) (I + C)``, so
``gain_i = K_ii`` and ``C_ij = K_ij / K_ii``.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ..acceptance.rules import Limits
from ..data.lotfile import LotChunk, board_arrays
from ..identifiability import assess
from ..lot.streaming import fit_chunk, judge_chunk

OFFDIAG = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
FITTED = tuple(f"W{i}{j}" for i in range(3) for j in range(3)) + ("V0", "V1", "V2", "Gamma0", "Gamma1", "Gamma2")
MEASURES = FITTED + ("residual_rms_mg", "crossval_rms_mg")


def effect_names(model: str) -> list[str]:
    """The population quantities a model's fits determine (sim/population.py names)."""
    names = [f"offset.offset_mg[{i}]" for i in range(3)] + [f"gain.gain[{i}]" for i in range(3)]
    names += [f"cross_axis.coupling[{i}][{j}]" for i, j in OFFDIAG]
    if model == "15":
        names += [f"cubic.cubic_per_g2[{i}]" for i in range(3)]
    return names


def effect_quantities(W: np.ndarray, V: np.ndarray, Gamma: np.ndarray, model: str) -> np.ndarray:
    """(B, Q) effect quantities of fitted calibrations (module docstring); NaN where W is singular."""
    finite = np.all(np.isfinite(W.reshape(len(W), -1)), axis=1)  # a skipped board's NaN W: no det (no warning)
    det = np.zeros(len(W))
    det[finite] = np.linalg.det(W[finite])
    good = np.isfinite(det) & (np.abs(det) > 1e-6)
    K = np.linalg.inv(np.where(good[:, None, None], W, np.eye(3)))
    off_mg = -1e3 * np.einsum("bij,bj->bi", K, V)
    gain = np.diagonal(K, axis1=1, axis2=2)
    coup = np.stack([K[:, i, j] / K[:, i, i] for i, j in OFFDIAG], axis=1)
    cols = [off_mg, gain, coup] + ([-Gamma] if model == "15" else [])
    out = np.concatenate(cols, axis=1)
    out[~good] = np.nan
    return out


def richest_model(chunk: LotChunk) -> str:
    """The richest model (15, 12, 6; 9 without references) the first fittable board's poses determine."""
    x, ref, _, reasons = board_arrays(chunk, "15")
    for b, why in enumerate(reasons):
        if why is None and ref is not None:
            g = x[chunk.starts[b]:chunk.starts[b + 1]]
            g = g / np.median(np.linalg.norm(g, axis=1))
            for m in ("15", "12", "6"):
                if assess(g, m).determined:
                    return m
    return "9"


@dataclass
class LotStats:
    """What one pass keeps (module docstring)."""

    model: str
    quantities: list[str]
    reservoir: int = 50_000
    block: int = 32
    seed: int = 0
    boards: int = 0
    rows: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # reservoir rows
    codes: list[tuple[str, tuple[str, ...]]] = field(default_factory=list)  # reservoir verdicts, reasons
    block_sums: list[np.ndarray] = field(default_factory=list)  # per chunk (blocks, 3, Q)
    verdicts: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)
    noise: list[float] = field(default_factory=list)  # per-chunk median per-sample std, input units
    noise_axes: list[np.ndarray] = field(default_factory=list)  # per-chunk median stated std per axis
    samples: list[float] = field(default_factory=list)
    refs: np.ndarray | None = None  # the first board's pose references (P, 3)
    pose_angles: dict[str, np.ndarray] = field(default_factory=dict)
    skipped: int = 0
    _carry: np.ndarray | None = None  # a partial block's rows carried to the next chunk
    _buf: np.ndarray | None = None  # the reservoir's storage (R rows); ``rows`` is its filled part
    _key: dict[tuple[str, tuple[str, ...]], tuple[str, tuple[str, ...]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    @property
    def columns(self) -> list[str]:
        return ["board"] + self.quantities + list(MEASURES)

    def add(self, chunk: LotChunk, per_g: float | None, units: str, limits: Limits | None) -> None:
        res = fit_chunk(chunk, self.model, per_g, units)
        verdicts, reasons = judge_chunk(res, limits, self.model)
        B = len(chunk.serials)
        if self.refs is None:
            self._keep_design(chunk, per_g)
        idx = self.boards + np.arange(B)
        eq = effect_quantities(res["W"], res["V"], res["Gamma"], self.model)
        meas = np.concatenate([res["W"].reshape(B, 9), res["V"], res["Gamma"],
                               1e3 * res["residual_rms_g"][:, None], 1e3 * res["crossval_rms_g"][:, None]], axis=1)
        rows = np.concatenate([idx[:, None].astype(float), eq, meas], axis=1)
        # one tuple per distinct (verdict, reason codes): a lot has a few, the reservoir holds 50,000 boards
        keys = [self._key.setdefault(k, k) for k in
                ((v, tuple(sorted({r.code for r in rs}))) for v, rs in zip(verdicts, reasons, strict=True))]
        for v, rs in keys:
            self.verdicts[v or "UNJUDGED"] += 1
            self.reasons.update(rs)
        self.skipped += int((~res["ok"]).sum())
        self._blocks(rows[:, 1:1 + len(self.quantities)], res["ok"])
        self._sample(rows, keys)
        self.boards += B

    def _keep_design(self, chunk: LotChunk, per_g: float | None) -> None:
        x, ref, _, reasons = board_arrays(chunk, self.model)
        b = next((i for i, why in enumerate(reasons) if why is None), 0)  # the first board that can be fitted
        s = slice(chunk.starts[b], chunk.starts[b + 1])
        self.refs = None if ref is None else ref[s].copy()
        self.pose_angles = {k: chunk.cols[k][s].copy() for k in ("pitch_deg", "roll_deg") if k in chunk.cols}
        c = chunk.cols
        if {"std_x", "n"} <= c.keys():
            std = np.stack([c["std_x"], c["std_y"], c["std_z"]], axis=1)
            self.noise.append(float(np.nanmedian(std)))
            self.noise_axes.append(np.nanmedian(std, axis=0))
            self.samples.append(float(np.nanmedian(c["n"])))

    def _blocks(self, q: np.ndarray, ok: np.ndarray) -> None:
        """Add the chunk's boards to block sums; a partial block waits for the next chunk."""
        q = np.where(ok[:, None] & np.isfinite(q), q, np.nan)
        if self._carry is not None:
            q = np.concatenate([self._carry, q])
        nb = len(q) // self.block
        self._carry = q[nb * self.block:]
        self._add_blocks(q[:nb * self.block].reshape(nb, self.block, q.shape[1]))

    def _add_blocks(self, qb: np.ndarray) -> None:
        have = np.isfinite(qb)
        z = np.where(have, qb, 0.0)
        self.block_sums.append(np.stack([have.sum(axis=1), z.sum(axis=1), (z * z).sum(axis=1)], axis=1))

    def finish(self) -> None:
        if self._carry is not None and len(self._carry):
            self._add_blocks(self._carry[None])
        self._carry = None

    def _sample(self, rows: np.ndarray, keys: list[tuple[str, tuple[str, ...]]]) -> None:
        """Algorithm R: board t (1-based) replaces a random slot with probability R / t."""
        R = self.reservoir
        if self._buf is None:  # the whole reservoir at once: filled in place (pages touched as filled),
            self._buf = np.empty((R, rows.shape[1]))  # never regrown by concatenation (a copy per chunk)
            self.rows = self._buf[:0]
        filled = len(self.rows)
        free = max(0, min(R - filled, len(rows)))
        if free:
            self._buf[filled:filled + free] = rows[:free]
            self.rows = self._buf[:filled + free]
            self.codes.extend(keys[:free])
        t = self.boards + free + 1 + np.arange(len(rows) - free)
        j = (self.rng.random(len(t)) * t).astype(np.int64)
        for k in np.flatnonzero(j < R):  # in order: a later board may replace an earlier one's slot
            self.rows[j[k]] = rows[free + k]
            self.codes[j[k]] = keys[free + k]

    def block_stats(self) -> np.ndarray:
        """(blocks, 3, Q): count, sum, sum of squares per block of consecutive boards."""
        if not self.block_sums:
            return np.zeros((0, 3, len(self.quantities)))
        return np.concatenate(self.block_sums)

    def column(self, name: str) -> np.ndarray:
        return self.rows[:, self.columns.index(name)]


def collect(chunks: Iterator[LotChunk], model: str | None, per_g: float | None, units: str,
            limits: Limits | None, reservoir: int = 50_000, seed: int = 0) -> LotStats:
    """Stream ``chunks`` into a LotStats (model None: the richest the first board's poses determine)."""
    stats: LotStats | None = None
    for chunk in chunks:
        if stats is None:
            m = model or richest_model(chunk)
            stats = LotStats(m, effect_names(m), reservoir=reservoir, seed=seed)
        stats.add(chunk, per_g, units, limits)
    if stats is None:
        stats = LotStats(model or "12", effect_names(model or "12"), reservoir=reservoir, seed=seed)
    stats.finish()
    return stats

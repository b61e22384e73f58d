"""Fast stacked fitters for a chunk of boards: the same estimators as linear.py and
gravity_norm.py, written as elementwise numpy over the board axis.

Model 12 (AN4399 Eqn 46) is solved on the centred design: with xc = g - mean(g),
S = xc^T xc (3 x 3), W^T = S^-1 xc^T (ref - mean(ref)) and V = mean(ref) - W mean(g),
which is the normal-equation solution of ``[g 1] beta = ref`` (the intercept column
drops out by the Frisch-Waugh theorem).  S^-1 comes from the adjugate, so no
per-board LAPACK call is made; (X^T X)^-1 of the full design follows by the block
(Schur complement) formula, giving standard errors, and the hat matrix diagonal
h = 1/P + xc^T S^-1 xc gives closed-form leave-one-out residuals r / (1 - h).
The condition number sqrt(lambda_max / lambda_min) of X^T X uses the extreme roots of
its characteristic polynomial (coefficients from principal minors, all computed
through S so they carry no cancellation), found by Laguerre's method, which
converges monotonically from outside the roots of a polynomial with real roots.

The design [g 1] is each board's own readings, so it cannot be factored once per lot;
what boards share is the reference set (the fixture's poses): fit_stacked groups boards
by identical references, and within a group the centred references, their norms and the
cross products xc^T yc (one BLAS matmul over the group) are computed once.

Arrays are laid out (3, P, D), boards last, so sums over poses are additions of P
contiguous rows; the covariance is kept as the 10 distinct entries of (X^T X)^-1 per board.

Models 6 and 15 use linear.fit_linear_batch (already batched normal equations), model 9
stacked_norm.fit9 (batched Gauss-Newton, boards last).

fit_stacked fits blocks of boards (BLOCK) in one thread per CPU and copies each into the
lot's arrays as soon as it is done.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DataError, UnderdeterminedError
from . import boardwise as bw
from .heap import keep_block_memory
from .linear import COND_LIMIT, diagnose_underdetermined, fit_linear_batch, param_names, residual_variance
from .result import BatchFit, LazyCovariance
from .stacked_norm import fit9
from .threads import usable_cpus

CHECK_COND = 1e5  # above this, extreme eigenvalues are recomputed by LAPACK (rare)


def _laguerre_root(coef: tuple[np.ndarray, ...], x: np.ndarray, iters: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A root of the monic quartic x^4 - e1 x^3 + e2 x^2 - e3 x + e4 from x (vectorised).

    All roots real: started above (below) all roots, Laguerre's iteration goes
    monotonically to the largest (smallest).  Returns the root and the last step.
    """
    e1, e2, e3, e4 = coef
    step = np.zeros_like(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(iters):
            p = (((x - e1) * x + e2) * x - e3) * x + e4
            dp = ((4 * x - 3 * e1) * x + 2 * e2) * x - e3
            d2p = (12 * x - 6 * e1) * x + 2 * e2
            g1 = dp / p
            h = g1 * g1 - d2p / p
            sq = np.sqrt(np.maximum(3.0 * (4.0 * h - g1 * g1), 0.0))
            den = g1 + np.copysign(sq, g1)
            step = np.where((p == 0) | (den == 0), 0.0, 4.0 / den)
            x = x - step
    return x, step


def _smallest_root(coef: tuple[np.ndarray, ...], top: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The smallest root of the quartic once its largest ``top`` is known: deflate to a cubic,
    take its smallest root in trigonometric form (three real roots), polish by 2 Newton steps
    on the quartic (a cluster of small roots makes Laguerre from below slow)."""
    e1, e2, e3, e4 = coef
    a = top - e1  # x^3 + a x^2 + b x + c = quartic / (x - top)
    b = e2 + top * a
    c = -e3 + top * b
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    m = np.sqrt(np.maximum(-p / 3.0, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        arg = np.clip(np.where(m > 0, -q / (2.0 * m**3), 0.0), -1.0, 1.0)
    t = np.arccos(arg) / 3.0
    x = 2.0 * m * np.cos(t + 2.0 * np.pi / 3.0) - a / 3.0  # the smallest of the three
    step = np.zeros_like(x)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(2):
            f = (((x - e1) * x + e2) * x - e3) * x + e4
            df = ((4 * x - 3 * e1) * x + 2 * e2) * x - e3
            step = np.where(df != 0, f / df, 0.0)
            x = x - step
    return x, step


def _cond12(S: bw.Sym3, det: np.ndarray, xbar: np.ndarray, P: int,
            G_full: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Condition number of X = [g 1] (sqrt of eigenvalue ratio of X^T X), per board."""
    a, b, c, d, e, f = S
    x0, x1, x2 = xbar
    Pn = float(P)
    e1 = a + d + f + Pn * (x0 * x0 + x1 * x1 + x2 * x2) + Pn

    def m2(sii: np.ndarray, sjj: np.ndarray, sij: np.ndarray, xi: np.ndarray, xj: np.ndarray
           ) -> np.ndarray:  # 2x2 principal minor of A = S + P xbar xbar^T
        return sii * sjj - sij * sij + Pn * (sii * xj * xj + sjj * xi * xi - 2 * sij * xi * xj)

    e2 = m2(a, d, b, x0, x1) + m2(a, f, c, x0, x2) + m2(d, f, e, x1, x2) + Pn * (a + d + f)
    (i00, i01, i02, i11, i12, i22), _ = bw.inv3_sym(a, b, c, d, e, f)
    q = (i00 * x0 * x0 + i11 * x1 * x1 + i22 * x2 * x2 + 2 * (i01 * x0 * x1 + i02 * x0 * x2 + i12 * x1 * x2))
    e3 = det + Pn * q + Pn * ((a * d - b * b) + (a * f - c * c) + (d * f - e * e))  # q already / det
    e4 = Pn * det
    coef = (e1, e2, e3, e4)
    hi, s_hi = _laguerre_root(coef, e1.copy())
    lo, s_lo = _smallest_root(coef, hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.sqrt(hi / np.maximum(lo, 1e-300))
    unsure = ~np.isfinite(cond) | (cond > CHECK_COND) | (np.abs(s_lo) > 1e-9 * np.abs(lo)) \
        | (np.abs(s_hi) > 1e-9 * np.abs(hi))
    if unsure.any():
        ev = np.linalg.eigvalsh(G_full(unsure))
        cond[unsure] = np.sqrt(ev[:, -1] / np.maximum(ev[:, 0], 1e-300))
    return cond


class _ChannelCovariance(LazyCovariance):
    """(D, 3, 4, 4) covariance (X^T X)^-1 s2_c of model 12, built per board on indexing from the
    10 distinct entries of the symmetric (X^T X)^-1 (saves D x 38 floats and their copies).

    ``G`` (D, 10): S^-1 upper triangle (00 01 02 11 12 22), u = -S^-1 xbar (3), 1/P + xbar^T S^-1 xbar;
    ``s2`` (D, 3): the residual variance per output channel."""

    _ROWS = np.array([[0, 1, 2, 6], [1, 3, 4, 7], [2, 4, 5, 8], [6, 7, 8, 9]])
    _fields = ("G", "s2")

    def __init__(self, G: np.ndarray, s2: np.ndarray):
        self.G, self.s2 = G, s2

    def __getitem__(self, d: Any) -> np.ndarray:
        Ginv = self.G[d][..., self._ROWS]  # (..., 4, 4)
        return Ginv[..., None, :, :] * self.s2[d][..., None, None]


def _centred(gf: np.ndarray, ref: np.ndarray, boards_last: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Readings and references boards last (3, P, D) and centred: xc = g - mean(g),
    yc = y - mean(y) (the centred form of AN4399 Eqn 46).  Returns xc, yc, xbar (3, D),
    ybar (3, 1 or D) and y (3, P, 1 or D); shared (P, 3) references stay one column.
    ``boards_last``: gf already as (3, P, D), when the caller has that copy."""
    P = gf.shape[1]
    shared = ref.ndim == 2
    # (3, P, D): boards last, so sums over poses add P contiguous rows (short-row reductions are slow)
    g = bw.boards_last(gf) if boards_last is None else boards_last
    y = ref.T[:, :, None] if shared else np.ascontiguousarray(ref.transpose(2, 1, 0))  # (3, P, 1 or D)
    xbar, ybar = g.sum(axis=1) / P, y.sum(axis=1) / P  # (3, D), (3, 1 or D)
    return g - xbar[:, None, :], y - ybar[:, None, :], xbar, ybar, y


def _scatter_inverse(xc: np.ndarray) -> tuple[bw.Sym3, np.ndarray, np.ndarray, bw.Sym3]:
    """S = xc^T xc per board (its 6 distinct entries), det(S) (1 where singular), a quick
    ok screen (D,) and S^-1 from the adjugate (zero where singular)."""
    S = tuple((xc[i] * xc[j]).sum(axis=0) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    adj, det = bw.inv3_sym(*S)
    scale = np.maximum(S[0] + S[3] + S[5], 1e-300)
    ok = det > 1e-12 * scale**3  # a quick screen; the condition number decides below
    det_safe = np.where(ok, det, 1.0)
    Sinv = tuple(np.where(ok, v, 0.0) / det_safe for v in adj)
    return S, det_safe, ok, Sinv


def _slopes(Sinv: bw.Sym3, xc: np.ndarray, yc: np.ndarray, shared: bool) -> tuple[np.ndarray, np.ndarray]:
    """S^-1 as (3, 3, D) and W^T = S^-1 xc^T yc (3 in, 3 out, D): the slopes of AN4399 Eqn 46
    with the intercept column dropped (Frisch-Waugh)."""
    i00, i01, i02, i11, i12, i22 = Sinv
    Si = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])  # (3, 3, D)
    # C = xc^T yc (3 in, 3 out, D); shared references: (3, P) @ (3 in, P, D) is one BLAS call
    C = yc[:, :, 0] @ xc if shared else np.einsum("ipd,cpd->icd", xc, yc)
    return Si, np.einsum("jid,icd->jcd", Si, C)  # W[c, j] = Wt[j, c]


def _residuals_and_hat(xc: np.ndarray, yc: np.ndarray, Wt: np.ndarray, Sinv: bw.Sym3
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Reference minus calibrated r = yc - W xc (3, P, D) and the hat diagonal
    h = 1/P + xc^T S^-1 xc (P, D)."""
    i00, i01, i02, i11, i12, i22 = Sinv
    r = np.empty_like(xc)  # (3, P, D) reference minus calibrated
    for c in range(3):
        r[c] = yc[c] - Wt[0, c] * xc[0] - Wt[1, c] * xc[1] - Wt[2, c] * xc[2]
    h = (i00 * xc[0] ** 2 + i11 * xc[1] ** 2 + i22 * xc[2] ** 2
         + 2 * (i01 * xc[0] * xc[1] + i02 * xc[0] * xc[2] + i12 * xc[1] * xc[2]))
    h += 1.0 / xc.shape[1]  # hat diagonal (P, D)
    return r, h


def _gram(gf: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """X^T X of X = [g 1] for the boards in ``mask`` (n, 4, 4), for LAPACK's eigenvalues."""
    X = np.concatenate([gf[mask], np.ones((int(mask.sum()), gf.shape[1], 1))], axis=-1)
    return X.swapaxes(1, 2) @ X


def _leave_one_out12(r2: np.ndarray, h: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-pose-out RMS (D,) from the squared residuals r2 (3, P, D) and the hat
    diagonal: the left-out residual is r / (1 - h); and where it holds (D,)."""
    P = h.shape[0]
    fit_h = h < 1.0 - 1e-9
    cv_ok = fit_h.all(axis=0) & ok
    w = 1.0 / np.where(fit_h, 1.0 - h, 1.0) ** 2  # leave-one-out residual r / (1 - h), squared
    return np.where(cv_ok, np.sqrt(((r2[0] + r2[1] + r2[2]) * w).sum(axis=0) / (3 * P)), np.nan), cv_ok


def _inverse_gram(Sinv: bw.Sym3, Si: np.ndarray, xbar: np.ndarray, P: int) -> np.ndarray:
    """The 10 distinct entries (D, 10) of (X^T X)^-1 of X = [g 1] by the block (Schur complement)
    formula [[S^-1, -S^-1 xbar], [., 1/P + xbar^T S^-1 xbar]] (see _ChannelCovariance)."""
    u = -np.einsum("ijd,jd->id", Si, xbar)  # (3, D)
    return np.stack([*Sinv, u[0], u[1], u[2], 1.0 / P - (u * xbar).sum(axis=0)], axis=1)


def fit12(gf: ArrayLike, ref: ArrayLike, noise_g: ArrayLike | None = None,
          boards_last: np.ndarray | None = None) -> BatchFit:
    """Model 12 for a stack of boards (D, P, 3) in g; same results as fit_linear_batch.

    ``ref`` is (D, P, 3), or (P, 3) shared by every board: then its centred form, its norms
    and the cross products xc^T yc (one BLAS matmul) are computed once for the stack.
    ``boards_last``: the same readings as (3, P, D), when the caller has them so."""
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    if P < 4:
        raise UnderdeterminedError(f"model 12 needs at least 4 poses; got {P}")
    ref = np.asarray(ref, dtype=float)
    xc, yc, xbar, ybar, y = _centred(gf, ref, boards_last)
    S, det_safe, ok, Sinv = _scatter_inverse(xc)
    Si, Wt = _slopes(Sinv, xc, yc, shared=ref.ndim == 2)
    W = Wt.transpose(2, 1, 0)  # (D, 3, 3)
    V = ybar.T - np.einsum("dcj,dj->dc", W, xbar.T)
    r, h = _residuals_and_hat(xc, yc, Wt, Sinv)
    cond = _cond12(S, det_safe, xbar, P, lambda mask: _gram(gf, mask))
    ok &= np.isfinite(cond) & (cond <= COND_LIMIT)
    r2 = r * r
    rss = r2.sum(axis=1).T  # (D, 3)
    cv_rms, cv_ok = _leave_one_out12(r2, h, ok)
    s2 = residual_variance(noise_g, rss, D, P, P - 4)
    se_ok = np.all(np.isfinite(s2), axis=1) & ok
    s2z = np.where(np.isfinite(s2), s2, 0.0)
    G = _inverse_gram(Sinv, Si, xbar, P)
    sW = np.sqrt(np.clip(s2z[:, :, None] * G[:, None, [0, 3, 5]], 0.0, None))
    sV = np.sqrt(np.clip(s2z * G[:, 9:10], 0.0, None))
    resid = r.transpose(2, 1, 0)  # (D, P, 3) view
    cal = y - r
    norm_err = (np.sqrt(cal[0] * cal[0] + cal[1] * cal[1] + cal[2] * cal[2]) - np.sqrt((y * y).sum(axis=0))).T
    messages = [""] * D
    for d in np.flatnonzero(~ok):
        messages[d] = diagnose_underdetermined(gf[d], "12")
    W = np.where(ok[:, None, None], W, 0.0)
    V = np.where(ok[:, None], V, 0.0)
    return BatchFit(
        model="12", W=W, V=V, Gamma=np.zeros((D, 3)), residuals_g=resid, norm_error_g=norm_err, P=rss,
        residual_rms_g=np.sqrt(rss.sum(axis=1) / (3 * P)), crossval_rms_g=cv_rms, crossval_ok=cv_ok,
        condition_number=cond, stderr_W=sW, stderr_V=sV, stderr_Gamma=np.zeros((D, 3)), stderr_ok=se_ok,
        covariance=_ChannelCovariance(G, s2z),
        params=np.concatenate([W.reshape(D, 9), V], axis=1), param_names=param_names("12"),
        ok=ok, messages=messages, readings_g=gf)


# Boards per call.  A block makes the same numpy calls whatever its size, and two threads hand
# the GIL over at each, so longer calls let two threads do more; too long and the working set
# leaves the cache.  Model 9 (~1,500 calls): two threads fit 1.5x one at 8192 boards, 1.2x at
# 2048.  Model 12, two threads at 100k boards, four alternating rounds: 1.02-1.19 M fits/s at
# 8192, 1.10-1.28 M at 16384, 0.80-0.88 M at 25000.
BLOCK = {"12": 16384, "9": 8192, "6": 1 << 40, "15": 1 << 40}


class _Assembler:
    """One BatchFit of D boards from fits of board subsets (rows given by a slice or indices):
    each part is copied into arrays allocated at the first part as soon as it is fitted, while
    it is still in cache (and no list of parts is kept to concatenate afterwards)."""

    _SHARED = ("model", "param_names", "input_units")

    def __init__(self, D: int, gf: np.ndarray):
        self.D, self.gf = D, gf
        self.kw: dict[str, Any] | None = None
        self.whole: BatchFit | None = None
        self.copied: list[str] = []

    def add(self, rows: np.ndarray | slice, b: BatchFit) -> None:
        if isinstance(rows, slice) and rows == slice(0, self.D):
            self.whole = b
            return
        if self.kw is None:
            self.kw = {name: self._alloc(name, getattr(b, name)) for name in b.__dataclass_fields__}
            self.copied = [name for name, out in self.kw.items() if name not in self._SHARED
                           and (isinstance(out, (list, LazyCovariance))
                                or (isinstance(out, np.ndarray) and out is not self.gf))]
        for name in self.copied:
            out, v = self.kw[name], getattr(b, name)
            if isinstance(out, LazyCovariance):
                for f in out._fields:
                    getattr(out, f)[rows] = getattr(v, f)
            elif isinstance(out, np.ndarray) or isinstance(rows, slice):
                out[rows] = v
            else:
                for k, i in enumerate(rows):
                    out[i] = v[k]

    def _alloc(self, name: str, v0: Any) -> Any:
        D = self.D
        if name in self._SHARED:
            return v0
        if name == "readings_g":
            return self.gf
        if name in ("messages", "status"):
            return None if v0 is None else [""] * D
        if name in ("held", "freed"):  # (D,) lists of models/held.Held
            return [[]] * D  # one shared empty list: a part's terms replace it (BatchFit.held)
        if isinstance(v0, LazyCovariance):
            return type(v0)(*(np.empty((D,) + getattr(v0, f).shape[1:]) for f in v0._fields))
        if v0 is None or np.ndim(v0) == 0:
            return v0
        return np.empty_like(v0, shape=(D,) + np.shape(v0)[1:])  # the part's memory layout: contiguous copies

    def result(self) -> BatchFit:
        if self.whole is not None:
            return self.whole
        if self.kw is None:
            raise UnderdeterminedError("no boards to fit")
        return BatchFit(**self.kw)


def assemble(D: int, gf: np.ndarray, parts: Sequence[tuple[np.ndarray | slice, BatchFit]]) -> BatchFit:
    """One BatchFit of D boards from fits of board subsets (rows, fit), as fit_stacked's blocks
    are put together; every part must be of one model with the same fields."""
    out = _Assembler(D, gf)
    for rows, b in parts:
        out.add(rows, b)
    return out.result()


def _reference_groups(ref: np.ndarray) -> list[tuple[np.ndarray | slice, np.ndarray]]:
    """Boards grouped by identical reference sets: [(rows, shared (P, 3) references)].
    A lot usually has one set (the fixture's poses); a broadcast array is recognised free."""
    D = len(ref)
    if D == 0 or ref.strides[0] == 0 or np.array_equal(ref, np.broadcast_to(ref[0], ref.shape)):
        return [(slice(0, D), np.ascontiguousarray(ref[0]) if D else ref.reshape(-1, 3))]
    uniq, inv = np.unique(ref.reshape(D, -1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    return [(np.flatnonzero(inv == k), uniq[k].reshape(-1, 3)) for k in range(len(uniq))]


def _workers() -> int:
    """Threads for fit_stacked: the CPUs this process may run on (numpy releases the GIL in
    its loops and LAPACK calls, so blocks fit in parallel), at most 8."""
    return min(usable_cpus(), 8)


Job = tuple[np.ndarray | slice, np.ndarray | None]  # boards of one block, their references


def fit_stacked(gf: ArrayLike, ref: ArrayLike | None, model: str, noise_g: ArrayLike | None = None,
                workers: int | None = None, free: np.ndarray | None = None,
                boards_last: np.ndarray | None = None) -> BatchFit:
    """The fast fitter of ``model`` on (D, P, 3) readings in g (references in g for 6/12/15),
    in blocks of BLOCK[model] boards, fitted by ``workers`` threads (default: one per CPU);
    model 12 per group of boards sharing their references.  Blocks are independent, so the
    result does not depend on the number of threads.  Sets glibc's heap thresholds for the
    process (heap.keep_block_memory) so each block reuses the previous block's memory.
    ``free`` (D, 9) bool, model 9 only: the parameters fitted; the others are held at nominal
    (models/held.py, stacked_norm.fit9).  ``boards_last``: gf as (3, P, D) (models.screening's
    copy), so model 12 does not transpose it again."""
    keep_block_memory()
    gf = np.asarray(gf, dtype=float)
    D, P, _ = gf.shape
    ref = None if ref is None else np.broadcast_to(np.asarray(ref, dtype=float), (D, P, 3))
    nz = None if noise_g is None else np.broadcast_to(np.asarray(noise_g, dtype=float), (D, P, 3))
    groups: list[Job] = list(_reference_groups(ref)) if model == "12" and ref is not None else [(slice(0, D), ref)]
    jobs: list[Job] = []
    for rows, gref in groups:
        idx = np.arange(D)[rows] if isinstance(rows, slice) else rows
        for a in range(0, len(idx), BLOCK[model]):
            sel = slice(idx[0] + a, min(idx[0] + a + BLOCK[model], idx[-1] + 1)) \
                if isinstance(rows, slice) else idx[a:a + BLOCK[model]]
            jobs.append((sel, gref))

    def run(job: Job) -> tuple[np.ndarray | slice, BatchFit]:
        sel, gref = job  # gref: model 12 the block's shared (P, 3) references, 6 and 15 all (D, P, 3)
        n = None if nz is None else nz[sel]
        if model == "9":
            return sel, fit9(gf[sel], n, free=None if free is None else free[sel])
        if gref is None:  # fitting.fit_batch says so first; a direct caller gets the same words
            raise DataError(f"model {model} needs pose references (ref_x/ref_y/ref_z or pitch/roll); "
                            "model 9 needs none")
        if model == "12":
            return sel, fit12(gf[sel], gref, n, None if boards_last is None else boards_last[:, :, sel])
        return sel, fit_linear_batch(gf[sel], gref[sel], model, n)

    out = _Assembler(D, gf)
    workers = _workers() if workers is None else max(1, int(workers))
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            out.add(*run(job))
        return out.result()
    with ThreadPoolExecutor(max_workers=workers) as ex:
        pending: deque[Future[tuple[np.ndarray | slice, BatchFit]]] = deque()
        for job in jobs:  # at most 2 blocks per thread in flight: memory stays bounded
            pending.append(ex.submit(run, job))
            if len(pending) >= 2 * workers:
                out.add(*pending.popleft().result())
        while pending:
            out.add(*pending.popleft().result())
    return out.result()

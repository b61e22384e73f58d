"""Fits per second for many boards at once, beside per-device loops, in one run.

    python benchmarks/bench_batch_fit.py [--boards 100000] [--loop-boards 2000] [--small]

Every model (6, 12, 15, 9): accelcal's stacked ``fit_batch`` beside a per-device
loop of the same library call ``accelcal_station.models.fit`` (one board at a
time: what a script without batching does), and beside a bare per-device loop
of the textbook solver: ``numpy.linalg.lstsq`` on the AN4399 regressors for the
linear models, ``scipy.optimize.least_squares`` (LM) on the same residual for
model 9.  The stacked fits also give every board its standard errors,
leave-one-out residuals and condition number; the bare loops give coefficients
only.  Loops run on a subset (--loop-boards) and their rate is per board, so
the ratios are like for like.  Boards are ideal sensors with random
gain/offset/cross-axis and 1 mg noise; linear models use AN4399 Table 5 (8
poses), model 9 twelve poses spread over the sphere.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import norm_residual

from accelcal_station.conventions import an4399_reference
from accelcal_station.models.fitting import fit, fit_batch
from accelcal_station.models.gravity_norm import fit_norm_batch
from accelcal_station.models.linear import regressors


def make_boards(D: int, ref: np.ndarray, rng) -> np.ndarray:
    K = np.eye(3) + rng.normal(0, 0.01, (D, 3, 3))
    off = rng.normal(0, 0.03, (D, 1, 3))
    return np.einsum("dij,pj->dpi", K, ref) + off + rng.normal(0, 1e-3, (D,) + ref.shape)


def rate(fn, n: int) -> tuple[float, float]:
    t0 = time.perf_counter()
    fn()
    dt = time.perf_counter() - t0
    return n / dt, dt


def _sphere(rng: np.random.Generator, n: int = 12) -> np.ndarray:
    """``n`` directions spread over the sphere (model 9 needs no references, only orientations)."""
    dirs = rng.normal(size=(n, 3))
    return dirs / np.linalg.norm(dirs, axis=1, keepdims=True)


def linear_rows(row, x: np.ndarray, ref8: np.ndarray, model: str, L: int, boards: int) -> None:
    """Model 6, 12 or 15: the stacked fit against a loop of models.fit and a loop of numpy lstsq."""
    r_ours, t = rate(lambda: fit_batch(x, ref8, model), boards)
    row(model, "accelcal fit_batch (stacked normal eqns)", r_ours, t, 1.0)
    r, t = rate(lambda: [fit(x[d], ref8, model) for d in range(L)], L)
    row(model, "loop of accelcal models.fit", r, t, r_ours / r)

    def loop_lstsq() -> None:
        X = regressors(x[:L], model)  # (L, 3, P, k): each channel its own design
        for d in range(L):
            if model == "12":
                np.linalg.lstsq(X[d, 0], ref8, rcond=None)
            else:
                for c in range(3):
                    np.linalg.lstsq(X[d, c], ref8[:, c], rcond=None)
    r, t = rate(loop_lstsq, L)
    row(model, "loop of numpy.linalg.lstsq", r, t, r_ours / r)


def norm_rows(row, x9: np.ndarray, L: int, L9: int, boards: int) -> None:
    """Model 9 on 12 poses spread over the sphere: stacked LM, with leave-one-out, loops, scipy."""
    r9, t = rate(lambda: fit_norm_batch(x9, crossval=False), boards)
    row(9, "accelcal fit_norm_batch (stacked LM)", r9, t, 1.0)
    n_cv = max(10, boards // 10)
    r9cv, t = rate(lambda: fit_batch(x9[:n_cv], None, "9"), n_cv)
    row(9, "  fit_batch, with leave-one-out crossval", r9cv, t, r9 / r9cv)
    r, t = rate(lambda: [fit(x9[d], None, "9") for d in range(L9)], L9)
    row(9, "  loop of accelcal models.fit (crossval too)", r, t, r9cv / r)
    p0 = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float)
    r, t = rate(lambda: [least_squares(norm_residual, p0, args=(x9[d],), method="lm") for d in range(L)], L)
    row(9, "loop of scipy.optimize.least_squares", r, t, r9 / r)
    print("ratio: the stacked rate divided by this row's rate (indented loop rows: vs the crossval row)")
    # agreement on the looped boards
    n = min(50, boards)
    ours = fit_norm_batch(x9[:n], crossval=False).params
    theirs = np.array([least_squares(norm_residual, p0, args=(x9[d],), method="lm").x for d in range(n)])
    print(f"max |param difference| ours vs scipy over {n} boards: {np.max(np.abs(ours - theirs)):.2e}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=100_000)
    ap.add_argument("--loop-boards", type=int, default=2000)
    ap.add_argument("--small", action="store_true", help="a quick run: 2000 boards, loops on 100")
    a = ap.parse_args(argv)
    if a.small:
        a.boards, a.loop_boards = min(a.boards, 2000), min(a.loop_boards, 100)
    if a.boards < 10 or a.loop_boards < 1:
        print("error: --boards >= 10 and --loop-boards >= 1", file=sys.stderr)
        return 2
    rng = np.random.default_rng(0)
    ang = np.array([[-35, -45], [-73, 161], [5, 17], [-16, 84], [16, -96], [-5, -163], [73, -18], [35, 135]])
    ref8 = an4399_reference(ang[:, 0], ang[:, 1])
    x = make_boards(a.boards, ref8, rng)
    L = min(a.loop_boards, a.boards)
    L9 = max(1, L // 4)  # models.fit with model 9 refits every leave-one-out subset: a slower loop

    print(f"fits per second: {a.boards} boards stacked (loops on {L}, model 9 library loop on {L9}); "
          "linear models on 8 poses (AN4399 Table 5), model 9 on 12 poses")
    print(f"{'model':>5} {'method':<44} {'fits/s':>12} {'seconds':>9} {'ratio':>8}")

    def row(model, method, r, t, ratio):
        print(f"{model:>5} {method:<44} {r:12.0f} {t:9.2f} {ratio:8.1f}", flush=True)

    for model in ("6", "12", "15"):
        linear_rows(row, x, ref8, model, L, a.boards)
    norm_rows(row, make_boards(a.boards, _sphere(rng), rng), L, L9, a.boards)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Fits per second for many boards at once, beside per-device loops, in one run.

    python benchmarks/bench_batch_fit.py [--boards 100000] [--loop-boards 2000]

Model 12: accelcal's stacked fit vs a per-device loop of numpy.linalg.lstsq.
Model 9: accelcal's stacked Levenberg-Marquardt vs a per-device loop of
scipy.optimize.least_squares on the same residual.  The loops run on a subset
(--loop-boards) and their rate is per board, so the ratios are like for like.
Boards are ideal sensors with random gain/offset/cross-axis and 1 mg noise.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.optimize import least_squares

from accelcal_station.conventions import an4399_reference
from accelcal_station.models import fit_batch
from accelcal_station.models.gravity_norm import fit_norm_batch


def make_boards(D: int, ref: np.ndarray, rng) -> np.ndarray:
    K = np.eye(3) + rng.normal(0, 0.01, (D, 3, 3))
    off = rng.normal(0, 0.03, (D, 1, 3))
    return np.einsum("dij,pj->dpi", K, ref) + off + rng.normal(0, 1e-3, (D,) + ref.shape)


def rate(fn, n: int) -> tuple[float, float]:
    t0 = time.perf_counter()
    fn()
    dt = time.perf_counter() - t0
    return n / dt, dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=100_000)
    ap.add_argument("--loop-boards", type=int, default=2000)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    ang = np.array([[-35, -45], [-73, 161], [5, 17], [-16, 84], [16, -96], [-5, -163], [73, -18], [35, 135]])
    ref8 = an4399_reference(ang[:, 0], ang[:, 1])
    x = make_boards(a.boards, ref8, rng)
    L = min(a.loop_boards, a.boards)

    print(f"boards: {a.boards} (loops on {L}), 8 poses each (AN4399 Table 5)")
    print(f"{'model':>5} {'method':<40} {'fits/s':>12} {'seconds':>9} {'ratio':>8}")

    r_ours, t = rate(lambda: fit_batch(x, ref8, "12"), a.boards)
    print(f"{12:>5} {'accelcal fit_batch (stacked normal eqns)':<40} {r_ours:12.0f} {t:9.2f} {1.0:8.1f}")

    def loop_lstsq():
        X = np.concatenate([x[:L], np.ones((L, 8, 1))], axis=2)
        for d in range(L):
            np.linalg.lstsq(X[d], ref8, rcond=None)
    r, t = rate(loop_lstsq, L)
    print(f"{12:>5} {'loop of numpy.linalg.lstsq':<40} {r:12.0f} {t:9.2f} {r_ours / r:8.1f}")

    # model 9 on 12 poses spread over the sphere
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    x9 = make_boards(a.boards, dirs, rng)
    r9, t = rate(lambda: fit_norm_batch(x9, crossval=False), a.boards)
    print(f"{9:>5} {'accelcal fit_norm_batch (stacked LM)':<40} {r9:12.0f} {t:9.2f} {1.0:8.1f}")
    r9cv, t = rate(lambda: fit_batch(x9[: a.boards // 10], None, "9"), a.boards // 10)
    print(f"{9:>5} {'  same, with leave-one-out crossval':<40} {r9cv:12.0f} {t:9.2f} {r9 / r9cv:8.1f}")

    def resid(p, v):
        M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
        return np.linalg.norm((v - p[6:]) @ M, axis=1) - 1.0

    p0 = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float)
    def loop_ls():
        for d in range(L):
            least_squares(resid, p0, args=(x9[d],), method="lm")
    r, t = rate(loop_ls, L)
    print(f"{9:>5} {'loop of scipy.optimize.least_squares':<40} {r:12.0f} {t:9.2f} {r9 / r:8.1f}")
    # agreement on the looped boards
    ours = fit_norm_batch(x9[:50], crossval=False).params
    theirs = np.array([least_squares(resid, p0, args=(x9[d],), method="lm").x for d in range(50)])
    print(f"max |param difference| ours vs scipy over 50 boards: {np.max(np.abs(ours - theirs)):.2e}")


if __name__ == "__main__":
    main()

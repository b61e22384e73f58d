"""Accuracy against peers on identical data: imucal's Ferraris calibration and scipy least_squares.

    python benchmarks/bench_peers.py [--boards 500] [--samples 256] [--heldout 10] [--small]

Every board (a simulated MMA8451 with noise, quantization, offset, gain and a
symmetric cross-axis matrix: a truth that all four methods can represent) is
measured once at the nine-position design (six faces + three 45 deg tilts),
``--samples`` raw samples per pose, and at ``--heldout`` random orientations.

* imucal ``FerrarisCalibration`` (installed by ``pip install -e '.[bench]'``) gets the
  six faces' raw samples through ``ferraris_regions_from_df``, with ``grav=1.0`` so
  it works in g.  Its gyroscope half needs regions too: it is fed zero-rate static
  gyro samples and, for each ``*_rot`` region, the same face's accelerometer
  samples (a turn about the vertical axis leaves them unchanged) with an exact
  -360 deg turn about that axis.  Only the accelerometer result is compared.
* accelcal model 12 gets the same six faces' means (same samples).
* scipy ``least_squares`` (method "lm"), one board at a time, and accelcal model 9
  (stacked Levenberg-Marquardt) fit the 9-parameter gravity-norm model
  ``A = M (V - B)`` to the same nine pose means.

Errors are against the simulator truth: RMS of W (ppm) and V (mg) in AN4399 form
(``G = W G_f + V``), tilt and |g| error of fresh held-out readings after calibration.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import (
    angle_deg,
    apply_an4399,
    design_refs,
    make_boards,
    measure,
    measure_raw,
    norm_residual,
    random_directions,
    rms,
    table,
    truth_stack,
)

from accelcal_station.models.fitting import fit_batch

NOT_INSTALLED = "imucal not installed: pip install -e '.[bench]'"
FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")  # imucal names of nine-position poses 0..5


def imucal_fits(raw6: np.ndarray, odr_hz: float):
    """imucal's Ferraris calibration of each board's six faces (raw6: (D, 6, n, 3) in g).

    Returns (W (D,3,3), V (D,3), calibrate(d, acc) -> calibrated acc, seconds, version),
    or None when imucal cannot be imported.
    """
    try:
        import imucal
        import pandas as pd
        from imucal import FerrarisCalibration, ferraris_regions_from_df
    except ImportError:
        return None
    D, _, n, _ = raw6.shape
    labels = np.repeat(np.array(FerrarisCalibration.FERRARIS_SECTIONS), n)
    still = np.zeros((n, 3))
    cols = ["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]
    W, V, infos, spent = np.empty((D, 3, 3)), np.empty((D, 3)), [], 0.0
    for d in range(D):
        acc = [raw6[d, i] for i in range(6)] + [raw6[d, 0], raw6[d, 2], raw6[d, 4]]  # *_rot: the *_p face
        gyr = [still] * 6
        for axis in range(3):
            turn = np.zeros((n, 3))
            turn[:, axis] = -360.0 * odr_hz / n  # integrates to exactly -360 deg (imucal's default)
            gyr.append(turn)
        df = pd.DataFrame(np.hstack([np.vstack(acc), np.vstack(gyr)]), columns=cols, index=labels)
        t0 = time.perf_counter()
        info = FerrarisCalibration(grav=1.0).compute(ferraris_regions_from_df(df), sampling_rate_hz=odr_hz,
                                                     from_acc_unit="g", from_gyr_unit="deg/s")
        spent += time.perf_counter() - t0
        # imucal applies a = R_a^-1 K_a^-1 (u - b_a): in AN4399 form W = R_a^-1 K_a^-1, V = -W b_a
        W[d] = np.linalg.inv(info.R_a) @ np.linalg.inv(info.K_a)
        V[d] = -W[d] @ info.b_a
        infos.append(info)

    def calibrate(d: int, acc: np.ndarray) -> np.ndarray:
        out, _ = infos[d].calibrate(acc=acc, gyr=np.zeros_like(acc), acc_unit="g", gyr_unit="deg/s")
        return out

    version = getattr(imucal, "__version__", "?")
    return W, V, calibrate, spent, version


def scipy_fits(x9: np.ndarray):
    """Per-board scipy.optimize.least_squares of the 9-parameter model; W = M, V = -M B."""
    p0 = np.array([1, 1, 1, 0, 0, 0, 0, 0, 0], dtype=float)
    t0 = time.perf_counter()
    P = np.array([least_squares(norm_residual, p0, args=(x,), method="lm").x for x in x9])
    spent = time.perf_counter() - t0
    M = P[:, [0, 3, 4, 3, 1, 5, 4, 5, 2]].reshape(-1, 3, 3)
    return M, -np.einsum("dij,dj->di", M, P[:, 6:]), P, spent


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=500, help="simulated boards (default 500)")
    ap.add_argument("--samples", type=int, default=256, help="samples per pose (default 256)")
    ap.add_argument("--heldout", type=int, default=10, help="held-out orientations per board (default 10)")
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--small", action="store_true", help="a quick run: 30 boards, 4 held-out orientations")
    a = ap.parse_args(argv)
    if a.small:
        a.boards, a.heldout = min(a.boards, 30), min(a.heldout, 4)
    if a.boards < 1 or a.samples < 2 or a.heldout < 1:
        print("error: --boards >= 1, --samples >= 2, --heldout >= 1", file=sys.stderr)
        return 2
    boards = make_boards("9", a.boards, a.seed)
    W0, V0, G0 = truth_stack(boards)
    ref9 = design_refs("nine-position")
    raw = np.stack([measure_raw(b, ref9, a.samples) for b in boards])  # (D, 9, n, 3) g
    rng = np.random.default_rng(a.seed + 1)
    dirs = random_directions((a.boards, a.heldout), rng)
    fresh = np.stack([measure(b, d, a.samples) for b, d in zip(boards, dirs, strict=True)])
    odr = boards[0].odr_hz

    def scores(W, V, cal=None):
        out = apply_an4399(W, V, np.zeros_like(V), fresh) if cal is None else cal
        return {"W": rms(W - W0) * 1e6, "V": rms(V - V0) * 1e3, "tilt": rms(angle_deg(out, dirs)),
                "norm": rms(np.linalg.norm(out, axis=-1) - 1.0) * 1e3}

    rows, res, im, Ps, f9 = compare(a, raw, ref9, fresh, odr, W0, V0, scores)
    report(a, odr, rows, res, im is not None, np.max(np.abs(Ps - f9.params)))
    return 0


def compare(a, raw, ref9, fresh, odr, W0, V0, scores):
    """Every method on the same samples: imucal (six faces), ours 12 and 9, scipy's 9, the truth."""
    x9 = raw.mean(axis=2)
    rows, res = [], {}

    def add(key, label, data, sc, seconds):
        res[key] = sc
        rows.append([label, data, f"{sc['W']:.1f}", f"{sc['V']:.4f}", f"{sc['tilt']:.5f}", f"{sc['norm']:.4f}",
                     "-" if seconds is None else f"{seconds / a.boards * 1e3:.3f}"])

    im = imucal_fits(raw[:, :6], odr)
    if im is not None:
        Wi, Vi, cal_i, t_i, ver = im
        out_i = np.stack([cal_i(d, fresh[d]) for d in range(a.boards)])
        add("imucal", f"imucal {ver} FerrarisCalibration", "six faces", scores(Wi, Vi, out_i), t_i)
    t0 = time.perf_counter()
    f12 = fit_batch(x9[:, :6], ref9[:6], "12")
    add("ours12_6", "accelcal model 12", "six faces", scores(f12.W, f12.V), time.perf_counter() - t0)
    Ws, Vs, Ps, t_s = scipy_fits(x9)
    add("scipy9", "scipy least_squares, 9-param", "nine positions", scores(Ws, Vs), t_s)
    t0 = time.perf_counter()
    f9 = fit_batch(x9, None, "9")
    add("ours9", "accelcal model 9", "nine positions", scores(f9.W, f9.V), time.perf_counter() - t0)
    t0 = time.perf_counter()
    f12n = fit_batch(x9, ref9, "12")
    add("ours12_9", "accelcal model 12", "nine positions", scores(f12n.W, f12n.V), time.perf_counter() - t0)
    add("truth", "true calibration (noise only)", "held-out only", scores(W0, V0), None)
    return rows, res, im, Ps, f9


def report(a, odr, rows, res, with_imucal: bool, max_diff: float) -> None:
    """The table of errors against the truth, and the peer / ours ratios."""
    print(f"accuracy vs peers on identical data: {a.boards} simulated MMA8451 boards (noise, quantization, offset, "
          f"gain, symmetric cross-axis), {a.samples} samples per pose at {odr:g} Hz, {a.heldout} held-out "
          f"orientations per board, seed {a.seed}")
    if not with_imucal:
        print(NOT_INSTALLED)
    print("errors vs the simulator truth (RMS over boards): W in ppm, V in mg (AN4399 form), held-out tilt in deg "
          "and |g| in mg; ms/board: fit time only")
    print(table(["method", "data", "W ppm", "V mg", "tilt deg", "|g| mg", "ms/board"], rows))
    print("ratios, peer / ours on the same data (> 1: ours is closer to the truth):")
    pairs = [("scipy9", "ours9", "scipy least_squares 9-param / accelcal model 9")]
    if with_imucal:
        pairs.insert(0, ("imucal", "ours12_6", "imucal Ferraris / accelcal model 12 (six faces)"))
    rrows = [[label] + [f"{res[p][k] / res[o][k]:.2f}" for k in ("W", "V", "tilt", "norm")] for p, o, label in pairs]
    print(table(["comparison", "W", "V", "tilt", "|g|"], rrows))
    print(f"max |parameter difference| scipy vs accelcal model 9 over {a.boards} boards: "
          f"{max_diff:.1e}")


if __name__ == "__main__":
    sys.exit(main())

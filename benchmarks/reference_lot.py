"""A plain numpy lot pipeline: the yardstick benchmarks/gate.py holds `accelcal batch LOT --out`
against (issue 35).

What a test engineer would write without the project: read the lot CSV (pyarrow's reader), take
each board's P consecutive rows, fit model 12 (AN4399 Eqn 46: [g 1] beta = ref, by the normal
equations over the stack, ``np.linalg.solve``), the leave-one-pose-out residuals from the hat
matrix diagonal (r / (1 - h)), and a PASS/FAIL verdict on limits of the residual RMS, largest
residual, leave-one-out RMS, gain error, cross-axis term and offset, and write one CSV row per
board.  It uses nothing of accelcal_station, so agreement with the project's numbers is a check
from outside (gate.py asserts it).

Assumes what the gate's lot has: every board has the same poses in the same order, counts with a
``# counts_per_g:`` line, pitch/roll references (AN4399 convention: (-sin theta, cos theta sin phi,
cos theta cos phi) g).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

# the limits the reference judges (acceptance keys of a station config), mg or fraction
LIMIT_KEYS = ("residual_rms_mg", "residual_max_mg", "crossval_rms_mg", "gain_error_max", "cross_axis_max",
              "offset_max_mg")


@dataclass
class LotFit:
    serial: np.ndarray  # (D,) str
    W: np.ndarray  # (D, 3, 3)
    V: np.ndarray  # (D, 3) g
    residual_rms_g: np.ndarray  # (D,)
    crossval_rms_g: np.ndarray  # (D,)
    passed: np.ndarray  # (D,) bool


def read_lot(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(serials (N,), readings (N, 3) counts, references (N, 3) g, counts per g) of a lot CSV."""
    import pyarrow.csv as pcsv

    per_g = None
    skip = 0
    with open(path) as f:
        for line in f:
            if not line.startswith("#"):
                break
            skip += 1
            key, _, value = line[1:].partition(":")
            if key.strip() == "counts_per_g":
                per_g = float(value)
    if per_g is None:
        raise ValueError(f"{path}: no '# counts_per_g:' line")
    t = pcsv.read_csv(path, read_options=pcsv.ReadOptions(skip_rows=skip))
    x = np.column_stack([t.column(c).to_numpy() for c in ("x", "y", "z")]).astype(float)
    th, ph = (np.radians(t.column(c).to_numpy().astype(float)) for c in ("pitch_deg", "roll_deg"))
    ref = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)])
    return t.column("serial").to_numpy().astype(str), x, ref, per_g


def fit_lot(serial: np.ndarray, x_counts: np.ndarray, ref: np.ndarray, per_g: float,
            limits: dict[str, float]) -> LotFit:
    """Model 12 and the verdict for boards of P consecutive rows each (P from the first board)."""
    P = int(np.argmax(serial != serial[0])) or len(serial)
    D = len(serial) // P
    g = x_counts.reshape(D, P, 3) / per_g
    y = ref.reshape(D, P, 3)
    X = np.concatenate([g, np.ones((D, P, 1))], axis=2)  # (D, P, 4)
    XtX = X.transpose(0, 2, 1) @ X
    beta = np.linalg.solve(XtX, X.transpose(0, 2, 1) @ y)  # (D, 4, 3): rows W^T then V
    W, V = beta[:, :3].transpose(0, 2, 1), beta[:, 3]
    r = y - X @ beta  # reference minus calibrated
    h = np.einsum("dpi,dij,dpj->dp", X, np.linalg.inv(XtX), X)
    rms = np.sqrt(np.mean(r**2, axis=(1, 2)))
    cv = np.sqrt(np.mean((r / (1.0 - h)[..., None]) ** 2, axis=(1, 2)))
    measured = {"residual_rms_mg": rms * 1e3, "residual_max_mg": np.abs(r).max(axis=(1, 2)) * 1e3,
                "crossval_rms_mg": cv * 1e3,
                "gain_error_max": np.abs(np.diagonal(W, axis1=1, axis2=2) - 1.0).max(axis=1),
                "cross_axis_max": np.abs(W * (1 - np.eye(3))).max(axis=(1, 2)),
                "offset_max_mg": np.abs(V).max(axis=1) * 1e3}
    passed = np.ones(D, bool)
    for key, lim in limits.items():
        passed &= measured[key] <= lim
    return LotFit(serial[::P], W, V, rms, cv, passed)


def write_results(fit: LotFit, out: str | Path) -> None:
    """One CSV row per board: serial, W (9), V (3), RMS and leave-one-out RMS in mg, verdict."""
    D = len(fit.serial)
    nums = np.column_stack([fit.W.reshape(D, 9), fit.V, fit.residual_rms_g * 1e3, fit.crossval_rms_g * 1e3])
    table = np.column_stack([fit.serial, nums.astype(str), np.where(fit.passed, "PASS", "FAIL")])
    header = ",".join(["serial", *(f"W{i}{j}" for i in range(3) for j in range(3)), "V0", "V1", "V2",
                       "residual_rms_mg", "crossval_rms_mg", "verdict"])
    np.savetxt(out, table, fmt="%s", delimiter=",", header=header, comments="")


def run(path: str | Path, out: str | Path, limits: dict[str, float]) -> LotFit:
    """The whole reference pipeline: read, fit, judge, write."""
    serial, x, ref, per_g = read_lot(path)
    fit = fit_lot(serial, x, ref, per_g, limits)
    write_results(fit, out)
    return fit

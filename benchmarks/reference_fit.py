"""A plain numpy `fit`: the yardstick benchmarks/gate.py holds `accelcal fit TABLE --model 12` against.

    python benchmarks/reference_fit.py TABLE.csv

Reads a pose table in counts (``# counts_per_g:`` line, x/y/z and pitch_deg/roll_deg columns),
fits model 12 (AN4399 Eqn 46: [g 1] beta = ref by least squares, ``np.linalg.lstsq``) and prints W,
V and the residual RMS in g as one JSON line: the same parse and solve as the command, with nothing
else (no checks, no identifiability, no report).  Uses nothing of accelcal_station.
"""
from __future__ import annotations

import json
import sys

import numpy as np


def main(path: str) -> None:
    per_g = 1.0
    with open(path) as f:
        lines = f.read().splitlines()
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    for ln in lines:
        if ln.startswith("# counts_per_g:"):
            per_g = float(ln.split(":", 1)[1])
    cols = body[0].split(",")
    rows = [ln.split(",") for ln in body[1:]]
    col = lambda name: np.array([float(r[cols.index(name)]) for r in rows])  # noqa: E731
    g = np.column_stack([col("x"), col("y"), col("z")]) / per_g
    th, ph = np.radians(col("pitch_deg")), np.radians(col("roll_deg"))
    ref = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)])
    X = np.column_stack([g, np.ones(len(g))])
    beta, *_ = np.linalg.lstsq(X, ref, rcond=None)
    r = ref - X @ beta
    rms = float(np.sqrt(np.mean(r**2)))
    print(json.dumps({"W": beta[:3].T.tolist(), "V": beta[3].tolist(), "residual_rms_g": rms}))


if __name__ == "__main__":
    main(sys.argv[1])

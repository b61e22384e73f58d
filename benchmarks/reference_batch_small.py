"""What a test engineer would write without accelcal (issue 51's yardstick for a small lot): pandas
read_csv in chunks, model 12 by the normal equations (AN4399 Eqn 46: [g 1] beta = ref), residual RMS,
leave-one-pose-out RMS through the hat matrix (r / (1 - h)), one results CSV.  Run as a whole process.

  python benchmarks/reference_batch_small.py LOT.csv RESULTS.csv
"""
import sys

import numpy as np
import pandas as pd

lot, out = sys.argv[1], sys.argv[2]
per_g, skip = 1.0, 0
with open(lot) as f:
    while (line := f.readline()).startswith("#"):
        skip += 1
        key, _, value = line[1:].partition(":")
        per_g = float(value) if key.strip() == "counts_per_g" else per_g
cols = ["serial", "pitch_deg", "roll_deg", "x", "y", "z"]
with open(out, "w") as f:
    f.write("serial," + ",".join(f"W{i}{j}" for i in range(3) for j in range(3))
            + ",V0,V1,V2,residual_rms_mg,crossval_rms_mg\n")
    for chunk in pd.read_csv(lot, skiprows=skip, usecols=cols, chunksize=8 * 4096):  # whole boards a chunk
        serial = chunk["serial"].to_numpy()
        P = int(np.argmax(serial != serial[0])) or len(serial)
        D = len(serial) // P
        th, ph = np.radians(chunk["pitch_deg"].to_numpy()), np.radians(chunk["roll_deg"].to_numpy())
        y = np.column_stack([-np.sin(th), np.cos(th) * np.sin(ph), np.cos(th) * np.cos(ph)]).reshape(D, P, 3)
        g = chunk[["x", "y", "z"]].to_numpy(float).reshape(D, P, 3) / per_g
        X = np.concatenate([g, np.ones((D, P, 1))], axis=2)
        XtX_inv = np.linalg.inv(X.transpose(0, 2, 1) @ X)
        beta = XtX_inv @ (X.transpose(0, 2, 1) @ y)  # (D, 4, 3): rows W^T then V
        r = y - X @ beta
        h = np.einsum("dpi,dij,dpj->dp", X, XtX_inv, X)
        rms = np.sqrt(np.mean(r**2, axis=(1, 2))) * 1e3
        loo = np.sqrt(np.mean((r / (1.0 - h)[..., None]) ** 2, axis=(1, 2))) * 1e3
        nums = np.column_stack([beta[:, :3].transpose(0, 2, 1).reshape(D, 9), beta[:, 3], rms, loo])
        pd.DataFrame(nums, index=serial[::P]).to_csv(f, header=False, float_format="%.17g")

"""Accuracy against the physical limit: fitted parameters and tilt vs the Cramer-Rao prediction.

    python benchmarks/bench_accuracy.py [--boards 1000] [--samples 256] [--heldout 10] [--small]

For each model (6, 9, 12, 15), a population of simulated MMA8451 boards with only
that model's class of errors (plus noise and quantization; see benchlib.py) is
measured at every design that determines the model, ``--samples`` samples per pose.
Per design:

* RMS over boards of (fitted - true) parameter, divided by the standard error
  ``fixtures.designs.predict_stderr`` predicts for that design and noise (the
  Cramer-Rao bound at an ideal sensor), pooled per parameter group; 1.00 is the limit.
* tilt error on held-out random orientations (not in any design): the angle between
  the calibrated fresh averaged reading and the true gravity direction, RMS in
  degrees, beside (a) the noise-only limit (the same readings through the true
  calibration) and (b) the tilt the Cramer-Rao covariance predicts after calibrating
  with this design (noise-only limit plus the calibration's own parameter error).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import (
    CLASS_EFFECTS,
    angle_deg,
    apply_an4399,
    design_refs,
    make_boards,
    measure,
    params_by_name,
    random_directions,
    rms,
    sem_g,
    table,
    truth_stack,
)

from accelcal_station.fixtures.designs import predict_stderr
from accelcal_station.models.fitting import fit_batch
from accelcal_station.models.gravity_norm import fit_norm_batch
from accelcal_station.models.linear import fit_linear_batch, regressors

PLAN = {  # model -> designs that determine it (an4399-2/-3 only determine model 6); plus optimal-N
    "6": ["an4399-2", "an4399-3", "an4399-4", "an4399-6", "an4399-8", "six-face"],
    "12": ["an4399-4", "an4399-6", "an4399-8", "six-face"],
    "15": ["an4399-8"],
    "9": ["nine-position"],
}
GROUPS = {"6": ("W", "V"), "12": ("W", "V"), "15": ("W", "V", "Gamma"), "9": ("M", "B")}


def predicted_tilt_deg(design: str, model: str, sem: float, dirs: np.ndarray) -> float:
    """RMS tilt after calibrating with ``design`` at noise ``sem`` (g), predicted from the
    Cramer-Rao covariance at an ideal sensor: per direction r, E[angle^2] =
    tr(S) - r^T S r with S = sem^2 I (fresh reading) + cov of the calibrated output."""
    ref = design_refs(design)[None]
    noise = np.full(ref.shape, sem)
    r = dirs.reshape(-1, 3)
    if model == "9":
        cov = fit_norm_batch(ref, noise_g=noise, crossval=False).covariance[0]  # (9, 9)
        J = np.zeros((len(r), 3, 9))  # d(M (r - B)) / dp at M = I, B = 0
        for j, (a, b) in enumerate([(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]):
            J[:, a, j] += r[:, b]
            if a != b:
                J[:, b, j] += r[:, a]
        J[:, :, 6:] = -np.eye(3)
        S = np.einsum("nij,jk,nlk->nil", J, cov, J)
    else:
        cov = fit_linear_batch(ref, ref, model, noise_g=noise).covariance[0]  # (3, k, k) per channel
        X = regressors(r[None], model)[0]  # (3, n, k)
        S = np.zeros((len(r), 3, 3))
        S[:, [0, 1, 2], [0, 1, 2]] = np.einsum("cnk,ckl,cnl->nc", X, cov, X)
    S = S + sem**2 * np.eye(3)
    a2 = np.trace(S, axis1=1, axis2=2) - np.einsum("ni,nij,nj->n", r, S, r)
    return float(np.rad2deg(np.sqrt(np.mean(a2))))


def run(boards: int, samples: int, heldout: int, seed: int, models: list[str], optimal: int) -> list[dict]:
    rows = []
    for m_i, model in enumerate(models):
        pop = make_boards(model, boards, seed + m_i)
        W0, V0, G0 = truth_stack(pop)
        sem = sem_g(pop[0], samples)
        rng = np.random.default_rng(seed + 100 + m_i)
        dirs = random_directions((boards, heldout), rng)
        fresh = np.stack([measure(b, d, samples) for b, d in zip(pop, dirs, strict=True)])  # (D, H, 3)
        limit = rms(angle_deg(apply_an4399(W0, V0, G0, fresh), dirs))
        for design in PLAN[model] + ([f"optimal-{optimal}"] if optimal >= (9 if model == "9" else 5) else []):
            ref = design_refs(design)
            x = np.stack([measure(b, ref, samples) for b in pop])  # (D, P, 3) in g
            fit = fit_batch(x, None if model == "9" else ref, model)
            pred = predict_stderr(design, model, sem)
            truth = params_by_name(fit.param_names, W0, V0, G0)
            z = (fit.params - truth) / pred["params"]  # (D, k): error in predicted standard errors
            ratio = {g: float(np.sqrt(np.mean(z[:, [n.split("_")[0] == g for n in fit.param_names]] ** 2)))
                     for g in GROUPS[model]}
            tilt = rms(angle_deg(apply_an4399(fit.W, fit.V, fit.Gamma, fresh), dirs))
            rows.append({"model": model, "design": design, "poses": len(ref), "ok": int(fit.ok.sum()),
                         "ratio": ratio, "tilt_deg": tilt, "tilt_cr_deg": predicted_tilt_deg(design, model, sem, dirs),
                         "limit_deg": limit, "sem_mg": sem * 1e3})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boards", type=int, default=1000, help="simulated boards per model (default 1000)")
    ap.add_argument("--samples", type=int, default=256, help="samples averaged per pose (default 256)")
    ap.add_argument("--heldout", type=int, default=10, help="held-out orientations per board (default 10)")
    ap.add_argument("--models", default="6,12,15,9", help="comma-separated models (default 6,12,15,9)")
    ap.add_argument("--optimal", type=int, default=12,
                    help="also the optimal-N design, N poses (default 12; 0: leave it out; computing it takes seconds)")
    ap.add_argument("--seed", type=int, default=4399)
    ap.add_argument("--small", action="store_true", help="a quick run: 40 boards, 4 held-out orientations")
    a = ap.parse_args(argv)
    if a.small:
        a.boards, a.heldout = min(a.boards, 40), min(a.heldout, 4)
    models = [m.strip() for m in a.models.split(",") if m.strip()]
    bad = [m for m in models if m not in PLAN]
    if bad or a.boards < 2 or a.samples < 1 or a.heldout < 1 or not (a.optimal == 0 or 5 <= a.optimal <= 64):
        print(f"error: --models {a.models!r} (allowed 6, 9, 12, 15), --boards >= 2, --samples and --heldout >= 1, "
              "--optimal 0 or 5..64", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    rows = run(a.boards, a.samples, a.heldout, a.seed, models, a.optimal)
    sem = rows[0]["sem_mg"]
    print(f"accuracy vs the Cramer-Rao limit: {a.boards} simulated MMA8451 boards per model, {a.samples} samples "
          f"per pose (standard error {sem:.4f} mg per axis), {a.heldout} held-out orientations per board, "
          f"seed {a.seed}")
    for m in models:
        print(f"  model {m} boards: noise, quantization, {', '.join(CLASS_EFFECTS[m])}")
    print("param ratio = RMS(fitted - true) / predicted standard error, pooled per group (1.00 = at the limit; "
          f"95% sampling interval +-{1.96 / np.sqrt(2 * a.boards):.2f} for one parameter, tighter pooled)")
    print("tilt: RMS angle error on held-out orientations (deg); CR = predicted after calibrating with that design; "
          "noise = true calibration on the same readings")
    out = []
    for r in rows:
        g = r["ratio"]
        first, second = list(g.values())[:2]
        gamma = g.get("Gamma")
        out.append([r["model"], r["design"], r["poses"], f"{r['ok']}/{a.boards}", f"{first:.2f}", f"{second:.2f}",
                    "-" if gamma is None else f"{gamma:.2f}", f"{r['tilt_deg']:.5f}", f"{r['tilt_cr_deg']:.5f}",
                    f"{r['tilt_deg'] / r['tilt_cr_deg']:.2f}", f"{r['limit_deg']:.5f}",
                    f"{r['tilt_deg'] / r['limit_deg']:.2f}"])
    print(table(["model", "design", "poses", "fitted", "W|M ratio", "V|B ratio", "Gamma ratio", "tilt deg",
                 "tilt CR deg", "tilt/CR", "noise deg", "tilt/noise"], out))
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

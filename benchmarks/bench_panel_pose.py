"""The jig's pose scatter, and what a panel's joint pose estimate does about it.

    python benchmarks/bench_panel_pose.py [--trials 20] [--scatter-deg 0.2] [--model 12] [--small]

A simulated jig presents each pose of an4399-8 with a fresh rotation error (the
``pose_error`` effect's per-pose scatter: rotation vectors with ``--scatter-deg`` rms
angle), the same for every board on the panel.  In-class boards (benchlib.make_boards:
offset, gain, cross-axis for model 12) are averaged over the station's sample count per
pose.  One board (board 0) is calibrated four ways:

  alone         its own fit against the commanded references
  panel of 4    references corrected by estimate_jig_poses from the 4 boards (jig_pose.py)
  panel of 16   the same with 16 boards
  perfect jig   no pose scatter at all (same noise)

and judged on held-out orientations (500 uniformly random true directions, noise-free
readings of the board): tilt error = angle between the calibrated vector and the true
one (degrees, rms over directions, then mean over trials), as measured and once the
calibrated frame is turned onto the board's by the one best rotation (Kabsch).  What no
panel can estimate is the part of the scatter every board's fit absorbs alike: a rotation
common to all poses (their mean error: it turns the frame, as a fixed jig rotation
does) and, on cube-vertex designs such as an4399-8, two traceless scale patterns too
(jig_pose.py); designs with more varied poses (optimal-16, the default here) leave only
the rotation.  The fit's residual RMS is
printed too: that is what the panel's estimate removes.  Fixed seeds; one run.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import angle_deg, apply_an4399, design_refs, make_boards, random_directions, rms, table

from accelcal_station.models.linear import fit_linear_batch
from accelcal_station.sim.sensor_model import rotation_matrix
from accelcal_station.station.jig_pose import estimate_jig_poses

SAMPLES = 225  # the station's mean samples per pose at capture.target_sem_mg 0.05 (bench_station_time)


def capture(boards, directions: np.ndarray) -> np.ndarray:
    """(B, P, 3) averaged readings in g, every board at the same true directions (P, 3)."""
    out = np.empty((len(boards), len(directions), 3))
    for b, board in enumerate(boards):
        for p, d in enumerate(directions):
            board.set_gravity_direction(d)
            out[b, p] = board.read(SAMPLES)[0].mean(axis=0) / board.counts_per_g
    return out


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation Q minimising sum |Q a_i - b_i|^2 (Kabsch)."""
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def tilt_error_deg(board, W, V, G, held: np.ndarray) -> tuple[float, float]:
    """(tilt error, tilt error once the calibration's frame is turned onto the board's), deg rms."""
    gf = board.model.response_g(held, board.temperature_c)
    cal = apply_an4399(W[None], V[None], G[None], gf[None])[0]
    Q = kabsch(cal, held)
    return rms(angle_deg(cal, held)), rms(angle_deg(cal @ Q.T, held))


def trial(model: str, scatter_deg: float, seed: int, design: str) -> dict[str, tuple[float, float, float]]:
    rng = np.random.default_rng(seed)
    boards = make_boards(model, 16, seed)
    ref = design_refs(design)
    R = rotation_matrix(rng.normal(0.0, scatter_deg / np.sqrt(3.0), (len(ref), 3)))  # rms angle = scatter
    gf = capture(boards, (R @ ref[..., None])[..., 0])
    gf_perfect = capture(boards[:1], ref)
    held = random_directions((500,), rng)
    out = {}

    def judge(name: str, g: np.ndarray, refs: np.ndarray) -> None:
        f = fit_linear_batch(g[None], refs[None], model)
        out[name] = (*tilt_error_deg(boards[0], f.W[0], f.V[0], f.Gamma[0], held), float(f.residual_rms_g[0]))

    judge("alone", gf[0], ref)
    for n in (4, 16):
        est = estimate_jig_poses(gf[:n], ref, model)
        judge(f"panel of {n}", gf[0], est.references_g[0])
    judge("perfect jig", gf_perfect[0], ref)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--scatter-deg", type=float, default=0.2)
    ap.add_argument("--model", default="12", choices=("6", "12", "15"))
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--design", default="optimal-16", help="pose design (accelcal poses NAME; default optimal-16)")
    ap.add_argument("--small", action="store_true", help="a quick run: 3 trials")
    a = ap.parse_args(argv)
    if a.small:
        a.trials = min(a.trials, 3)
    if a.trials < 1 or not a.scatter_deg >= 0:
        print("error: --trials must be >= 1 and --scatter-deg >= 0", file=sys.stderr)
        return 2
    res = [trial(a.model, a.scatter_deg, a.seed + t, a.design) for t in range(a.trials)]
    names = list(res[0])
    tilt, framed, resid = ({k: float(np.mean([r[k][i] for r in res])) for k in names} for i in range(3))
    print(f"pose scatter {a.scatter_deg:g} deg rms per pose, model {a.model}, design {a.design}, {SAMPLES} samples "
          f"per pose, board 0 of 16 in-class boards, mean of {a.trials} trials")
    rows = [[k, f"{tilt[k]:.4f}", f"{tilt[k] / tilt['perfect jig']:.2f}", f"{framed[k]:.4f}",
             f"{framed[k] / framed['perfect jig']:.2f}", f"{resid[k] * 1e3:.3f}"] for k in names]
    print(table(["calibrated", "held-out tilt error (deg rms)", "/ perfect jig", "same, frame turned (deg rms)",
                 "/ perfect jig", "fit residual RMS (mg)"], rows))
    print(f"ratio panel of 16 / perfect jig, frame turned: {framed['panel of 16'] / framed['perfect jig']:.2f} "
          f"(goal <= 1.2); as measured: {tilt['panel of 16'] / tilt['perfect jig']:.2f}")
    print("Left as measured: one rotation of the whole frame (the pose errors' mean over the design), the same for "
          "every board, which no panel can see; a constant jig rotation is absorbed in W the same way.")
    if framed["panel of 16"] > 1.2 * framed["perfect jig"]:
        print(f"Left even with the frame turned: on {a.design} some per-pose rotation patterns mimic a scale error "
              "for every board alike (cube vertices: two traceless scale patterns), which no panel can see either; "
              "a design with more varied poses (optimal-16) leaves only the frame's rotation.")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Samples per pose from the design's leverage: how many each pose needs so the fitted parameters
reach their target standard uncertainties (docs/capture.md, "Sequential capture").

The station fits by ordinary least squares (AN4399 Eqn 46; the nine-parameter model linearised at
M = I, B = 0).  For one block of the fit (a channel of models 6/12/15, the whole of model 9) with
rows a_i (the model's Jacobian at pose i) and pose means of variance v_i, the estimator's covariance
is the sandwich

    cov = G A^T diag(v) A G,   G = (A^T A)^-1   so   var(theta_j) = sum_i v_i g_ij^2,  g = A G

(the propagation of each pose's measured variance, GUM eq. 13).  With v_i = q / n_i (q: the per-sample
variance times tau_int, so q / n_i = sigma^2 / n_eff,i) every parameter's variance is linear in
1 / n_i, and minimising the total sum n_i subject to var_j <= T_j for one target is Neyman's optimal
allocation (Cochran, Sampling Techniques, 3rd ed., section 5.5, by Cauchy-Schwarz):

    n_i = sqrt(w_i) * sum_k sqrt(w_k) / T,   w_i = q_i g_ij^2

(the poses that matter more to the parameter get more samples, in proportion to the square root
of their contribution).  Several targets (offset and gain of three axes) are met together through
the Lagrange dual of the same problem, n_i = sqrt(sum_j lambda_j w_ji), each candidate scaled until
its worst target ratio is 1; the multipliers move toward the binding targets (lambda_j <- lambda_j
ratio_j^2) and the candidate with the fewest samples is kept (the uniform allocation among them, so
the plan never needs more samples than equal counts would).  Poses already captured enter with
their measured variances and are not re-allocated.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DUAL_STEPS = 24  # multiplier updates; the total changes by < 0.1 % after ~10 on the shipped designs


@dataclass(frozen=True)
class DesignRows:
    """The fit's linearised rows per block (A: (B, m, p)), how each block's pose variance is made of
    the three axes' (mix: (B, m, 3)), and where each axis's offset and gain sit ((3,) (block, param))."""

    model: str
    A: np.ndarray
    mix: np.ndarray
    offset_at: tuple[tuple[int, int], ...]
    gain_at: tuple[tuple[int, int], ...]

    @property
    def poses(self) -> int:
        return int(self.A.shape[1])


@dataclass(frozen=True)
class Allocation:
    """Samples per pose (n: (m,), ints), the parameters' predicted standard uncertainty with them
    (u: (B, p), in the fit's units: g for offsets, a fraction for gains), the worst predicted/target
    ratio, and whether the remaining poses can meet the targets at all."""

    n: np.ndarray
    u: np.ndarray
    worst_ratio: float
    feasible: bool


def design_rows(model: str, expected_g: np.ndarray) -> DesignRows:
    """The Jacobian rows of ``model`` (6, 9, 12, 15) at the poses' expected readings (m, 3) in g, taken
    as the readings themselves (the nominal chip: W = I, V = 0): models/linear.py regressors' layout."""
    r = np.asarray(expected_g, dtype=float)
    m = len(r)
    one = np.ones((m, 1))
    eye = np.broadcast_to(np.eye(3)[:, None, :], (3, m, 3))
    if model == "9":
        # d(|M (v - B)| - 1) at M = I, B = 0, v = r/|r|: r_k^2, 2 r_k r_l (M_xy, M_xz, M_yz), -r_k
        u = r / np.linalg.norm(r, axis=1, keepdims=True)
        A = np.concatenate([u**2, 2 * u[:, [0, 0, 1]] * u[:, [1, 2, 2]], -u], axis=1)[None]
        return DesignRows(model, A, (u**2)[None], ((0, 6), (0, 7), (0, 8)), ((0, 0), (0, 1), (0, 2)))
    if model == "6":
        A = np.stack([np.stack([r[:, k], one[:, 0]], axis=1) for k in range(3)])
        return DesignRows(model, A, eye.copy(), ((0, 1), (1, 1), (2, 1)), ((0, 0), (1, 0), (2, 0)))
    base = np.concatenate([r, one], axis=1)
    if model == "12":
        A = np.broadcast_to(base, (3, m, 4)).copy()
    else:
        A = np.stack([np.concatenate([base, r[:, k:k + 1] ** 3], axis=1) for k in range(3)])
    return DesignRows(model, A, eye.copy(), ((0, 3), (1, 3), (2, 3)), ((0, 0), (1, 1), (2, 2)))


def target_variances(rows: DesignRows, offset_u_g: float | None, gain_u: float | None) -> np.ndarray:
    """(B, p) target variances: offset_u_g^2 at each axis's offset, gain_u^2 at its gain, inf elsewhere."""
    T = np.full(rows.A.shape[::2], np.inf)
    for at, u in ((rows.offset_at, offset_u_g), (rows.gain_at, gain_u)):
        if u is not None:
            for b, p in at:
                T[b, p] = float(u) ** 2
    return T


def leverage(rows: DesignRows) -> np.ndarray:
    """g^2 = (A G)^2, (B, m, p): pose i's weight in var(theta_j) per unit of its variance."""
    A = rows.A
    G = np.linalg.inv(A.transpose(0, 2, 1) @ A)
    return (A @ G) ** 2


def block_variance(rows: DesignRows, axis_var: np.ndarray) -> np.ndarray:
    """Each block's per-pose variance (B, m) from per-axis variances (m, 3) or (3,)."""
    v = np.broadcast_to(np.asarray(axis_var, dtype=float), (rows.poses, 3))
    return np.einsum("bmk,mk->bm", rows.mix, v)


def ols_uncertainty(rows: DesignRows, pose_var: np.ndarray) -> np.ndarray:
    """Standard uncertainty (B, p) of the OLS parameters with pose-mean variances (B, m) (the sandwich)."""
    return np.sqrt(np.einsum("bm,bmp->bp", pose_var, leverage(rows)))


def allocate(rows: DesignRows, fixed_var: np.ndarray, per_sample_var: np.ndarray, remaining: np.ndarray,
             target_var: np.ndarray, n_min: int, n_max: int) -> Allocation:
    """Samples for the ``remaining`` poses ((m,) bool) so every finite target of ``target_var`` (B, p) is
    met with the fewest samples (module docstring).  fixed_var (B, m): the captured poses' pose-mean
    variances; per_sample_var (B, m): sigma^2 tau_int expected at the remaining ones.  Captured poses
    get n = 0; every remaining pose at least n_min; at most n_max (then ``feasible`` is False)."""
    rem = np.asarray(remaining, dtype=bool)
    g2 = leverage(rows)
    F = np.einsum("bm,bmp->bp", np.where(rem, 0.0, fixed_var), g2)
    act = np.isfinite(target_var)
    S = (target_var - F)[act]  # (J,) the variance left to the remaining poses
    W = (per_sample_var[..., None] * g2).transpose(0, 2, 1)[act][:, rem]  # (J, r)
    n = np.zeros(rows.poses)
    if not rem.any():
        return _result(rows, fixed_var, per_sample_var, n, target_var, True)
    if np.any(S <= 0.0):  # the captured poses alone already exceed a target: take all there is
        n[rem] = n_max
        return _result(rows, fixed_var, per_sample_var, n, target_var, False)
    best = _scaled(np.ones(int(rem.sum())), W, S)
    lam = np.ones(len(S))
    for _ in range(DUAL_STEPS if len(S) > 1 else 1):
        cand = _scaled(np.sqrt(np.maximum(lam @ W, 1e-300)), W, S)
        if cand.sum() < best.sum():
            best = cand
        ratio = (W @ (1.0 / cand)) / S
        lam = lam * ratio**2
        lam /= lam.sum()
    n[rem] = np.clip(np.ceil(best), n_min, n_max)
    return _result(rows, fixed_var, per_sample_var, n, target_var, bool(np.all(np.ceil(best) <= n_max)))


def _scaled(n: np.ndarray, W: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``n`` scaled so its worst target ratio (W @ 1/n) / S is exactly 1."""
    return n * float(np.max((W @ (1.0 / n)) / S))


def _result(rows: DesignRows, fixed_var: np.ndarray, per_sample_var: np.ndarray, n: np.ndarray,
            target_var: np.ndarray, feasible: bool) -> Allocation:
    """The allocation with its predicted uncertainties (captured poses at their measured variance)."""
    var = np.where(n > 0, per_sample_var / np.maximum(n, 1.0), fixed_var)
    u = ols_uncertainty(rows, var)
    act = np.isfinite(target_var)
    worst = float(np.max(u[act] ** 2 / target_var[act])) ** 0.5 if act.any() else 0.0
    return Allocation(n.astype(int), u, worst, feasible)

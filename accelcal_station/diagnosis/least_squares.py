"""The fits of the diagnosis, batched over held-out folds: weighted least squares (with references),
and Levenberg-Marquardt on r = |A theta + b| - gamma - d theta (norm only; the nine-position paper)."""
from __future__ import annotations

import numpy as np


def pinv(G: np.ndarray) -> np.ndarray:
    return np.linalg.pinv(G, rcond=1e-12, hermitian=True)


def wls(A: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares for a batch: A (N, R, p), y (N, R), w (N, R) -> theta (N, p), C (N, p, p)."""
    Aw = A * w[..., None]
    C = pinv(A.swapaxes(-1, -2) @ Aw)
    theta = (C @ (Aw.swapaxes(-1, -2) @ y[..., None]))[..., 0]
    return theta, C


def norm_resid(A: np.ndarray, b: np.ndarray, d: np.ndarray, gamma: float,
               theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Norm residuals r (N, P), their Jacobian J (N, P, p) and the unit outputs (N, P, 3) at theta (N, p)."""
    u = np.einsum("npcq,nq->npc", A, theta) + b
    nrm = np.linalg.norm(u, axis=-1)
    r = nrm - gamma - (theta @ d)[:, None]
    uh = u / np.maximum(nrm, 1e-300)[..., None]
    J = np.einsum("npc,npcq->npq", uh, A) - d
    return r, J, uh


def lm_norm(A: np.ndarray, b: np.ndarray, d: np.ndarray, gamma: float, w: np.ndarray, theta0: np.ndarray,
            iters: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt on r = |A theta + b| - gamma - d theta, weights w (N, P); batch N."""
    theta = np.array(theta0, float)
    N, p = theta.shape
    lam = np.full(N, 1e-3)
    r, J, _ = norm_resid(A, b, d, gamma, theta)
    cost = np.sum(w * r**2, axis=1)
    for _ in range(iters):
        JtJ = np.einsum("npq,np,npr->nqr", J, w, J)
        grad = np.einsum("npq,np->nq", J, w * r)
        dg = np.maximum(np.einsum("nqq->nq", JtJ), 1e-12)
        M = JtJ + (lam[:, None] * dg)[..., None] * np.eye(p)
        step = -np.linalg.solve(M, grad[..., None])[..., 0]
        tn = theta + step
        rn, Jn, _ = norm_resid(A, b, d, gamma, tn)
        cn = np.sum(w * rn**2, axis=1)
        ok = np.isfinite(cn) & (cn <= cost)
        theta[ok], r[ok], J[ok] = tn[ok], rn[ok], Jn[ok]
        small = ok & (cost - cn <= 1e-12 * np.maximum(cost, 1e-300))
        cost[ok] = cn[ok]
        lam = np.where(ok, np.maximum(lam / 10, 1e-12), lam * 10)
        if np.all(small | (lam > 1e10)):
            break
    C = pinv(np.einsum("npq,np,npr->nqr", J, w, J))
    return theta, C


def norm_start(g: np.ndarray, labels: list[tuple[str, str]], gamma: float) -> np.ndarray:
    """Start of the norm fit: a sphere centred at the mid-range, radius the median norm."""
    c = 0.5 * (g.max(axis=0) + g.min(axis=0))
    s = float(np.median(np.linalg.norm(g - c, axis=1))) / gamma
    th = np.zeros(len(labels))
    for k, (_effect, det) in enumerate(labels):
        if det.startswith("W_") and det[2] == det[3]:
            th[k] = 1.0 / s
        elif det.startswith("V_"):
            th[k] = -c["xyz".index(det[2])] / s
    return th
